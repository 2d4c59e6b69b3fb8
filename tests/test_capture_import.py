"""Importers on real frames: depth kept as the sensor's integers, colour bytes copied, poses read."""

import json
import shutil

import cv2
import numpy as np
import pytest
from capture_helpers import APC, APC_FRAMES, TUM_K, TUM_PAIR
from conftest import run_cli


def test_import_7scenes_keeps_depth_colour_and_poses(tmp_path, capsys):
    code, out, err = run_cli(
        ["capture", "import", str(APC), "--layout", "7scenes", "--out", str(tmp_path / "rec"), "--json"], capsys
    )
    assert code == 0, err
    info = json.loads(out)  # exactly one JSON object on stdout
    assert info["frames"] == len(APC_FRAMES) and info["poses"] == "per_frame" and info["depth_scale"] == 0.001
    from spare_twin.recording import Recording

    rec = Recording.open(tmp_path / "rec")
    rec.validate()
    K = np.loadtxt(APC / "intrinsics.K.txt")
    assert np.allclose(rec.cameras[0].K, K)
    for i, n in enumerate(APC_FRAMES):
        src_depth = cv2.imread(str(APC / f"frame-{n:06d}.depth.png"), cv2.IMREAD_UNCHANGED)
        got = cv2.imread(str(rec.path("cam0", "depth", i)), cv2.IMREAD_UNCHANGED)
        assert got.dtype == np.uint16 and np.array_equal(got, src_depth)  # not re-quantised
        assert rec.path("cam0", "color", i).read_bytes() == (APC / f"frame-{n:06d}.color.png").read_bytes()
        assert np.allclose(rec.T_world_camera("cam0", i), np.loadtxt(APC / f"frame-{n:06d}.pose.txt"))
    assert rec.source["source_frames"] == [f"frame-{n:06d}" for n in APC_FRAMES]
    d = rec.depth_m("cam0", 0)
    assert 0.3 < np.median(d[d > 0]) < 0.6  # the shelf bin is ~0.4 m away


def test_import_tum_pair_with_intrinsics(tmp_path, capsys):
    code, out, err = run_cli(
        [
            "capture",
            "import",
            str(TUM_PAIR),
            "--layout",
            "tum",
            "--intrinsics",
            TUM_K,
            "--out",
            str(tmp_path / "tum"),
            "--json",
        ],
        capsys,
    )
    assert code == 0, err
    info = json.loads(out)
    assert info["frames"] == 2 and info["poses"] == "unknown" and info["depth_scale"] == pytest.approx(1 / 5000)
    from spare_twin.recording import Recording

    rec = Recording.open(tmp_path / "tum")
    assert np.allclose(rec.cameras[0].K, [[520.9, 0, 325.1], [0, 521.0, 249.7], [0, 0, 1]])
    raw = cv2.imread(str(TUM_PAIR / "2_depth.png"), cv2.IMREAD_UNCHANGED)
    assert np.allclose(rec.depth_m("cam0", 1), raw.astype(np.float32) / 5000)


def test_import_tum_lists_with_groundtruth(tmp_path):
    """The full TUM layout: rgb.txt/depth.txt association (one unmatched colour frame skipped) + groundtruth."""
    from spare_twin.capture.frames import parse_intrinsics_arg
    from spare_twin.capture.importers import ImportOptions, import_folder

    src = tmp_path / "tum_seq"
    (src / "rgb").mkdir(parents=True)
    (src / "depth").mkdir()
    for k, t in (("1", 100.000), ("2", 100.033)):
        shutil.copy(TUM_PAIR / f"{k}.png", src / "rgb" / f"{t:.6f}.png")
        shutil.copy(TUM_PAIR / f"{k}_depth.png", src / "depth" / f"{t + 0.004:.6f}.png")
    (src / "rgb.txt").write_text(
        "# timestamp filename\n100.000000 rgb/100.000000.png\n100.033000 rgb/100.033000.png\n"
        "100.500000 rgb/missing-depth.png\n"
    )
    (src / "depth.txt").write_text("100.004000 depth/100.004000.png\n100.037000 depth/100.037000.png\n")
    (src / "groundtruth.txt").write_text(
        "# timestamp tx ty tz qx qy qz qw\n100.001 1 2 3 0 0 0 1\n100.034 1.1 2 3 0 0 0.7071068 0.7071068\n"
    )
    rec = import_folder(src, "tum", tmp_path / "rec", ImportOptions(K=parse_intrinsics_arg(TUM_K), progress=False))
    assert rec.n_frames == 2 and rec.cameras[0].poses == "per_frame"
    T1 = rec.T_world_camera("cam0", 1)
    assert np.allclose(T1[:3, 3], [1.1, 2, 3]) and np.allclose(
        T1[:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-6
    )
    assert np.allclose(rec.timestamps_s, [0.0, 0.033])


def test_import_open3d_recorder_folder(tmp_path):
    """color/*.jpg + depth/*.png + camera_intrinsic.json (open3d: column-major intrinsic_matrix)."""
    from spare_twin.capture.importers import ImportOptions, import_folder

    src = tmp_path / "o3d"
    (src / "color").mkdir(parents=True)
    (src / "depth").mkdir()
    for i, n in enumerate(APC_FRAMES[:2]):
        bgr = cv2.imread(str(APC / f"frame-{n:06d}.color.png"))
        cv2.imwrite(str(src / "color" / f"{i:06d}.jpg"), bgr)
        shutil.copy(APC / f"frame-{n:06d}.depth.png", src / "depth" / f"{i:06d}.png")
    K = np.loadtxt(APC / "intrinsics.K.txt")
    (src / "camera_intrinsic.json").write_text(
        json.dumps({"width": 640, "height": 480, "intrinsic_matrix": K.T.ravel().tolist()})
    )
    rec = import_folder(src, "open3d", tmp_path / "rec", ImportOptions(progress=False))
    assert rec.n_frames == 2 and rec.depth_scale == 0.001 and rec.cameras[0].poses == "unknown"
    assert np.allclose(rec.cameras[0].K, K)
    assert rec.color("cam0", 0).shape == (480, 640, 3)


def test_bag_without_hardware_reports_clearly(tmp_path, capsys):
    """open3d cannot write .bag files, so only the error paths are testable without a camera."""
    bad = tmp_path / "broken.bag"
    bad.write_bytes(b"not a rosbag")
    code, out, err = run_cli(["capture", "import", str(bad), "--layout", "bag", "--out", str(tmp_path / "r")], capsys)
    assert code == 1 and "broken.bag" in err and len(err.strip().splitlines()) == 1 and out == ""
    code, out, err = run_cli(
        ["capture", "import", str(tmp_path / "none.bag"), "--layout", "bag", "--out", str(tmp_path / "r")], capsys
    )
    assert code == 1 and "none.bag: no such file" in err
    assert not (tmp_path / "r").exists()


def test_record_without_device_is_one_line(tmp_path, capsys):
    code, out, err = run_cli(["capture", "record", "--out", str(tmp_path / "live"), "--json"], capsys)
    assert code == 1 and out == ""
    assert err.strip().splitlines()[-1].startswith("spare-twin capture: error: no Intel RealSense device found")
    assert not (tmp_path / "live").exists()
