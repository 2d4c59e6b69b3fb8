"""What a real print and a real sensor add (spare_twin.sim.effects and its hooks): each effect measured on
what it renders, the raycast renderer against pybullet, and byte-identical recordings per seed."""

import dataclasses
import json

import numpy as np
import pytest

from spare_twin.cli import main
from spare_twin.object.kinematics import forward_kinematics, printed_lengths_m
from spare_twin.recording import Recording
from spare_twin.sim.active_sensor import flying_pixels, shadow_mask
from spare_twin.sim.effects import ALL_EFFECTS, EFFECTS, NO_EFFECTS, parse_effects
from spare_twin.sim.noise import load_noise
from spare_twin.sim.render import RenderConfig, render_recording

#: The rig's eight fixed cameras, one static pose, no noise: what each effect changes is all that changes.
RIG = dict(frames=1, resolution="320x240", motion="static", seed=11)


def _render(obj, out, effects=NO_EFFECTS, **kw) -> Recording:
    cfg = RenderConfig(**{**RIG, **kw}, effects=effects)
    render_recording(obj.root, out, cfg, progress=False)
    return Recording.open(out)


def _points(rec, cam, t=0, label=None):
    """(N, 3) world points of a camera's frame (the recording's poses), optionally of one link label."""
    c = rec.camera(cam)
    d, seg = rec.depth_m(cam, t), rec.segmentation(cam, t)
    keep = d > 0 if label is None else (d > 0) & (seg == label)
    v, u = np.nonzero(keep)
    z = d[v, u]
    p = np.stack([(u - c.K[0, 2]) * z / c.K[0, 0], (v - c.K[1, 2]) * z / c.K[1, 1], z, np.ones_like(z)])
    return (rec.camera_poses(cam)[t] @ p)[:3].T


def test_flying_pixels_string_a_thin_links_silhouette_out_along_the_rays(printed_object, tmp_path):
    clean = _render(printed_object, tmp_path / "clean")
    fly = _render(printed_object, tmp_path / "fly", parse_effects("flying_pixels"))
    streak, rim = 0, 0
    for cam in ("cam0", "cam2", "cam5"):
        d0, d1, seg = clean.depth_m(cam, 0), fly.depth_m(cam, 0), clean.segmentation(cam, 0)
        changed = d0 != d1
        # only along depth edges: every changed pixel has a neighbour that differs by over 5 % of the nearer
        pad = np.pad(d0, 1)
        nb = np.stack([pad[1:-1, 2:], pad[1:-1, :-2], pad[2:, 1:-1], pad[:-2, 1:-1]])
        near_edge = ((np.abs(nb - d0) > 0.05 * np.minimum(nb, d0)) & (nb > 0)).any(0)
        assert changed.any() and near_edge[changed].all()
        # the background pixels just beside a link: many now read between the link and what is behind it
        link = seg > 0
        beside = ~link & (d0 > 0) & (np.pad(link, 1)[1:-1, 2:] | np.pad(link, 1)[1:-1, :-2])
        link_depth = np.where(np.pad(link, 1)[1:-1, 2:], np.pad(d0, 1)[1:-1, 2:], np.pad(d0, 1)[1:-1, :-2])
        between = beside & (d1 < d0 - 0.005) & (d1 > link_depth + 0.001)
        streak += int(between.sum())
        rim += int(beside.sum())
        # and every changed reading lies between the two surfaces of its edge, on its own pixel's ray
        assert np.all(d1[changed] <= np.maximum(d0, nb.max(0))[changed] + 1e-4)
        assert np.all(d1[changed] >= np.minimum(d0, np.where(nb > 0, nb, np.inf).min(0))[changed] - 1e-4)
    assert rim > 100 and streak > 0.3 * rim, (streak, rim)  # flying_prob 0.6, a mixed depth drawn uniformly
    assert fly.source["effects"]["on"] == ["flying_pixels"] and "effects" not in clean.source


def test_a_sensors_edge_holes_start_at_the_scenes_edges_not_at_its_mixed_readings():
    """The noise model's holes (fitted per edge of the scene) start where the scene's depth steps, not
    at each mixed reading along a link's rim (deeper than the link beside it): with flying pixels on,
    a thin link keeps the pixels it keeps without them (bench seed 31685's Kinect capture: one link
    read 95 pixels in every fourth frame of its first camera, 449 with the scene's edges)."""
    scene = np.full((120, 640), 0.8, np.float32)  # a desk 30 cm behind ... (the sensor's own width)
    scene[:, 300:312] = 0.5  # ... a link 12 pixels wide
    link = scene < 0.6
    noise = load_noise("kinect_v1")
    noise = dataclasses.replace(noise, min_range_m=0.2)
    mixed = flying_pixels(scene, np.random.default_rng(1), 0.6, 2)
    assert (mixed[link] > 0.51).sum() > 100  # the link's rim reads deeper than the link
    kept = {}
    for name, depth, scene_depth in (("plain", scene, None), ("mixed", mixed, scene), ("as_own", mixed, None)):
        kept[name] = int((noise.apply(depth, np.random.default_rng(2), scene_depth)[link] > 0).sum())
    assert kept["mixed"] == kept["plain"] > 0.5 * link.sum(), kept  # the same holes as without mixed readings
    assert kept["as_own"] < 0.7 * kept["plain"], kept  # each mixed reading an edge: the link eaten from its rims


@pytest.mark.parametrize("baseline_m", [0.05, -0.075])
def test_shadow_band_lies_on_the_side_away_from_the_projector(baseline_m):
    fx, z_near, z_far = 500.0, 0.5, 1.0
    depth = np.full((40, 200), z_far, np.float32)
    depth[10:30, 80:120] = z_near  # a box in front of a wall
    mask = shadow_mask(depth, fx, baseline_m)
    width = fx * abs(baseline_m) * (1 / z_near - 1 / z_far)  # 25 px at 5 cm, 37.5 px at 7.5 cm
    cols = np.flatnonzero(mask[20])
    assert not mask[:10].any() and not mask[30:].any() and not mask[:, 80:120].any()  # the box itself is lit
    if baseline_m > 0:  # projector to the right: the wall left of the box is in its shadow
        assert cols.max() == 79 and abs(len(cols) - width) <= 1.5
    else:
        assert cols.min() == 120 and abs(len(cols) - width) <= 1.5
    assert not shadow_mask(depth, fx, 0.0).any()


def test_shadows_in_a_render_fall_only_on_the_far_side_of_edges(printed_object, tmp_path):
    clean = _render(printed_object, tmp_path / "clean")
    shaded = _render(printed_object, tmp_path / "shaded", parse_effects("shadows"))
    lost = 0
    for cam in ("cam1", "cam4"):
        d0, d1 = clean.depth_m(cam, 0), shaded.depth_m(cam, 0)
        gone = (d0 > 0) & (d1 == 0)
        assert np.array_equal(d1[~gone], d0[~gone])  # nothing else changes
        rows, cols = np.nonzero(gone)
        for r, c in zip(rows, cols):  # a nearer surface lies to its right (the projector's side)
            right = d0[r, c + 1 :]
            assert ((right > 0) & (right < d0[r, c] - 1e-3)).any()
        lost += len(rows)
    assert lost > 50
    assert shaded.source["effects"]["drawn"]["baseline_m"] == 0.05  # a clean render: the 5 cm default


def test_dark_links_lose_about_the_configured_fraction(printed_object, tmp_path):
    assert printed_object.spec.colors[2] == "black"  # link 2 is dark, the others not
    effects = dataclasses.replace(parse_effects("dark_plastic"), dark_return=(0.4, 0.4))
    clean = _render(printed_object, tmp_path / "clean")
    dark = _render(printed_object, tmp_path / "dark", effects)
    kept, total = 0, 0
    for cam in [c.name for c in clean.cameras]:
        d0, d1, seg = clean.depth_m(cam, 0), dark.depth_m(cam, 0), clean.segmentation(cam, 0)
        black = seg == 3
        kept += int((d1[black] > 0).sum())
        total += int(black.sum())
        np.testing.assert_array_equal(d1[~black], d0[~black])  # the other links and the table keep every pixel
    assert total > 500 and abs(kept / total - 0.4) < 0.03, (kept, total)
    assert dark.source["effects"]["drawn"]["dark_links"] == [2]


def test_joint_play_tilts_a_links_tip_off_its_layer_by_the_drawn_angle(printed_object, tmp_path):
    effects = dataclasses.replace(parse_effects("joint_play"), joint_tilt_deg=(3.0, 3.0), joint_shift_mm=0.0)
    spec = printed_object.spec
    out = {}
    for name, fx in (("nominal", NO_EFFECTS), ("play", effects)):
        rec = _render(printed_object, tmp_path / name, fx)
        gt = rec.ground_truth()
        T_link1 = forward_kinematics(spec, gt["joint_angles_rad"][0])[1]  # the nominal link 1 frame
        slopes = []
        length = printed_lengths_m(spec)[1]
        for cam in [c.name for c in rec.cameras]:
            p = _points(rec, cam, label=2)  # link 1
            q = (np.linalg.inv(T_link1) @ np.c_[p, np.ones(len(p))].T)[:3].T
            q = q[(q[:, 2] > 0.15 * length) & (q[:, 2] < 0.85 * length)]
            if len(q) > 100:  # one face of the plate, seen along the link: its y against the distance along it
                slopes.append(np.polyfit(q[:, 2], q[:, 1], 1)[0])
        out[name] = (float(np.median(slopes)) * length, gt)
    tip_off_m, gt = out["play"]
    tilt = gt["effects_tilt_deg"]
    assert np.allclose(np.abs(tilt), 3.0)
    # Rx(delta) carries the link's far end to -y: L sin(delta) off its layer (3.3 mm for this 63 mm link)
    want = -length * np.sin(np.radians(tilt[0]))
    assert abs(out["nominal"][0]) < 0.0003
    assert abs(tip_off_m - want) < 0.15 * abs(want), (tip_off_m, want)
    # the ground truth keeps the nominal configuration and records where the geometry went
    np.testing.assert_array_equal(gt["joint_angles_rad"], out["nominal"][1]["joint_angles_rad"])
    np.testing.assert_allclose(
        gt["T_world_link"][0, 1], out["nominal"][1]["T_world_link"][0, 1] @ gt["effects_W_link_geometry"][1], atol=1e-9
    )


def test_print_scale_error_scales_the_measured_object(printed_object, tmp_path):
    effects = dataclasses.replace(parse_effects("print_error"), scale_error=(0.05, 0.05), level_error_deg=(0.0, 0.0))
    heights = {}
    for name, fx in (("cad", NO_EFFECTS), ("print", effects)):
        rec = _render(printed_object, tmp_path / name, fx)
        heights[name] = max(
            _points(rec, c.name, label=k)[:, 2].max(initial=0.0) for c in rec.cameras for k in (1, 2, 3)
        )
    assert rec.ground_truth()["effects_scale"] == pytest.approx(1.05)
    assert heights["print"] / heights["cad"] == pytest.approx(1.05, abs=0.006), heights


def test_d435_noise_grows_with_the_square_of_depth():
    noise = load_noise("realsense_d435")
    rng = np.random.default_rng(0)
    sigma = {}
    for z in (1.0, 2.0, 3.0):
        d = noise.apply(np.full((240, 424), z, np.float32), rng)
        sigma[z] = float(np.std(d[d > 0]))
    assert sigma[1.0] == pytest.approx(0.0038, rel=0.1)
    assert sigma[2.0] / sigma[1.0] == pytest.approx(4.0, rel=0.1)
    assert sigma[3.0] / sigma[1.0] == pytest.approx(9.0, rel=0.1)
    assert noise.ref_width_px == 848


def test_raycast_renderer_draws_what_pybullet_draws(printed_object, tmp_path):
    # both renderers load the same perturbed URDF: the comparison covers the print's effects too
    # (no clutter: pybullet draws a clutter cylinder's top about 1 mm above its nominal height; boxes agree)
    kw = dict(effects=parse_effects("joint_play,print_error"))
    pb = _render(printed_object, tmp_path / "pb", **kw)
    rc = _render(printed_object, tmp_path / "rc", renderer="raycast", **kw)
    assert rc.source["renderer"] == "raycast" and rc.source["sensor_model"] == "open3d-raycast"
    assert rc.source["effects"] == pb.source["effects"]
    np.testing.assert_allclose(rc.ground_truth()["T_world_link"], pb.ground_truth()["T_world_link"], atol=1e-6)
    for cam in [c.name for c in pb.cameras]:
        da, db = pb.depth_m(cam, 0), rc.depth_m(cam, 0)
        sa, sb = pb.segmentation(cam, 0), rc.segmentation(cam, 0)
        both = (da > 0) & (db > 0)
        assert both.sum() > 0.95 * max((da > 0).sum(), (db > 0).sum())
        diff_mm = np.abs(da - db)[both] * 1000
        assert np.median(diff_mm) < 0.5 and np.percentile(diff_mm, 99) < 3.0
        for k in (1, 2, 3):
            iou = ((sa == k) & (sb == k)).sum() / max(((sa == k) | (sb == k)).sum(), 1)
            assert iou > 0.95 or ((sa == k).sum() < 30), (cam, k, iou)


def _same_bytes(a, b):
    files = sorted(q.relative_to(a) for q in a.rglob("*") if q.is_file())
    assert files == sorted(q.relative_to(b) for q in b.rglob("*") if q.is_file())
    return all((a / f).read_bytes() == (b / f).read_bytes() for f in files)


@pytest.mark.parametrize("renderer", ["pybullet", "raycast"])
def test_every_effect_same_seed_same_bytes(printed_object, tmp_path, capsys, renderer):
    argv = ["--path", "handheld", "--resolution", "160x120", "--frames", "3", "--noise", "realsense_sr300"]
    argv += ["--effects", "all", "--renderer", renderer]
    for name, seed in (("a", "5"), ("b", "5"), ("c", "6")):
        assert main(["render", str(printed_object.root), "--out", str(tmp_path / name), *argv, "--seed", seed]) == 0
    assert _same_bytes(tmp_path / "a", tmp_path / "b")
    assert not _same_bytes(tmp_path / "a", tmp_path / "c")
    rec = Recording.open(tmp_path / "a")
    # a recording's source.effects, as a JSON file, replays the same capture
    (tmp_path / "fx.json").write_text(json.dumps(rec.source["effects"]))
    argv[argv.index("all")] = str(tmp_path / "fx.json")
    assert main(["render", str(printed_object.root), "--out", str(tmp_path / "d"), *argv, "--seed", "5"]) == 0
    assert _same_bytes(tmp_path / "a", tmp_path / "d")
    fx = rec.source["effects"]
    assert fx["on"] == list(EFFECTS) and fx["drawn"]["baseline_m"] == 0.05
    lo, hi = ALL_EFFECTS.clutter_count
    assert lo <= len(rec.source["clutter"]) <= hi
    # the recorded poses are a tracker's: a few tenths of a degree and a few millimetres off the true ones
    true, kept = rec.ground_truth()["T_world_camera"], rec.camera_poses("cam0")
    off_mm = np.linalg.norm(true[:, :3, 3] - kept[:, :3, 3], axis=1) * 1000
    cos = (np.einsum("tij,tij->t", true[:, :3, :3], kept[:, :3, :3]) - 1) / 2
    off_deg = np.degrees(np.arccos(np.clip(cos, -1, 1)))
    assert np.all((off_mm > 0.1) & (off_mm < 20)) and np.all(off_deg < 2) and off_deg.max() > 0.02
    assert rec.ground_truth()["effects_scale"] < 1.0  # PLA shrinks
    K = rec.camera("cam0").K
    assert (K[0, 2], K[1, 2]) != (79.5, 59.5)  # the principal point is off the image centre


def test_bad_effects_are_one_line_errors_naming_the_flag(printed_object, tmp_path, capsys):
    out = tmp_path / "rec"
    code = main(["render", str(printed_object.root), "--out", str(out), "--effects", "shadows,wobble"])
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1 and "--effects 'wobble': no such effect" in err
    assert not out.exists()
    (tmp_path / "fx.json").write_text(json.dumps({"dark_return": [0.2, 1.5]}))
    code = main(["render", str(printed_object.root), "--out", str(out), "--effects", str(tmp_path / "fx.json")])
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1 and "fx.json: dark_return (0.2, 1.5): must lie within 0..1" in err
    assert not out.exists()
    bad = dataclasses.replace(ALL_EFFECTS, dark_return=(0.9, 0.2))
    with pytest.raises(Exception, match="effects: dark_return"):
        RenderConfig(effects=bad).validate()


def test_hand_and_desk_wander_more_and_stand_closer(printed_object):
    from spare_twin.sim.handheld import HandheldPath, handheld_poses
    from spare_twin.sim.render import footprint_segments_xy_m
    from spare_twin.sim.render_effects import EffectsRun
    from spare_twin.sim.scene import clutter_radius_m, sample_clutter

    spec = printed_object.spec
    spread = {}
    for name, fx in (("plain", NO_EFFECTS), ("hand", parse_effects("hand"))):
        path = EffectsRun(fx, 3, spec, 640).handheld_path(HandheldPath())
        eye = handheld_poses(path, 80, 3)[:, :3, 3]
        spread[name] = (np.ptp(np.linalg.norm(eye[:, :2], axis=1)), np.ptp(eye[:, 2]))
    assert spread["hand"][0] > 1.5 * spread["plain"][0] and spread["hand"][1] > 1.3 * spread["plain"][1]
    footprint = footprint_segments_xy_m(spec, np.zeros((1, spec.n_links)))
    gaps = []
    for seed in range(8):
        fx = EffectsRun(ALL_EFFECTS, seed, spec, 640)
        items = sample_clutter(fx.clutter_config(0), np.random.default_rng([seed, 0xC1A7]), footprint, 0.006)
        assert 2 <= len(items) <= 5 and len(items) == fx.clutter_drawn
        for item in items:
            c = np.asarray(item["position_m"][:2])
            a, b = footprint[:, 0], footprint[:, 1]
            t = np.clip(((c - a) * (b - a)).sum(1) / np.maximum(((b - a) ** 2).sum(1), 1e-12), 0, 1)
            gaps.append(np.linalg.norm(a + t[:, None] * (b - a) - c, axis=1).min() - clutter_radius_m(item) - 0.006)
    assert min(gaps) >= 0.03 - 1e-9 and min(gaps) < 0.06  # clear of the chain, some only centimetres away


def test_simulated_capture_passes_its_effects_and_renderer_on(printed_object, tmp_path, monkeypatch):
    from spare_twin.capture import simulated

    seen = {}

    def fake_render(object_dir, out, cfg, progress=True):
        seen["cfg"] = cfg
        raise RuntimeError("stop after the render's configuration")

    monkeypatch.setattr(simulated, "render_recording", fake_render)
    cfg = simulated.SensorCaptureConfig(effects=ALL_EFFECTS, renderer="raycast")
    with pytest.raises(RuntimeError, match="stop after"):
        simulated.simulated_capture(printed_object.root, tmp_path, cfg, progress=False)
    assert seen["cfg"].effects == ALL_EFFECTS and seen["cfg"].renderer == "raycast"
    assert simulated.SensorCaptureConfig().effects == NO_EFFECTS  # the capture the project was developed on
