"""`spare-twin render`: a complete recording that the recording reader returns."""

import json

import numpy as np
import pytest

from spare_twin.cli import main
from spare_twin.object import folder as objects
from spare_twin.recording import Recording


def test_render_writes_a_complete_recording(tmp_path, capsys):
    from spare_twin.config import sample_chain

    obj = objects.build_object(sample_chain(2, 5), tmp_path / "obj", preview=False)
    rc = main(["render", str(obj.root), "--out", str(tmp_path / "rec"), "--frames", "3", "--resolution", "network"])
    assert rc == 0
    assert "wrote" in capsys.readouterr().out
    rec = Recording.open(tmp_path / "rec")
    rec.validate()
    assert rec.n_frames == 3 and len(rec.cameras) == 8 and rec.fps == 10.0
    assert rec.source["kind"] == "sim" and rec.rig == "spare8"
    assert rec.object_config["n_links"] == 2
    cam = rec.cameras[0]
    assert (cam.height, cam.width) == (96, 128) and cam.T_world_camera.shape == (4, 4)
    d = rec.depth_m("cam0", 2)
    seg = rec.segmentation("cam0", 2)
    assert d.dtype == np.float32 and 0.2 < d[d > 0].min() < 0.6 and set(np.unique(seg)) <= {0, 1, 2, 3}
    assert (seg > 0).any() and (d[seg > 0] > 0).all()
    gt = rec.ground_truth()
    assert gt["joint_angles_rad"].shape == (3, 2) and gt["T_world_link"].shape == (3, 3, 4, 4)
    assert np.allclose(gt["link_lengths_pu"], obj.spec.link_lengths_pu)
    meta = json.loads((tmp_path / "rec" / "recording.json").read_text())
    assert meta["format"] == "spare-twin-recording"


def test_render_bad_object_dir_is_one_line_error(tmp_path, capsys):
    assert main(["render", str(tmp_path / "nope"), "--out", str(tmp_path / "rec")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope" in err[0]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--frames", "0"], "--frames 0: must be a whole number, at least 1"),
        (["--fps", "-1"], "--fps -1.0: must be a positive number"),
        (["--fps", "inf"], "--fps inf: must be a positive number"),
        (["--seed", "-1"], "--seed -1: must be a non-negative integer"),
        (["--resolution", "8x8"], "--resolution '8x8': width and height must be within 16..4096"),
        (["--rig", "nope"], "--rig 'nope': no such rig"),
        (["--noise", "nope"], "--noise 'nope': no such noise model"),
        (["--hide-poses"], "--hide-poses: only for a hand-held path"),
        (["--path", "handheld", "--sweep-deg", "20"], "--sweep-deg 20.0: must be within 30..360 degrees"),
        (["--path", "handheld", "--sweep-deg", "nan"], "--sweep-deg nan: must be within 30..360 degrees"),
        (["--sweep-deg", "180"], "--sweep-deg: only for a hand-held path"),
        (["--path", "handheld", "--distance", "0.1"], "--distance 0.1: must be within 0.2..3 metres"),
        (["--distance", "1"], "--distance: only for a hand-held path"),
        (["--clutter", "-1"], "--clutter -1: must be a whole number, 0..8"),
        (["--clutter", "9"], "--clutter 9: must be a whole number, 0..8"),
    ],
)
def test_bad_options_are_one_line_errors_naming_the_flag(tmp_path, capsys, argv, message):
    from spare_twin.config import sample_chain

    obj = objects.build_sim_twin(sample_chain(1, 0), tmp_path / "obj")
    assert main(["render", str(obj.root), "--out", str(tmp_path / "rec"), *argv]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "rec").exists()


# -- hand-held arcs, clutter and the empty table ----------------------------------------------------------
SMALL = ["--path", "handheld", "--resolution", "160x120", "--noise", "none", "--seed", "4"]


def _render(obj, out, *argv):
    assert main(["render", str(obj.root), "--out", str(out), *argv]) == 0
    return Recording.open(out)


def _azimuth_span_deg(T_world_camera):
    c = T_world_camera[:, :3, 3]
    az = np.unwrap(np.arctan2(c[:, 1], c[:, 0]))
    return np.degrees(az[-1] - az[0]), np.diff(az)


@pytest.mark.parametrize("sweep, frames", [(120.0, 9), (250.0, 6), (360.0, 8)])
def test_handheld_path_covers_the_asked_sweep(printed_object, tmp_path, capsys, sweep, frames):
    rec = _render(printed_object, tmp_path / "rec", *SMALL, "--frames", str(frames), "--sweep-deg", str(sweep))
    assert f"({sweep:g} deg)" in capsys.readouterr().out
    span, steps = _azimuth_span_deg(rec.ground_truth()["T_world_camera"])
    # an arc runs from its first frame to its last; a loop stops one step short of closing; the aim wanders
    # about 1.5 cm at 0.42 m, so the azimuth about the base axis is good to a few degrees
    want = sweep if sweep < 360 else sweep * (frames - 1) / frames
    assert abs(abs(span) - want) < 4.0, (span, want)
    assert np.all(steps * np.sign(span) > 0)  # one way round, never back


def _points_world(rec, t):
    """(N, 3) world points of frame t (true poses), and the segmentation of those pixels."""
    cam = rec.cameras[0]
    d, seg = rec.depth_m("cam0", t), rec.segmentation("cam0", t)
    v, u = np.nonzero(d > 0)
    z = d[v, u]
    K = cam.K
    p = np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z, np.ones_like(z)])
    T = rec.ground_truth()["T_world_camera"][t]
    return (T @ p)[:3].T, seg[v, u]


def test_clutter_stands_on_the_table_clear_of_the_object(printed_object, tmp_path):
    from spare_twin.sim.render import footprint_segments_xy_m
    from spare_twin.sim.scene import clutter_radius_m

    bare = _render(printed_object, tmp_path / "bare", *SMALL, "--frames", "6")
    busy = _render(printed_object, tmp_path / "busy", *SMALL, "--frames", "6", "--clutter", "4")
    items = busy.source["clutter"]
    assert len(items) == 4 and "clutter" not in bare.source
    assert {i["shape"] for i in items} <= {"box", "cylinder"}
    # the same motion and path: clutter has a seed stream of its own
    np.testing.assert_array_equal(bare.ground_truth()["T_world_camera"], busy.ground_truth()["T_world_camera"])
    np.testing.assert_array_equal(bare.ground_truth()["joint_angles_rad"], busy.ground_truth()["joint_angles_rad"])
    segs = footprint_segments_xy_m(printed_object.spec, busy.ground_truth()["joint_angles_rad"])
    for item in items:
        c, rad = np.asarray(item["position_m"][:2]), clutter_radius_m(item)
        extents = 2 * np.asarray(item["half_extents_m"])
        assert np.all((extents > 0.019) & (extents < 0.121))
        assert 0.12 <= np.linalg.norm(c) - rad and np.linalg.norm(c) + rad <= 0.35
        a, b = segs[:, 0], segs[:, 1]
        t = np.clip(((c - a) * (b - a)).sum(1) / np.maximum(((b - a) ** 2).sum(1), 1e-12), 0, 1)
        assert np.linalg.norm(a + t[:, None] * (b - a) - c, axis=1).min() > rad + 0.02
    # in depth: points above the table that are not the object are the clutter, and only there
    seen = np.zeros(len(items), bool)
    for t in range(6):
        for rec, has_clutter in ((bare, False), (busy, True)):
            pts, seg = _points_world(rec, t)
            other = pts[(seg == 0) & (pts[:, 2] > 0.004)]
            if not has_clutter:
                assert len(other) < 5, len(other)
                continue
            dist = np.stack([np.linalg.norm(other[:, :2] - i["position_m"][:2], axis=1) for i in items])
            reach = np.array([clutter_radius_m(i) for i in items])[:, None] + 0.004
            assert np.all((dist <= reach).any(0))  # every such point is on some clutter item
            tall = np.array([2 * i["half_extents_m"][2] for i in items])[:, None] + 0.004
            assert np.all(other[:, 2] <= tall.max())
            seen |= ((dist <= reach) & (other[:, 2] > 0.004)).sum(1) > 20
    assert seen.sum() >= 3  # the items are in view (one may hide behind another all along a short path)


def test_empty_table_is_the_same_scene_without_the_object(printed_object, tmp_path, capsys):
    argv = [*SMALL, "--frames", "4", "--clutter", "2", "--sweep-deg", "200"]
    full = _render(printed_object, tmp_path / "full", *argv)
    empty = _render(printed_object, tmp_path / "empty", *argv, "--empty")
    assert "no object on the table" in capsys.readouterr().out
    empty.validate()
    assert empty.object_config is None and empty.source["object"] is False
    gt = empty.ground_truth()
    assert set(gt) == {"T_world_camera"}  # no n_links, no lengths, no joint angles: nothing to find
    np.testing.assert_array_equal(gt["T_world_camera"], full.ground_truth()["T_world_camera"])
    assert empty.source["clutter"] == full.source["clutter"]
    object_pixels = 0
    for t in range(4):
        seg_full, seg_empty = full.segmentation("cam0", t), empty.segmentation("cam0", t)
        assert not seg_empty.any()
        object_pixels += int((seg_full > 0).sum())
        # where the object is not, the two renders see the same depth; where it is, the empty one sees past it
        d_full, d_empty = full.depth_m("cam0", t), empty.depth_m("cam0", t)
        np.testing.assert_array_equal(d_full[seg_full == 0], d_empty[seg_full == 0])
        behind = d_empty[seg_full > 0]
        assert np.all((behind == 0) | (behind > d_full[seg_full > 0] - 1e-6))  # table, clutter or nothing
        pts, _ = _points_world(empty, t)
        near_axis = pts[np.linalg.norm(pts[:, :2], axis=1) < 0.1]
        assert np.all(near_axis[:, 2] < 0.004)  # nothing stands where the object stood
    assert object_pixels > 200


def test_same_seed_same_bytes(printed_object, tmp_path):
    argv = [*SMALL, "--frames", "3", "--clutter", "3", "--sweep-deg", "150", "--noise", "kinect_v1", "--hide-poses"]
    a = _render(printed_object, tmp_path / "a", *argv)
    b = _render(printed_object, tmp_path / "b", *argv)
    files = sorted(q.relative_to(a.root) for q in a.root.rglob("*") if q.is_file())
    assert files == sorted(q.relative_to(b.root) for q in b.root.rglob("*") if q.is_file())
    for f in files:
        assert (a.root / f).read_bytes() == (b.root / f).read_bytes(), f
    # a sensor with a 1 m minimum range is held beyond it, and still sees the object
    T = a.ground_truth()["T_world_camera"]
    assert np.linalg.norm(T[:, :3, 3] - [0, 0, 0.09], axis=1).mean() > 1.2
    assert any((a.depth_m("cam0", t) > 0).mean() > 0.2 for t in range(3))
