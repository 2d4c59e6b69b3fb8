"""Every input is validated before use, with one shared set of validators (issue 31, deliverable 2).

Each case spoils one input the way the issue's probe did and runs the command end to end in a tmp
folder: it must exit non-zero with one stderr line naming the file (or the flag), no traceback, and
leave every folder as it was (nothing written on refusal)."""

from __future__ import annotations

import json
import os
import shutil
import signal
from pathlib import Path

import numpy as np
import pytest
from capture_helpers import APC, seven_scenes
from conftest import REPO, interrupt_pool, run_cli, stderr_lines, tree

from spare_twin.errors import SpareTwinError

SPARE_TWIN = str(REPO / ".venv" / "bin" / "spare-twin")


def refused(argv: list[str], capsys, root: Path, names: str, *also: str) -> str:
    """Run `spare-twin ARGV` in-process: exit 1, one stderr line naming `names` (and `also`), nothing
    under `root` added, removed or changed. Returns the line."""
    before = tree(root)
    code, _, err = run_cli(argv, capsys)
    got = stderr_lines(err)
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
    src = seven_scenes(tmp_path / "scenes")
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


# -- checkpoints -------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny_checkpoint(tmp_path_factory):
    """A small, untrained but well-formed count network checkpoint."""
    from spare_twin.nets import checkpoint as ckpt
    from spare_twin.nets.presets import resolve
    from spare_twin.nets.registry import build_model

    preset = resolve("conv3d-depth-mv-count", {"net": {"channels": [4, 8], "fc_hidden": 16}})
    model = build_model(preset.net)
    path = tmp_path_factory.mktemp("ckpt") / "good.pt"
    meta = ckpt.new_meta("data", "spare8", 0, "test")
    return ckpt.save(path, ckpt.model_record(preset.name, preset.net, preset.train, model, meta))


def _spoil_checkpoint(src: Path, dst: Path, spoil) -> None:
    import torch

    ck = torch.load(src, weights_only=True)
    spoil(ck)
    torch.save(ck, dst)


def _nan_weight(ck):
    name = next(k for k, v in ck["state_dict"].items() if v.is_floating_point() and v.numel() > 1)
    ck["state_dict"][name][0] = float("nan")


def _other_shape(ck):
    ck["net"]["channels"] = [8, 16]


SPOILED_CHECKPOINTS = {
    "nan-weight": (_nan_weight, "is not finite"),
    "no-net": (lambda ck: ck.pop("net"), "no 'net'"),
    "no-state-dict": (lambda ck: ck.pop("state_dict"), "no 'state_dict'"),
    "state-dict-a-list": (lambda ck: ck.update(state_dict=[1, 2]), "'state_dict' must be a dict"),
    "weights-of-another-shape": (_other_shape, "weights do not fit"),
    "net-not-a-config": (lambda ck: ck["net"].update(grid=5), "net: not a network configuration"),
}


@pytest.mark.parametrize("spoil", SPOILED_CHECKPOINTS)
def test_checkpoint_structure_and_finite_weights(spoil, tiny_checkpoint, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "data").mkdir()
    how, words = SPOILED_CHECKPOINTS[spoil]
    _spoil_checkpoint(tiny_checkpoint, tmp_path / "bad.pt", how)
    refused(["evaluate", "--model", "bad.pt", "--data", "data"], capsys, tmp_path, "bad.pt", words)


def test_a_well_formed_checkpoint_loads(tiny_checkpoint):
    from spare_twin.nets.checkpoint import load_model

    model, net, ck = load_model(tiny_checkpoint)
    assert net.arch == ck["net"]["arch"] and not model.training


# -- URDFs -------------------------------------------------------------------------------------------


def _urdf(obj: Path) -> Path:
    return next(obj.glob("*.urdf"))


def _joint_fixed(text: str) -> str:
    start = text.index('<joint name="joint2"')
    return text[:start] + text[start:].replace('type="revolute"', 'type="fixed"', 1)


def _joint_deleted(text: str) -> str:
    start = text.index('<joint name="joint2"')
    end = text.index("</joint>", start) + len("</joint>")
    return text[:start] + text[end:]


def _child_link0(text: str) -> str:
    start = text.index('<joint name="joint2"')
    return text[:start] + text[start:].replace('<child link="link2"/>', '<child link="link0"/>', 1)


def _mesh_missing(text: str) -> str:
    return text.replace('filename="link2.stl"', 'filename="link2_gone.stl"')


def _nan_origin(text: str) -> str:
    start = text.index('<joint name="joint2"')
    head, tail = text[:start], text[start:]
    i = tail.index('xyz="') + len('xyz="')
    return head + tail[:i] + "nan " + tail[tail.index(" ", i) + 1 :]


SPOILED_URDFS = {
    "joint2-fixed": (_joint_fixed, "joint joint2 is 'fixed', must be 'revolute'"),
    "joint2-deleted": (_joint_deleted, "no joint named joint2"),
    "joint2-child-link0": (_child_link0, "joint joint2 joins link1 -> link0, must join link1 -> link2"),
    "mesh-missing": (_mesh_missing, "mesh 'link2_gone.stl': no such file"),
    "nan-origin": (_nan_origin, "must be finite numbers"),
}


@pytest.mark.parametrize("spoil", SPOILED_URDFS)
def test_render_checks_the_urdf_against_the_object(spoil, printed_object, tmp_path, capsys, monkeypatch):
    """Today: `fixed` renders with exit 0 and wrong ground truth; a deleted joint or a loop is SIGSEGV."""
    monkeypatch.chdir(tmp_path)
    shutil.copytree(printed_object.root, tmp_path / "obj")
    how, words = SPOILED_URDFS[spoil]
    urdf = _urdf(tmp_path / "obj")
    spoiled = how(urdf.read_text())
    assert spoiled != urdf.read_text()
    urdf.write_text(spoiled)
    argv = ["render", "obj", "--out", "rec", "--frames", "1", "--resolution", "32x24"]
    refused(argv, capsys, tmp_path, urdf.name, words)


def test_the_twin_checks_the_urdf_before_pybullet(printed_object, tmp_path):
    """Every pybullet load goes through the check (the dataset's sequences too), not only render's."""
    from spare_twin.object.folder import load_object
    from spare_twin.sim.twin import Twin

    shutil.copytree(printed_object.root, tmp_path / "obj")
    urdf = _urdf(tmp_path / "obj")
    urdf.write_text(_child_link0(urdf.read_text()))
    with Twin() as twin, pytest.raises(SpareTwinError, match="must join link1 -> link2"):
        twin.load(load_object(tmp_path / "obj"))


def test_urdf_check_accepts_every_built_object(object_dirs):
    from spare_twin.object.urdf import check_urdf

    for n, obj in object_dirs.items():
        check_urdf(obj.urdf_path, n)


# -- sizes, counts and workers -----------------------------------------------------------------------


@pytest.mark.parametrize(
    "argv, words",
    [
        (["render", "OBJ", "--out", "rec", "--frames", str(10**12)], "--frames 1000000000000: at most 999,999"),
        (["dataset", "--out", "data", "--instances", "2", "--frames", str(10**12)], "--frames 1000000000000: at most"),
        (["dataset", "--out", "data", "--instances", str(10**12)], "--instances 1000000000000: at most 999,999"),
        (["dataset", "--out", "data", "--instances", "2", "--frames", "9000"], "--frames 9000: at most"),
        (["dataset", "--out", "data", "--instances", "2", "--frames", "0"], "--frames 0: must be a whole number"),
    ],
    ids=["render-frames", "dataset-frames", "dataset-instances", "dataset-frames-over-memory", "dataset-frames-0"],
)
def test_sizes_and_counts_are_bounded_before_anything_is_written(
    argv, words, printed_object, tmp_path, capsys, monkeypatch
):
    from spare_twin import validate

    monkeypatch.chdir(tmp_path)
    # a 1 GiB machine: 9,000 frames of 8 network images (393 kB a frame) no longer fit in half of it
    monkeypatch.setattr(validate, "memory_bytes", lambda: 2**30)
    argv = [str(printed_object.root) if a == "OBJ" else a for a in argv]
    refused(argv, capsys, tmp_path, words)
    assert not (tmp_path / "data").exists() and not (tmp_path / "rec").exists()


def test_a_refused_dataset_size_leaves_nothing_that_blocks_the_corrected_command(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, _, _ = run_cli(["dataset", "--out", "data", "--instances", "1", "--frames", str(10**12)], capsys)
    assert code == 1 and not (tmp_path / "data").exists()
    code, out, err = run_cli(["dataset", "--out", "data", "--instances", "1", "--frames", "1"], capsys)
    assert code == 0, err
    assert "wrote 1 new sequences" in out


def test_workers_are_capped_at_the_cores_and_the_work(tmp_path, capsys, monkeypatch):
    """`--workers 500` for 2 sequences: one note, then a pool of at most 2 (not 500 processes idling)."""
    from spare_twin.dataset import backends

    monkeypatch.chdir(tmp_path)
    pools = []
    real_run_local = backends.run_local

    def spy(todo, cfg, seed, seq_dir, workers=1):
        pools.append(workers)
        return real_run_local(todo, cfg, seed, seq_dir, 1)  # the pool size is what is checked; render here

    monkeypatch.setattr("spare_twin.dataset.build.run_local", spy)
    argv = ["dataset", "--out", "data", "--instances", "2", "--frames", "1", "--workers", "500"]
    code, out, err = run_cli(argv, capsys)
    assert code == 0, err
    notes = [ln for ln in stderr_lines(err) if ln.startswith("note: ")]
    assert pools == [min(2, len(os.sched_getaffinity(0)))]
    assert len(notes) == 1 and notes[0].startswith(f"note: workers 500: using {pools[0]} ("), notes


def test_cap_workers_says_why_once(capsys, monkeypatch):
    from spare_twin import validate

    monkeypatch.setattr(validate, "usable_cores", lambda: 16)
    assert validate.cap_workers(40, 2) == 2
    assert validate.cap_workers(8, 100) == 8
    assert validate.cap_workers(500, 1000) == 16
    err = capsys.readouterr().err.splitlines()
    assert err == ["note: workers 40: using 2 (2 to do)", "note: workers 500: using 16 (16 cores)"]


def test_ctrl_c_stops_the_worker_pool_quietly(tmp_path):
    """SIGINT to the whole process group, as a terminal's Ctrl-C sends it, with a pool of 2 rendering:
    one line, exit 130, no worker traceback, no process left."""
    argv = [SPARE_TWIN, "dataset", "--out", "data", "--instances", "8", "--frames", "40", "--workers", "2"]
    code, err = interrupt_pool(argv, tmp_path)
    assert code == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    said = [ln for ln in stderr_lines(err) if not ln.startswith("dataset data:")]  # the progress bar's last state
    assert said == ["spare-twin dataset: interrupted"], said


def test_pool_workers_leave_ctrl_c_to_the_driver():
    """Deterministic half of the test above: every worker ignores SIGINT, the driver's handler and
    signal mask are as before (a Ctrl-C while the pool starts is held, not lost)."""
    from spare_twin.dataset.backends import start_pool

    before = signal.getsignal(signal.SIGINT)
    with start_pool(2, os.getpid, ()) as pool:
        handlers = pool.map(signal.getsignal, [signal.SIGINT] * 4, chunksize=1)
    assert set(handlers) == {signal.SIG_IGN}
    assert signal.getsignal(signal.SIGINT) is before
    assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, [])


# -- dataset shards ----------------------------------------------------------------------------------


def test_a_shard_that_does_not_read_back_is_made_again(tmp_path, capsys, monkeypatch):
    """One shard truncated, one replaced by garbage: resuming re-renders both (same bytes as before),
    it never counts them as done; reading a bad one for training is one line naming it."""
    from spare_twin.dataset.build import build_manifest
    from spare_twin.dataset.torch_data import SpareDataset

    monkeypatch.chdir(tmp_path)
    argv = ["dataset", "--out", "data", "--instances", "3", "--frames", "1"]
    code, _, err = run_cli(argv, capsys)
    assert code == 0, err
    seq = tmp_path / "data" / "sequences"
    good = {p.name: p.read_bytes() for p in seq.glob("seq-*.h5")}
    assert len(good) == 3
    truncated, garbage = seq / "seq-000000.h5", seq / "seq-000002.h5"
    truncated.write_bytes(good[truncated.name][: len(good[truncated.name]) // 2])
    garbage.write_bytes(b"not an HDF5 file " * 100)

    manifest = build_manifest(tmp_path / "data", 3)  # as after a run cut short: the bad shards are not done
    assert [r["index"] for r in manifest["sequences"]] == [1] and not manifest["complete"]
    data = SpareDataset(tmp_path / "data", split="all")
    with pytest.raises(SpareTwinError, match=r"seq-00000[02]\.h5: unreadable"):
        for i in range(len(data)):
            data[i]

    code, out, err = run_cli(argv, capsys)
    assert code == 0, err
    assert "wrote 2 new sequences" in out and "1 were already there" in out, out
    notes = [ln for ln in stderr_lines(err) if ln.startswith("note: ")]
    assert len(notes) == 2 and "seq-000000.h5: does not read back" in notes[0], notes
    assert "seq-000002.h5: does not read back" in notes[1]
    assert {p.name: p.read_bytes() for p in seq.glob("seq-*.h5")} == good
    assert json.loads((tmp_path / "data" / "manifest.json").read_text())["complete"]


def test_shard_check_reads_a_good_shard_and_names_a_wrong_one(tmp_path, capsys, monkeypatch):
    from spare_twin.dataset.store import shard_problem

    monkeypatch.chdir(tmp_path)
    assert run_cli(["dataset", "--out", "data", "--instances", "1", "--frames", "2"], capsys)[0] == 0
    f = tmp_path / "data" / "sequences" / "seq-000000.h5"
    assert shard_problem(f, 0, 8, 2, 96, 128) is None
    assert "not 1" in shard_problem(f, 1, 8, 2, 96, 128)
    assert "expected (8, 3, 96, 128)" in shard_problem(f, 0, 8, 3, 96, 128)
    assert shard_problem(tmp_path / "nothing.h5", 0, 8, 2, 96, 128).startswith("unreadable")


@pytest.mark.parametrize(
    "meta, words",
    [
        ([1, 2], "no 3x3 intrinsic_matrix"),
        ({"intrinsic_matrix": [500, 0, 0, 0, 500, 0, 320, 240, 1], "depth_scale": "abc"}, "must be numbers"),
        ({"intrinsic_matrix": [500, 0, 0, 0, 500, 0, 320, 240, 1], "depth_scale": 1e-320}, "finite and positive"),
        ({"intrinsic_matrix": [500, 0, 0, 0, 500, 0, 320, 240, 1], "x": [[[[1]]]] * 2 + ["[" * 70]}, None),
        ('{"intrinsic_matrix": ' + "[" * 70 + "]" * 70 + "}", "nested 71 deep"),
    ],
    ids=["not-an-object", "scale-a-string", "scale-infinite", "brackets-in-strings-are-fine", "nested"],
)
def test_open3d_intrinsics_file(meta, words, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    src = tmp_path / "o3d"
    for kind in ("color", "depth"):
        (src / kind).mkdir(parents=True)
        shutil.copy(APC / f"frame-000015.{kind}.png", src / kind / "000000.png")
    (src / "intrinsic.json").write_text(meta if isinstance(meta, str) else json.dumps(meta))
    argv = ["capture", "import", "o3d", "--layout", "open3d", "--out", "rec"]
    if words is None:  # a well-formed file: the import goes through
        code, _, err = run_cli(argv, capsys)
        assert code == 0, err
    else:
        refused(argv, capsys, tmp_path, "intrinsic.json", words)


@pytest.mark.parametrize(
    "spoil",
    [
        lambda raw: raw[:44] + bytes(len(raw) - 44),  # the header's dict literal cut short by zeros
        lambda raw: raw[:100],  # truncated
        lambda raw: raw.replace(b"'shape': (2, 4, 4)", b"'shape': (999999999999, 4, 4)"),  # a lying header
    ],
    ids=["header-zeroed", "truncated", "header-promises-terabytes"],
)
def test_a_spoiled_pose_file_is_one_line(spoil, tiny_rec, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    shutil.copytree(tiny_rec / "hand", tmp_path / "rec")
    p = tmp_path / "rec" / "cameras" / "cam0" / "T_world_camera.npy"
    raw = p.read_bytes()
    assert spoil(raw) != raw
    p.write_bytes(spoil(raw))
    refused(["capture", "register", "rec"], capsys, tmp_path, "T_world_camera.npy", "not a readable .npy file")
