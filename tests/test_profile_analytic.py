"""Analytic profile samples (`spare-twin dataset --analytic-profiles`, spare_twin.nets.profile_analytic):
the printed chain drawn straight into the profile frame, its joint play measured in the image, the
folder drawn the same bytes from the same seed, resumed, extended, and read by training."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from conftest import refused_before_torch, run_cli

from spare_twin.config import sample_chain
from spare_twin.errors import SpareTwinError
from spare_twin.nets.presets import PRESETS, TrainConfig
from spare_twin.nets.profile_analytic import analytic_profiles, analytic_sample
from spare_twin.nets.profile_analytic_config import ANALYTIC_SEED_BASE, SEED_STRIDE, AnalyticProfileConfig
from spare_twin.nets.profile_train import profile_samples
from spare_twin.nets.sample_folders import ANALYTIC_KIND, HANDHELD_FORMAT, SPLIT_CODES
from spare_twin.observe.profile import Z_RANGE_PU

#: A capture with nothing but the print's geometry: no noise, blur, holes or strays, both faces seen.
CLEAN = dict(
    scale_error=(0.0, 0.0), level_error_deg=(0.0, 0.0), joint_shift_mm=0.0, far_face_share=(1.0, 1.0),
    dark_link_prob=0.0, noise_across_m=(0.0, 0.0), noise_in_plane_m=(0.0, 0.0), view_offset_m=(0.0, 0.0),
    view_turn_deg=(0.0, 0.0), holes=0, stray_share=(0.0, 0.0), base_axis_error_m=(0.0, 0.0), plane_error_deg=0.0,
)  # fmt: skip


def test_a_sample_is_its_chains_profile_with_its_labels():
    c = AnalyticProfileConfig(samples=12, seed=3)
    for i in (0, 4, 11):
        s = analytic_sample(c, i)
        n = i % 6 + 1
        spec = sample_chain(n, seed=ANALYTIC_SEED_BASE + 3 * SEED_STRIDE + i)
        assert s["n"] == n and np.array_equal(s["lengths"], spec.label_lengths())
        assert s["x"].shape == (3, 64, 80) and s["x"].dtype == np.float16
        assert np.count_nonzero(s["angles"][:n]) == n and not s["angles"][n:].any()
        occupied = s["x"][0] > 0
        assert occupied.sum() > 100
        # link k sits about k layers along the joint axes: the chain's last link near n
        assert n - 1.5 < s["x"][1][occupied].max() < n + 1.5
        again = analytic_sample(c, i)
        assert all(np.array_equal(s[k], again[k]) for k in s)  # a pure function of (settings, index)


def _layer_slope(image: np.ndarray, print_scale: float) -> float:
    """Layers per metre that a one-link chain's moving link runs across along its length: the slope of
    its cells' mean t (those off the base column, 2 cm or more from the joint) against their distance
    from the joint (the base column's top, on the base axis)."""
    occupied, mean_t = image[0] > 0, image[1]
    cell_m = (Z_RANGE_PU[1] - Z_RANGE_PU[0]) / image.shape[1] * print_scale
    axis_col = image.shape[2] // 2  # s = 0: the profile's s range is symmetric about the base axis
    column = np.nonzero(occupied[:, axis_col] & (mean_t[:, axis_col] < 0.5))[0]
    # the base link and the foot's boss (18 mm wide) below the joint, on the base axis
    below = (np.arange(image.shape[1]) >= column.min())[:, None]
    base = below & (np.abs(np.arange(image.shape[2]) - axis_col) <= 3)[None, :]
    rows, cols = np.nonzero(occupied & ~base)
    dist_m = np.hypot(rows - column.min(), cols - axis_col) * cell_m
    clear = dist_m > 0.02  # past the joint's round end, where the base link's cells mix in
    return float(np.polyfit(dist_m[clear], mean_t[rows[clear], cols[clear]], 1)[0])


@pytest.mark.parametrize("index", [96, 114])  # one-link chains of seed 0 with 7-8 cm links (0.90, 0.98 pu)
def test_a_tilted_link_runs_across_layers_by_its_tilt_and_is_levelled(index):
    """Joint play: a link tilted by delta out of the plane runs sin(delta) along the joint axes per
    metre of its length; measured in the image of the points as captured as the slope of its cells'
    mean t, against the same chain untilted (the same draws but the tilt's), whose link stays on its
    layer. The network's image, levelled by the layers' comb as `predict` levels a capture's
    (`measure.level`), holds the link on its layer."""
    spec = sample_chain(1, seed=ANALYTIC_SEED_BASE + index)
    flat_c = AnalyticProfileConfig(samples=1, joint_tilt_deg=(0.0, 0.0), **CLEAN)
    tilted_c = AnalyticProfileConfig(samples=1, joint_tilt_deg=(4.0, 4.0), **CLEAN)
    flat = analytic_sample(flat_c, index, levelled=False)
    tilted = analytic_sample(tilted_c, index, levelled=False)
    expected = np.sin(np.radians(4.0)) / (spec.layer_pitch_mm / 1000.0)  # layers per metre
    flat_slope = _layer_slope(flat["x"].astype(np.float32), spec.print_scale)
    tilted_slope = _layer_slope(tilted["x"].astype(np.float32), spec.print_scale)
    assert abs(flat_slope) < 0.25 * expected, (flat_slope, expected)
    assert 0.8 * expected < abs(tilted_slope - flat_slope) < 1.2 * expected, (tilted_slope, flat_slope, expected)
    levelled_slope = _layer_slope(analytic_sample(tilted_c, index)["x"].astype(np.float32), spec.print_scale)
    assert abs(levelled_slope) < 0.25 * expected, (levelled_slope, expected)


def test_a_farther_plate_behind_a_nearer_one_is_hidden():
    """Where two links overlap (at their joints), a sweep from one side sees the nearer plate's face:
    cells holding both layers (t extent over 0.6 layers) are fewer than where nothing is hidden."""
    c = AnalyticProfileConfig(samples=1, **{**CLEAN, "far_face_share": (0.0, 0.0), "rim_share": (0.0, 0.0)})
    both = {}
    for share in (1.0, 0.0):
        images = [analytic_sample(dataclasses.replace(c, hidden_share=share), i)["x"] for i in range(1, 20, 3)]
        both[share] = np.array([(x[2].astype(np.float32) > 0.6).sum() for x in images])
    assert (both[1.0] <= both[0.0]).all() and both[1.0].sum() < 0.75 * both[0.0].sum(), both


def test_the_folder_is_the_same_bytes_resumes_extends_and_is_read_by_training(tmp_path, capsys):
    out = tmp_path / "ap"
    code, printed, _ = run_cli(["dataset", "--analytic-profiles", "--instances", "66", "--out", str(out)], capsys)
    assert code == 0 and "60 training and 6 validation" in printed  # 11 rounds of six: the tenth is validation
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["format"] == HANDHELD_FORMAT and manifest["kind"] == ANALYTIC_KIND
    assert manifest["samples"] == {"train": 60, "val": 6}
    first = (out / "samples.npz").read_bytes()
    with np.load(out / "samples.npz") as z:
        assert z["x"].shape == (66, 3, 64, 80) and z["n"].tolist()[:7] == [1, 2, 3, 4, 5, 6, 1]
        assert (z["split"][54:60] == SPLIT_CODES["val"]).all() and (z["split"][:54] == SPLIT_CODES["train"]).all()
    other = tmp_path / "again"
    assert run_cli(["dataset", "--analytic-profiles", "--instances", "66", "--out", str(other)], capsys)[0] == 0
    assert (other / "samples.npz").read_bytes() == first  # the same seed: the same bytes

    chunk = out / "chunks" / "chunk00000.npz"
    stamp = chunk.stat().st_mtime_ns
    analytic_profiles(out, AnalyticProfileConfig(samples=66), progress=False)  # done: nothing redrawn
    assert chunk.stat().st_mtime_ns == stamp and (out / "samples.npz").read_bytes() == first
    with pytest.raises(SpareTwinError, match="holds analytic profile samples of seed 0, not 1"):
        analytic_profiles(out, AnalyticProfileConfig(samples=66, seed=1), progress=False)

    split = profile_samples([out], "train", PRESETS["profile-depth-multitask"].net, TrainConfig(epochs=1))
    assert len(split) == 2 * 60  # each training sample and its mirror image
    item = split[0]
    assert item["x"].shape == (3, 64, 80) and int(item["n_links"]) == 1


def test_bad_options_are_said_before_torch_is_loaded(tmp_path):
    cases = [
        (["--instances", "0"], ("--instances",)),
        (["--instances", "6", "--seed", "1000"], ("--seed",)),
        (["--instances", "6", "--workers", "0"], ("--workers",)),
        (["--instances", "6", "--frames", "10"], ("--frames", "not an option of --analytic-profiles")),
        (["--instances", "6", "--handheld"], ("--handheld", "--analytic-profiles")),
    ]
    argvs = [(["dataset", "--analytic-profiles", "--out", "ap", *argv], words) for argv, words in cases]
    refused_before_torch(argvs, tmp_path)
