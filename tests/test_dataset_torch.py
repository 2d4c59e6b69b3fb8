"""Torch datasets: multi-view and temporal, depth and grey, stored and on the fly."""

import numpy as np
import pytest
import torch

from spare_twin.dataset.build import generate_dataset
from spare_twin.dataset.generate import GenConfig, sequence_spec
from spare_twin.dataset.torch_data import MultiViewDataset, OnTheFlyDataset, TemporalDataset
from spare_twin.sim.noise import DepthNoise

T = 4


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("ds")
    generate_dataset(root, 6, seed=2, workers=1, cfg=GenConfig(frames=T), progress=False)
    return root


def _check(item, lead, n_views_meta):
    assert item["x"].dtype == torch.float32 and item["x"].shape == (lead, 96, 128)
    assert item["n_links"].dtype == torch.int64 and 1 <= int(item["n_links"]) <= 6
    assert item["lengths_pu"].shape == (7,) and item["lengths_pu"].dtype == torch.float32
    n = int(item["n_links"])
    assert (item["lengths_pu"][: n + 1] > 0).all() and (item["lengths_pu"][n + 1 :] == 0).all()
    assert item["K"].shape == (n_views_meta, 3, 3) and item["T_world_camera"].shape == (n_views_meta, 4, 4)
    assert item["print_scale"].dtype == torch.float32


def test_multiview_depth_and_grey(data):
    ds = MultiViewDataset(data, split="all", modality="depth")
    assert len(ds) == 6 * T
    item = ds[T * 2 + 1]  # sequence 2, time step 1
    _check(item, 8, 8)
    assert int(item["n_links"]) == 3
    assert np.allclose(item["lengths_pu"][:4].numpy(), sequence_spec(2, 2).link_lengths_pu)
    assert item["joint_angles_rad"].shape == (6,) and (item["joint_angles_rad"][3:] == 0).all()
    x = item["x"]
    assert 0.2 < x[x > 0].min() < 0.6 and x.max() < 2.0  # metres
    g = MultiViewDataset(data, split="all", modality="grey")[0]["x"]
    assert 0 <= g.min() and g.max() <= 1 and g.std() > 0.05
    batch = next(iter(torch.utils.data.DataLoader(ds, batch_size=5, shuffle=True)))
    assert batch["x"].shape == (5, 8, 96, 128) and batch["n_links"].shape == (5,)


def test_temporal(data):
    ds = TemporalDataset(data, split="all", modality="depth")
    assert len(ds) == 6 * 8
    item = ds[8 * 5 + 3]  # sequence 5 camera 3
    _check(item, T, 1)
    assert int(item["n_links"]) == 6 and item["joint_angles_rad"].shape == (T, 6)
    assert not torch.equal(item["x"][0], item["x"][-1])  # the chain moves


def test_splits_are_disjoint(data):
    sizes = {s: len(MultiViewDataset(data, split=s)) for s in ("train", "val", "test")}
    assert sum(sizes.values()) == 6 * T and sizes["train"] > 0


def test_depth_noise_option(data):
    clean = MultiViewDataset(data, split="all")[0]["x"]
    noisy = MultiViewDataset(data, split="all", depth_noise=DepthNoise(dropout_prob=0.05))[0]["x"]
    assert noisy.shape == clean.shape and not torch.equal(noisy, clean)
    assert ((noisy == 0) & (clean > 0)).float().mean() > 0.02


def test_on_the_fly():
    ds = OnTheFlyDataset(
        mode="tmp", modality="grey", cfg=GenConfig(frames=T), seed=5, sequences=2, samples_per_sequence=2
    )
    items = list(ds)
    assert len(items) == 4
    _check(items[0], T, 1)
    assert [int(i["n_links"]) for i in items] == [1, 1, 2, 2]
    again = list(ds)
    assert torch.equal(items[3]["x"], again[3]["x"])  # seeded
    mv = next(iter(OnTheFlyDataset(mode="mv", cfg=GenConfig(frames=T), sequences=1, samples_per_sequence=1)))
    _check(mv, 8, 8)


def test_pose_jitter_turns_all_views_about_the_table_normal(data):
    from spare_twin.dataset.torch_data import PoseJitter

    clean = MultiViewDataset(data, split="all")[5]
    turned = MultiViewDataset(data, split="all", pose_jitter=PoseJitter(yaw_deg=10.0, xy_m=0.003))[5]
    assert torch.equal(turned["x"], clean["x"])  # images untouched, only the frame they are given in
    J = turned["T_world_camera"].double() @ torch.linalg.inv(clean["T_world_camera"].double())
    assert torch.allclose(J, J[0].expand_as(J), atol=1e-5)  # one error for the whole sample
    J = J[0].numpy()
    yaw = np.degrees(np.arctan2(J[1, 0], J[0, 0]))
    assert 0 < abs(yaw) <= 10.0 and np.allclose(J[2], [0, 0, 1, 0], atol=1e-6) and abs(J[0, 3]) < 0.02


def test_on_the_fly_streams_are_disjoint_across_processes_and_workers():
    from spare_twin.dataset.streams import stream_indices

    S, N, W = 10, 2, 3  # sequences (rounded up to a multiple of N by OnTheFlyDataset), processes, workers
    per_rank = []
    for rank in range(N):
        got = [k for w in range(W) for k in stream_indices(rank, N, w, W, S)]
        per_rank.append(got)
    flat = [k for got in per_rank for k in got]
    assert sorted(flat) == list(range(S))  # every sequence once, by one worker of one process
    assert len(per_rank[0]) == len(per_rank[1])  # the same number of steps on every rank
    assert OnTheFlyDataset(sequences=9, rank=1, world_size=2).sequences == 10
    with pytest.raises(Exception, match="rank"):
        OnTheFlyDataset(rank=2, world_size=2)
