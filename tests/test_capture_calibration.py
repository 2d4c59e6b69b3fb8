"""ChArUco: board files at true print size, pose recovery from a synthetic view, depth refinement, calibrate."""

import json

import numpy as np
import pytest
from conftest import run_cli
from scipy.spatial.transform import Rotation

K = np.array([[600.0, 0, 320], [0, 600, 240], [0, 0, 1]])


def _pose(euler_deg, t):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", euler_deg, degrees=True).as_matrix()
    T[:3, 3] = t
    return T


def _err(A, B):
    E = np.linalg.inv(A) @ B
    return np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1))), 1000 * np.linalg.norm(E[:3, 3])


@pytest.mark.parametrize("euler, t", [([15, -20, 5], [-0.12, -0.08, 0.55]), ([-30, 10, 80], [0.05, -0.1, 0.7])])
def test_board_pose_from_synthetic_view(euler, t):
    from spare_twin.capture.board import BoardSpec, board_pose, render_board_view

    spec = BoardSpec()
    T = _pose(euler, t)
    img, _ = render_board_view(spec, K, T, 640, 480)
    pose = board_pose(img, K, spec, source="synthetic")
    rot, trans = _err(T, pose.T_camera_board)
    assert pose.corners >= 15 and pose.reprojection_px < 0.5
    assert rot < 0.3 and trans < 2.0, (rot, trans)


def test_depth_refinement_fixes_distance():
    from spare_twin.capture.board import BoardPose, BoardSpec, refine_with_depth, render_board_view

    spec = BoardSpec()
    T = _pose([20, 10, 0], [-0.1, -0.07, 0.6])
    _, depth = render_board_view(spec, K, T, 640, 480)
    wrong = T.copy()
    # 2 deg tilt about the board's own x axis (depth cannot see an in-plane turn, so none is added)
    wrong[:3, :3] = T[:3, :3] @ Rotation.from_euler("x", 2, degrees=True).as_matrix()
    wrong[:3, 3] += 0.01 * T[:3, 2]  # 1 cm along the board normal
    refined = refine_with_depth(BoardPose(wrong, 24, 0.1), depth, K, spec)
    rot, trans = _err(T, refined.T_camera_board)
    assert refined.depth["points"] > 1000
    assert rot < 0.05 and trans < 3.0, (rot, trans, refined.depth)
    n = refined.T_camera_board[:3, 2]
    assert abs(n @ (refined.T_camera_board[:3, 3] - T[:3, 3])) < 1e-4  # on the true plane


def test_board_files_at_true_size(tmp_path, capsys):
    from PIL import Image

    code, out, err = run_cli(["capture", "board", "--out", str(tmp_path), "--json"], capsys)
    assert code == 0, err
    info = json.loads(out)
    png = Image.open(info["png"])
    assert png.size == (3508, 2480) and round(png.info["dpi"][0]) == 300  # A4 landscape at 300 dpi
    assert info["size_m"] == pytest.approx([0.245, 0.175])
    pdf = (tmp_path / "board.pdf").read_bytes()
    import re

    box = re.search(rb"/MediaBox \[ ?0 0 ([\d.]+) ([\d.]+) ?\]", pdf)
    assert pdf.startswith(b"%PDF") and box
    assert [float(v) / 72 * 25.4 for v in box.groups()] == pytest.approx([297, 210], abs=0.5)  # A4 landscape, mm
    # the board in the PNG is 245 mm wide: count dark columns along its first row of squares
    a = np.asarray(png.convert("L")) < 128
    rows = np.flatnonzero(a.any(axis=1))
    cols = np.flatnonzero(a[rows[0] + 10])
    assert abs((cols.max() - cols.min() + 1) / 300 * 25.4 - 245) < 0.5


def test_calibrate_command_on_a_synthetic_two_camera_rig(tmp_path, capsys):
    """Two fixed cameras see the board lying on the table; calibrate recovers their world poses."""
    import cv2

    from spare_twin.capture.board import T_WORLD_BOARD, BoardSpec, render_board_view
    from spare_twin.recording import Camera, Recording, RecordingWriter

    spec = BoardSpec()
    T_cb = {"a": _pose([25, 10, 0], [-0.12, -0.06, 0.6]), "b": _pose([-20, -15, 30], [-0.1, -0.05, 0.65])}
    cams = [Camera(n, 640, 480, K, None, "unknown") for n in T_cb]
    with RecordingWriter(
        tmp_path / "rig", cams, 1, 10.0, {"kind": "sensor", "sensor_model": "synthetic"}, depth_scale=0.001
    ) as w:
        for n, T in T_cb.items():
            img, depth = render_board_view(spec, K, T, 640, 480)
            w.add_frame(n, 0, cv2.cvtColor(img, cv2.COLOR_GRAY2RGB), depth)
    code, out, err = run_cli(["capture", "calibrate", str(tmp_path / "rig"), "--json"], capsys)
    assert code == 0, err
    rec = Recording.open(tmp_path / "rig")
    for n, T in T_cb.items():
        want = T_WORLD_BOARD @ np.linalg.inv(T)
        got = rec.camera(n).T_world_camera
        rot, trans = _err(want, got)
        assert rec.camera(n).poses == "fixed" and rot < 0.3 and trans < 3.0, (n, rot, trans)
        assert got[2, 3] > 0.4  # cameras above the table (world z up)


def test_board_not_found_is_one_line(tmp_path, capsys):
    from spare_twin.capture.board import BoardSpec, board_pose
    from spare_twin.errors import SpareTwinError

    with pytest.raises(SpareTwinError, match=r"^blank\.png: ChArUco board not found \(0 corners"):
        board_pose(np.full((480, 640), 128, np.uint8), K, BoardSpec(), source="blank.png")
