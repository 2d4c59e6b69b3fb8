"""The twin simulation as a simulated RGB-D sensor: `spare-twin render --path handheld --noise NAME`
writes a recording like a real hand-held capture, and the real-capture chain (register, fuse, find the
object) runs on it."""

import numpy as np
from conftest import FRAMES, run_cli


def test_handheld_recording_looks_like_a_real_capture(handheld_rec, printed_object):
    from spare_twin.recording import Recording

    rec = Recording.open(handheld_rec)
    rec.validate()
    assert rec.rig is None and len(rec.cameras) == 1 and rec.n_frames == FRAMES
    cam = rec.cameras[0]
    assert (cam.width, cam.height) == (320, 240) and cam.poses == "per_frame"
    assert rec.source["kind"] == "sim" and rec.source["sensor_model"] == "realsense_sr300"
    assert rec.depth_scale == 0.001  # the sensor's unit, as an imported RealSense recording has
    gt = rec.ground_truth()
    poses = np.stack([rec.T_world_camera("cam0", t) for t in range(FRAMES)])
    np.testing.assert_allclose(gt["T_world_camera"], poses)
    assert np.ptp(gt["joint_angles_rad"], axis=0).max() == 0  # the object holds still by default
    # one loop round the object, smooth steps, always looking at it
    c = poses[:, :3, 3]
    az = np.unwrap(np.arctan2(c[:, 1], c[:, 0]))
    assert abs(az[-1] - az[0]) > np.radians(300) and np.all(np.diff(az) * np.sign(az[-1] - az[0]) > 0)
    r = np.linalg.norm(c[:, :2], axis=1)
    assert 0.3 < r.min() and r.max() < 0.55 and np.ptp(r) > 0.01 and np.ptp(c[:, 2]) > 0.01
    K = cam.K
    for T in poses:
        p = np.linalg.inv(T) @ np.array([0, 0, 0.08, 1.0])  # the chain's middle projects near the centre
        u, v = K[0, 0] * p[0] / p[2] + K[0, 2], K[1, 1] * p[1] / p[2] + K[1, 2]
        assert abs(u - 160) < 50 and abs(v - 120) < 50
    # sensor noise: millimetre steps, holes at the object's depth edges
    d = rec.depth_m("cam0", 0)
    assert np.allclose(d[d > 0] * 1000, np.round(d[d > 0] * 1000), atol=1e-3)
    seg = rec.segmentation("cam0", 0)
    assert (d[seg > 0] == 0).mean() > 0.02  # some object pixels lost, as a real sensor loses them at edges
    assert (d > 0).mean() > 0.4


def test_render_sensor_options_and_errors(printed_object, tmp_path, capsys):
    from spare_twin.recording import Recording

    out = tmp_path / "hidden"
    code, _, err = run_cli(
        [
            "render",
            str(printed_object.root),
            "--out",
            str(out),
            "--path",
            "handheld",
            "--frames",
            "2",
            "--resolution",
            "64x48",
            "--hide-poses",
            "--noise",
            "none",
        ],
        capsys,
    )
    assert code == 0, err
    rec = Recording.open(out)
    assert rec.cameras[0].poses == "unknown" and rec.T_world_camera("cam0", 0) is None
    assert rec.ground_truth()["T_world_camera"].shape == (2, 4, 4) and rec.depth_scale == 1e-4
    for bad, word in (
        (["--noise", "nosuchsensor"], "nosuchsensor"),
        (["--resolution", "huge"], "--resolution"),
        (["--hide-poses"], "--hide-poses"),
    ):
        code, out_, err = run_cli(
            ["render", str(printed_object.root), "--out", str(tmp_path / "x"), "--frames", "1", *bad], capsys
        )
        lines = err.strip().splitlines()
        assert code == 1 and out_ == "" and word in lines[-1] and "Traceback" not in err
    assert not (tmp_path / "x").exists()


def test_register_finds_the_object_on_the_simulated_sensor(registered_rec, printed_object):
    from spare_twin.capture.pipeline import fuse_recording
    from spare_twin.recording import Recording

    root, res = registered_rec
    assert res["object"] is not None and res["used_reference"] is True
    pts, cols, T_wo = fuse_recording(root)
    height = printed_object.spec.link_lengths_pu[0] * printed_object.spec.print_scale  # at least the base post
    assert len(pts) > 500 and pts[:, 2].max() > 0.8 * height
    assert abs(T_wo[2, 3]) < 0.005 and T_wo[2, 2] > 0.999  # the table is z = 0 of the sim world
    assert np.linalg.norm(np.median(pts[:, :2], axis=0)) < 0.1  # near the base, which stands at the origin
    assert Recording.open(root).registration.object["points"] == len(pts)
