"""Bad input gives a one-line error naming the file, and never touches an existing recording."""

import shutil

import cv2
import numpy as np
import pytest
from capture_helpers import APC, TUM_PAIR, seven_scenes
from conftest import run_cli


def _import(src, out, capsys, *extra):
    code, stdout, err = run_cli(
        ["capture", "import", str(src), "--layout", "7scenes", "--out", str(out), *extra], capsys
    )
    lines = err.strip().splitlines()
    return code, lines[-1] if lines else "", stdout


def _depth(n):
    return cv2.imread(str(APC / f"frame-{n:06d}.depth.png"), cv2.IMREAD_UNCHANGED)


@pytest.mark.parametrize(
    "case, expect",
    [
        ("missing_depth", "frame-000019.depth.png: missing"),
        ("extra_depth", "frame-000031.depth.png: extra depth frame"),
        ("missing_pose", "frame-000019.pose.txt: missing"),
        ("size_mismatch", "frame-000019.depth.png: size 320x240 does not match"),
        ("empty_depth", "frame-000019.depth.png: depth image is empty"),
        ("corrupt_png", "frame-000019.color.png: not a readable image"),
        ("eight_bit_depth", "frame-000019.depth.png: depth must be a single-channel 16-bit PNG"),
        ("bad_pose", "frame-000019.pose.txt: not a rigid pose (not finite"),
    ],
)
def test_bad_frames(tmp_path, capsys, case, expect):
    src = seven_scenes(tmp_path / "src")
    f = src / "frame-000019"
    if case == "missing_depth":
        (src / "frame-000019.depth.png").unlink()
    elif case == "extra_depth":
        shutil.copy(APC / "frame-000019.depth.png", src / "frame-000031.depth.png")
    elif case == "missing_pose":
        (src / "frame-000019.pose.txt").unlink()
    elif case == "size_mismatch":
        cv2.imwrite(f"{f}.depth.png", cv2.resize(_depth(19), (320, 240), interpolation=cv2.INTER_NEAREST))
    elif case == "empty_depth":
        cv2.imwrite(f"{f}.depth.png", np.zeros((480, 640), np.uint16))
    elif case == "corrupt_png":
        data = (src / "frame-000019.color.png").read_bytes()
        (src / "frame-000019.color.png").write_bytes(data[: len(data) // 3])
    elif case == "eight_bit_depth":
        cv2.imwrite(f"{f}.depth.png", (_depth(19) // 8).astype(np.uint8))
    elif case == "bad_pose":
        (src / "frame-000019.pose.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 1 nan\n0 0 0 1\n")
    code, line, stdout = _import(src, tmp_path / "rec", capsys)
    assert code == 1 and stdout == ""
    assert line.startswith("spare-twin capture: error: ") and expect in line, line
    assert not (tmp_path / "rec").exists()


def test_wrong_depth_scale_is_caught(tmp_path, capsys):
    src = seven_scenes(tmp_path / "src")
    code, line, _ = _import(src, tmp_path / "rec", capsys, "--depth-scale", "1.0")  # mm read as metres: ~400 m
    assert code == 1 and "frame-000015.depth.png: median depth" in line and "wrong --depth-scale" in line
    code, line, _ = _import(TUM_PAIR, tmp_path / "rec", capsys, "--intrinsics", "1,1,0.5,0.5")
    assert code == 1  # a TUM folder is not a 7-Scenes layout
    assert "not a 7-Scenes layout" in line


def test_failed_import_leaves_existing_recording_intact(tmp_path, capsys):
    src = seven_scenes(tmp_path / "src")
    out = tmp_path / "rec"
    code, _, _ = _import(src, out, capsys)
    assert code == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    (src / "frame-000019.color.png").write_bytes(b"\x89PNG broken")
    code, line, _ = _import(src, out, capsys)
    assert code == 1 and "frame-000019.color.png" in line
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert before == after
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".rec.")]  # no temporary left behind


def test_tum_without_intrinsics_and_bad_flags(tmp_path, capsys):
    code, _, err = run_cli(
        ["capture", "import", str(TUM_PAIR), "--layout", "tum", "--out", str(tmp_path / "r")], capsys
    )
    assert code == 1 and "pass --intrinsics fx,fy,cx,cy" in err
    code, _, err = run_cli(
        [
            "capture",
            "import",
            str(TUM_PAIR),
            "--layout",
            "tum",
            "--intrinsics",
            "520,521",
            "--out",
            str(tmp_path / "r"),
        ],
        capsys,
    )
    assert code == 1 and "--intrinsics '520,521'" in err
    code, _, err = run_cli(["capture", "register", str(tmp_path / "nowhere")], capsys)
    assert code == 1 and "nowhere: not a folder" in err
