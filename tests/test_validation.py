"""Every input is validated before use, with one shared set of validators (issue 31, deliverable 2).

Each case spoils one input the way the issue's probe did and runs the command end to end in a tmp
folder: it must exit non-zero with one stderr line naming the file (or the flag), no traceback, and
leave every folder as it was (nothing written on refusal)."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from capture_helpers import APC
from conftest import REPO, run_cli

from spare_twin.errors import SpareTwinError

SPARE_TWIN = str(REPO / ".venv" / "bin" / "spare-twin")


def tree(root: Path) -> dict[str, str]:
    """Every path under `root` -> a hash of its content ("dir" for a folder)."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            p = Path(dirpath) / name
            rel = p.relative_to(root).as_posix()
            out[rel] = "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def lines(stderr: str) -> list[str]:
    """The stderr lines a person sees (a progress bar redraws its line with carriage returns)."""
    return [ln.split("\r")[-1] for ln in stderr.split("\n") if ln.split("\r")[-1].strip()]


def refused(argv: list[str], capsys, root: Path, names: str, *also: str) -> str:
    """Run `spare-twin ARGV` in-process: exit 1, one stderr line naming `names` (and `also`), nothing
    under `root` added, removed or changed. Returns the line."""
    before = tree(root)
    code, _, err = run_cli(argv, capsys)
    got = lines(err)
    assert code == 1, (code, err)
    assert len(got) == 1, got
    assert "Traceback" not in err
    for word in (names, *also):
        assert word in got[0], (word, got[0])
    assert tree(root) == before, "the refused command changed the folder"
    return got[0]


# -- poses -----------------------------------------------------------------------------------------


def _scaled(T):
    T = T.copy()
    T[:3, :3] *= 2
    return T


def _sheared(T):
    T = T.copy()
    T[0, 1] += 0.4
    return T


def _bottom_row(T):
    T = T.copy()
    T[3, 0] = 0.5
    return T


def _far(T):
    T = T.copy()
    T[0, 3] = 1e300
    return T


SPOILED_POSES = {
    "scaled-x2": _scaled,
    "zeros": lambda T: np.zeros((4, 4)),
    "sheared": _sheared,
    "bottom-row-0.5": _bottom_row,
    "translation-1e300": _far,
}
POSE_WORDS = {
    "scaled-x2": "orthonormal",
    "zeros": "bottom row",
    "sheared": "orthonormal",
    "bottom-row-0.5": "bottom row",
    "translation-1e300": "translation",
}


@pytest.fixture(scope="module")
def tiny_rec(printed_object, tmp_path_factory):
    """A 1-frame rig render at 32x24 (8 fixed cameras) and a 1-frame hand-held one (per-frame poses)."""
    from spare_twin.sim.render import RenderConfig, render_recording

    root = tmp_path_factory.mktemp("validation_recs")
    render_recording(printed_object.root, root / "rig", RenderConfig(frames=1, resolution="32x24"), progress=False)
    hand = RenderConfig(frames=2, resolution="32x24", path="handheld", motion="static", segmentation=False)
    render_recording(printed_object.root, root / "hand", hand, progress=False)
    return root


@pytest.mark.parametrize("spoil", SPOILED_POSES)
def test_recording_json_pose_must_be_rigid(spoil, tiny_rec, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    shutil.copytree(tiny_rec / "rig", tmp_path / "rec")
    meta_path = tmp_path / "rec" / "recording.json"
    meta = json.loads(meta_path.read_text())
    T = np.asarray(meta["cameras"][3]["T_world_camera"])
    meta["cameras"][3]["T_world_camera"] = SPOILED_POSES[spoil](T).tolist()
    meta_path.write_text(json.dumps(meta))
    line = refused(["capture", "register", "rec"], capsys, tmp_path, "recording.json", "cam3", POSE_WORDS[spoil])
    assert "not a rigid pose" in line


@pytest.mark.parametrize("spoil", SPOILED_POSES)
def test_per_frame_pose_file_must_be_rigid(spoil, tiny_rec, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    shutil.copytree(tiny_rec / "hand", tmp_path / "rec")
    p = tmp_path / "rec" / "cameras" / "cam0" / "T_world_camera.npy"
    poses = np.load(p)
    poses[1] = SPOILED_POSES[spoil](poses[1])
    np.save(p, poses)
    line = refused(["capture", "register", "rec"], capsys, tmp_path, "T_world_camera.npy", POSE_WORDS[spoil])
    assert "pose 1" in line


@pytest.mark.parametrize("spoil", SPOILED_POSES)
def test_import_refuses_a_pose_that_is_not_rigid(spoil, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    src = tmp_path / "scenes"
    src.mkdir()
    for n in (15, 19):
        for kind in ("color.png", "depth.png", "pose.txt"):
            shutil.copy(APC / f"frame-{n:06d}.{kind}", src)
    shutil.copy(APC / "intrinsics.K.txt", src)
    pose = src / "frame-000019.pose.txt"
    np.savetxt(pose, SPOILED_POSES[spoil](np.loadtxt(pose)))
    argv = ["capture", "import", "scenes", "--layout", "7scenes", "--out", "rec"]
    refused(argv, capsys, tmp_path, "frame-000019.pose.txt", POSE_WORDS[spoil])


def test_tum_ground_truth_needs_unit_quaternions_and_plausible_positions(tmp_path):
    from spare_twin.capture.layouts import _tum_pose

    gt = tmp_path / "groundtruth.txt"
    assert np.allclose(_tum_pose("1 2 3 0 0 0 1".split(), gt, 0.5)[:3, 3], (1, 2, 3))
    with pytest.raises(SpareTwinError, match=r"groundtruth.txt: the pose at 0.500000 s: quaternion"):
        _tum_pose("1 2 3 0 0 0 0".split(), gt, 0.5)
    with pytest.raises(SpareTwinError, match=r"groundtruth.txt: the pose at 0.500000 s: not a rigid pose"):
        _tum_pose("1e300 2 3 0 0 0 1".split(), gt, 0.5)


def test_pose_validator_accepts_real_poses_and_names_each_problem():
    from spare_twin.validate import check_pose, check_poses, pose_problem

    T = np.loadtxt(APC / "frame-000015.pose.txt")
    assert pose_problem(T) is None
    assert pose_problem(T.astype(np.float32)) is None  # float32 round-off is within the tolerance
    mirror = np.diag([1.0, 1.0, -1.0, 1.0])
    assert "determinant" in pose_problem(mirror)
    assert "finite" in pose_problem(np.full((4, 4), np.nan))
    with pytest.raises(SpareTwinError, match=r"^here: not a rigid pose \(translation"):
        check_pose(_far(T), "here")
    with pytest.raises(SpareTwinError, match=r"^there: pose 2 is not a rigid pose"):
        check_poses([T, T, _scaled(T)], "there")


# -- JSON --------------------------------------------------------------------------------------------

DEEP = "[" * 5000 + "]" * 5000


def test_deeply_nested_recording_json(tiny_rec, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    shutil.copytree(tiny_rec / "rig", tmp_path / "rec")
    meta_path = tmp_path / "rec" / "recording.json"
    meta_path.write_text(meta_path.read_text()[:-2] + ', "notes": ' + DEEP + "}\n")
    refused(["capture", "register", "rec"], capsys, tmp_path, "recording.json", "nested 5001 deep")


def test_huge_integer_in_recording_json(tiny_rec, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    shutil.copytree(tiny_rec / "rig", tmp_path / "rec")
    meta_path = tmp_path / "rec" / "recording.json"
    meta_path.write_text(meta_path.read_text().replace('"fps": 10.0', '"fps": ' + "9" * 5000))
    refused(["capture", "register", "rec"], capsys, tmp_path, "recording.json", "5000 digits")


def test_deeply_nested_rig_file(printed_object, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "rig.json").write_text('{"cameras": ' + DEEP + "}")
    argv = ["render", str(printed_object.root), "--out", "rec", "--rig", "rig.json", "--frames", "1"]
    refused(argv, capsys, tmp_path, "rig.json", "nested 5001 deep")


def test_huge_integer_in_object_json(printed_object, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    shutil.copytree(printed_object.root, tmp_path / "obj")
    p = tmp_path / "obj" / "object.json"
    d = json.loads(p.read_text())
    p.write_text(json.dumps(d).replace('"seed": ', '"seed": ' + "1" * 5000 + ', "was": ', 1))
    assert "1" * 5000 in p.read_text()
    refused(["render", "obj", "--out", "rec", "--frames", "1"], capsys, tmp_path, "object.json", "5000 digits")


def test_deeply_nested_chain_config(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "chain.json").write_text('{"n_links": 2, "x": ' + DEEP + "}")
    refused(["object", "--config", "chain.json", "--out", "obj"], capsys, tmp_path, "chain.json", "nested")


def test_json_reader_bounds():
    from spare_twin.io import MAX_JSON_DEPTH, json_depth, parse_json

    assert json_depth(json.dumps({"a[": ["]]", [1, {"b": "{{"}]]})) == 4  # brackets in strings do not count
    assert parse_json("[" * MAX_JSON_DEPTH + "]" * MAX_JSON_DEPTH, "f")  # the bound itself is fine
    assert parse_json('{"seed": ' + "9" * 100 + "}", "f")["seed"] == int("9" * 100)
    with pytest.raises(SpareTwinError, match=r"^f: not valid JSON \(nested 65 deep"):
        parse_json("[" * 65 + "]" * 65, "f")
    with pytest.raises(SpareTwinError, match=r"^f: not valid JSON \(an integer of 101 digits"):
        parse_json("[-" + "9" * 101 + "]", "f")
