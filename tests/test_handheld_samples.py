"""The profile network's hand-held samples (`spare-twin dataset --handheld`, spare_twin.bench.handheld_samples):
a capture drawn the bench's way becomes a labelled profile sample, the folder resumes, and training
reads it beside (or instead of) the rig's datasets."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from conftest import refused_before_torch, run_cli

from spare_twin.bench.handheld_config import HANDHELD_SEED_BASE, SETTINGS_BLOCK, HandheldConfig
from spare_twin.bench.handheld_samples import handheld_dataset
from spare_twin.config import sample_chain
from spare_twin.errors import SpareTwinError
from spare_twin.io import write_json_atomic
from spare_twin.nets.presets import PRESETS, TrainConfig
from spare_twin.nets.profile_train import profile_samples
from spare_twin.nets.sample_folders import HANDHELD_FORMAT, SPLIT_CODES
from spare_twin.recording import npz_bytes


@pytest.fixture(scope="module")
def one_capture(tmp_path_factory):
    out = tmp_path_factory.mktemp("handheld") / "hh"
    manifest = handheld_dataset(out, HandheldConfig(objects=1, seed=0), progress=False)
    return out, manifest


def test_a_handheld_capture_becomes_a_labelled_profile_sample(one_capture):
    out, manifest = one_capture
    assert manifest["samples"] == {"train": 1, "val": 0} and manifest["rejected"] == {"train": 0, "val": 0}
    assert manifest["first_chain_seed"] == HANDHELD_SEED_BASE  # never a bench seed
    with np.load(out / "samples.npz") as z:
        x, n, lengths, angles, split = z["x"], z["n"], z["lengths"], z["angles"], z["split"]
    # object 0 of the bench's table: one moving link, its chain drawn from the first training seed
    spec = sample_chain(n_links=1, seed=HANDHELD_SEED_BASE)
    assert x.shape == (1, 3, 64, 80) and x.dtype == np.float16 and split.tolist() == [SPLIT_CODES["train"]]
    assert n.tolist() == [1] and np.allclose(lengths[0], spec.label_lengths())
    assert angles[0, 0] != 0 and not angles[0, 1:].any()  # the held pose's joint, nothing past it
    occupied = x[0, 0] > 0  # the chain's points drawn into its profile: base column and one link
    assert occupied.sum() > 100
    assert not (out / "scratch").exists()  # the capture itself is not kept
    assert sorted(p.name for p in (out / "objects").iterdir()) == [f"seed{HANDHELD_SEED_BASE}.npz"]


def test_the_handheld_folder_resumes_and_refuses_another_seed(one_capture):
    out, manifest = one_capture
    sample = out / "objects" / f"seed{HANDHELD_SEED_BASE}.npz"
    before = (sample.stat().st_mtime_ns, (out / "samples.npz").read_bytes())
    again = handheld_dataset(out, HandheldConfig(objects=1, seed=0), progress=False)
    assert again == manifest and before == (sample.stat().st_mtime_ns, (out / "samples.npz").read_bytes())
    with pytest.raises(SpareTwinError, match="holds hand-held samples of seed 0, not 1"):
        handheld_dataset(out, HandheldConfig(objects=1, seed=1), progress=False)
    assert before == (sample.stat().st_mtime_ns, (out / "samples.npz").read_bytes())
    assert sorted(p.name for p in out.parent.iterdir()) == ["hh"]  # no partial copy left beside it


def test_handheld_flags_are_checked_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "hh"
    for extra, says in (
        (["--frames", "10"], "--frames: not an option of --handheld"),
        (["--sim2real"], "--sim2real: not an option of --handheld"),
        (["--seed", "1000"], "--seed 1000: at most 999"),
        (["--instances", "0"], "--instances 0: must be a whole number"),
    ):
        instances = [] if "--instances" in extra else ["--instances", "2"]
        argv = ["dataset", "--handheld", "--out", str(out), *instances]
        rc, _, err = run_cli([*argv, *extra], capsys)
        assert rc != 0 and says in err and len(err.strip().splitlines()) == 1, (extra, err)
        assert not out.exists()


def test_a_bad_count_seed_workers_or_folder_is_said_before_torch_is_loaded(tmp_path):
    """A count, seed or worker count out of range, or a folder that is not the command's output (one that
    only looks like another seed's samples; a real one of another seed is refused in
    `test_the_handheld_folder_resumes_and_refuses_another_seed`): said before the drawing's modules (the
    measurement and torch: 5 s of a new process) are imported, and nothing written."""
    (tmp_path / "other").mkdir()
    write_json_atomic(tmp_path / "other" / "manifest.json", {"format": HANDHELD_FORMAT, "seed": 3})
    cases = [
        (["--instances", "-1"], ("--instances -1", "at least 1")),
        (["--instances", "0"], ("--instances 0",)),
        (["--instances", "2", "--seed", "1000"], ("--seed 1000", "at most 999")),
        (["--instances", "2", "--workers", "0"], ("--workers 0", "at least 1")),
        (["--instances", "2", "--out", "other"], ("other:", "not an earlier dataset --handheld output")),
    ]
    refused_before_torch(
        [(["dataset", "--handheld", "--out", "hh", *extra], words) for extra, words in cases], tmp_path
    )


def _synthetic_handheld(folder, counts: list[int], splits: list[str]):
    """A hand-held sample folder whose profiles show n bright bands for n links (learnable)."""
    x = np.zeros((len(counts), 3, 64, 80), np.float16)
    lengths = np.zeros((len(counts), 7), np.float32)
    angles = np.zeros((len(counts), 6), np.float32)
    for i, n in enumerate(counts):
        x[i, 0, : 8 * (n + 1)] = 1.0
        x[i, 1, : 8 * (n + 1), :10] = n  # layers on the left only: a mirror image differs
        lengths[i, : n + 1] = 0.5
        angles[i, :n] = 0.25
    arrays = {
        "x": x,
        "n": np.array(counts, np.int64),
        "lengths": lengths,
        "angles": angles,
        "split": np.array([SPLIT_CODES[s] for s in splits], np.uint8),
    }
    folder.mkdir()
    (folder / "samples.npz").write_bytes(npz_bytes(arrays))
    write_json_atomic(folder / "manifest.json", {"format": HANDHELD_FORMAT, "file": "samples.npz", "seed": 0})
    return folder


def test_training_reads_handheld_samples_repeated_and_evaluate_refuses_them(tmp_path):
    hh = _synthetic_handheld(tmp_path / "hh", [1, 2, 3, 4, 5, 6, 1, 2], ["train"] * 6 + ["val"] * 2)
    net = PRESETS["profile-depth-multitask"].net
    train = profile_samples([hh], "train", net, TrainConfig(handheld_repeat=3), progress=False)
    val = profile_samples([hh], "val", net, TrainConfig(handheld_repeat=3), progress=False)
    assert len(train) == 36 and len(val) == 2  # validation is neither mirrored nor repeated
    assert [int(train[i]["n_links"]) for i in range(36)] == [1, 2, 3, 4, 5, 6] * 6
    # the mirror image: the profile flipped left to right, the joint angles negated
    first, mirror = train[0], train[18]
    assert not torch.equal(mirror["x"], first["x"]) and first["joint_angles_rad"][0] == 0.25
    assert torch.equal(mirror["x"], first["x"].flip(-1)) and torch.equal(
        mirror["joint_angles_rad"], -first["joint_angles_rad"]
    )
    with pytest.raises(SpareTwinError, match="hand-held profile samples are for training"):
        profile_samples([hh], "test", net, None, progress=False)


def test_a_short_training_run_on_handheld_samples_learns(tmp_path, capsys):
    counts = [i % 6 + 1 for i in range(48)]
    hh = _synthetic_handheld(tmp_path / "hh", counts, ["train"] * 42 + ["val"] * 6)
    out = tmp_path / "run"
    argv = ["train", "--preset", "profile-depth-multitask", "--data", str(hh), "--out", str(out)]
    rc, _, err = run_cli([*argv, "--epochs", "8", "--batch-size", "8", "--seed", "0"], capsys)
    assert rc == 0, err
    history = json.loads((out / "history.json").read_text())
    assert history[-1]["train_loss"] < 0.5 * history[0]["train_loss"]
    card = (out / "MODEL_CARD.md").read_text()
    assert str(hh) in card


def test_handheld_config_is_checked_and_its_captures_do_not_depend_on_the_count():
    with pytest.raises(SpareTwinError, match="instances 0"):
        HandheldConfig(objects=0)
    assert HandheldConfig(objects=3, seed=2).bench_config().seed == HANDHELD_SEED_BASE + 2_000_000
    # a larger --instances extends the folder: the first objects' captures stay what they were
    many = HandheldConfig(objects=SETTINGS_BLOCK + 5).settings()
    assert HandheldConfig(objects=3).settings() == many[:3]
    assert [c.seed - HANDHELD_SEED_BASE for c in many[-2:]] == [SETTINGS_BLOCK + 3, SETTINGS_BLOCK + 4]
    assert len({c.frames for c in many[:SETTINGS_BLOCK]}) > 40  # each block spreads its settings


def test_handheld_samples_follow_the_rig_samples_in_a_training_split(tmp_path):
    """Rig samples (here read from a run folder's cache of observed samples) come first, then each
    hand-held folder's, repeated; the rig's rejected count stays the rig's."""
    from spare_twin.nets.profile_train import ObservedProfiles

    hh = _synthetic_handheld(tmp_path / "hh", [2, 3, 4], ["train", "train", "val"])
    rig = {
        "x": np.ones((4, 3, 64, 80), np.float16),
        "n": np.array([6, 6, 5, 5], np.int64),
        "lengths": np.zeros((4, 7), np.float32),
        "angles": np.zeros((4, 6), np.float32),
        "rejected": np.array(7, np.int64),
    }
    cache = tmp_path / "samples-train.npz"
    cache.write_bytes(npz_bytes(rig))
    ds = ObservedProfiles([tmp_path / "rig"], "train", cache, False, (hh,), 2)
    assert [int(ds[i]["n_links"]) for i in range(len(ds))] == [6, 6, 5, 5] + [2, 3] * 4
    assert ds.rejected == 7 and float(ds[0]["x"].mean()) == 1.0 and float(ds[4]["x"][0, 0, 0]) == 1.0


def test_the_validation_split_holds_every_count_alike():
    """Every tenth round of counts is validation: of 120 objects, two chains of each count 1..6 (every
    tenth object would have given only 2-, 4- and 6-link chains: an object's count follows its index)."""
    from spare_twin.bench.handheld_samples import split_of

    rows = HandheldConfig(objects=120).settings()
    counts = [c.n_links for c in rows]
    assert counts[:12] == [1, 2, 3, 4, 5, 6] * 2
    val = sorted(c for i, c in enumerate(counts) if split_of(i) == "val")
    assert val == [1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6, 6]
