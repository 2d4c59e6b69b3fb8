"""The dataset: generation, byte-identical regeneration, extension, resume after kill -9, splits."""

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from spare_twin.cli import main
from spare_twin.dataset.build import generate_dataset
from spare_twin.dataset.generate import SPLIT_COUNTS, GenConfig, n_links_of, split_of
from spare_twin.errors import SpareTwinError

CFG = GenConfig(frames=3)


def _hashes(root: Path) -> dict:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted((root / "sequences").glob("*.h5"))}


def test_splits_and_balance_follow_the_paper():
    counts = {}
    for i in range(324):
        counts[(split_of(i), n_links_of(i))] = counts.get((split_of(i), n_links_of(i)), 0) + 1
    for split, per_n in (("train", 32), ("val", 6), ("test", 16)):
        assert all(counts[(split, n)] == per_n for n in range(1, 7))
    assert sum(SPLIT_COUNTS) * 6 * 2 == 324
    # 192 / 36 / 96 sequences x 800 images = 153,600 / 28,800 / 76,800
    assert [sum(v for (s, _), v in counts.items() if s == name) * 800 for name in ("train", "val", "test")] == [
        153600,
        28800,
        76800,
    ]
    assert {split_of(i) for i in range(6 * 6)} == {"train", "val", "test"}  # small datasets have every split


def test_generate_extend_regenerate(tmp_path):
    a = tmp_path / "a"
    r = generate_dataset(a, 4, seed=3, workers=1, cfg=CFG, progress=False)
    assert r["complete"] and r["generated"] == 4
    first = _hashes(a)
    mtimes = {p.name: p.stat().st_mtime_ns for p in (a / "sequences").glob("*.h5")}
    # extend: only the new sequences are written, the old files are untouched
    r = generate_dataset(a, 7, seed=3, workers=2, cfg=CFG, progress=False)
    assert r["generated"] == 3 and r["already_present"] == 4
    after = _hashes(a)
    assert {k: after[k] for k in first} == first
    assert all((a / "sequences" / k).stat().st_mtime_ns == m for k, m in mtimes.items())
    m = json.loads((a / "manifest.json").read_text())
    assert m["complete"] and [s["index"] for s in m["sequences"]] == list(range(7))
    assert [s["n_links"] for s in m["sequences"]] == [1, 2, 3, 4, 5, 6, 1]
    assert m["images"] == 7 * 8 * 3
    # regenerate from scratch elsewhere, in one go: byte-identical files
    b = tmp_path / "b"
    generate_dataset(b, 7, seed=3, workers=1, cfg=CFG, progress=False)
    assert _hashes(b) == after
    # another seed changes the data; the folder refuses a mismatched seed or settings
    with pytest.raises(SpareTwinError, match="seed"):
        generate_dataset(a, 7, seed=4, workers=1, cfg=CFG, progress=False)
    with pytest.raises(SpareTwinError, match="frames"):
        generate_dataset(a, 7, seed=3, workers=1, cfg=GenConfig(frames=4), progress=False)


def test_resume_after_kill_9(tmp_path):
    ref = tmp_path / "ref"
    generate_dataset(ref, 6, seed=1, workers=1, cfg=GenConfig(frames=6), progress=False)
    out = tmp_path / "killed"
    cmd = [
        sys.executable,
        "-m",
        "spare_twin.cli",
        "dataset",
        "--out",
        str(out),
        "--instances",
        "6",
        "--seed",
        "1",
        "--frames",
        "6",
        "--workers",
        "1",
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 60
    while time.time() < deadline and len(list((out / "sequences").glob("seq-*.h5"))) < 2:
        time.sleep(0.02)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    done = len(list((out / "sequences").glob("seq-*.h5")))
    assert 2 <= done < 6, "the run finished before it could be killed"
    # a half-written shard as a kill mid-write leaves it, and a stale lock of the dead process
    (out / "sequences" / f".seq-00000{done}.h5.tmp-99999").write_bytes(b"\x89HDF garbage")
    assert (out / ".lock").exists()
    assert main(["dataset", "--out", str(out), "--instances", "6", "--seed", "1", "--frames", "6"]) == 0
    assert _hashes(out) == _hashes(ref)
    assert not list((out / "sequences").glob(".*tmp*")) and not (out / ".lock").exists()
    assert json.loads((out / "manifest.json").read_text())["complete"]


def test_dataset_cli_errors(tmp_path, capsys):
    assert main(["dataset", "--out", str(tmp_path / "d")]) == 1
    assert "--instances" in capsys.readouterr().err
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "x.txt").write_text("x")
    assert main(["dataset", "--out", str(tmp_path / "junk"), "--instances", "1"]) == 1
    assert "not a dataset folder" in capsys.readouterr().err


def test_sim2real_and_print_geometry(tmp_path):
    import h5py
    import numpy as np

    from spare_twin.sim.scene import SIM2REAL

    cfg = GenConfig(frames=2, geometry="print", randomization=SIM2REAL)
    generate_dataset(tmp_path / "d", 3, seed=9, workers=1, cfg=cfg, progress=False)
    with h5py.File(tmp_path / "d" / "sequences" / "seq-000002.h5") as f:
        scene = json.loads(f.attrs["scene"])
        assert scene["link_rgb"] is not None and len(scene["link_rgb"]) == 4
        # jittered rig: not the nominal poses and intrinsics
        from spare_twin.sim.rig import Rig

        assert not np.allclose(f["T_world_camera"][()], Rig().poses())
        assert not np.allclose(f["K"][0], Rig().K())
        labels = f["segmentation"][()]
        assert set(np.unique(labels)) >= {0, 1, 2, 3, 4}


def test_force_replaces_a_foreign_folder_only_once_the_new_dataset_is_complete(tmp_path, monkeypatch):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    with pytest.raises(SpareTwinError, match="not a dataset folder"):
        generate_dataset(mine, 1, seed=1, cfg=CFG, progress=False)
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]

    # Interrupted while the new dataset is made: the old folder is whole, no temporary is left.
    import spare_twin.dataset.build as build

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(build, "_generate", interrupted)
    with pytest.raises(KeyboardInterrupt):
        generate_dataset(mine, 1, seed=1, cfg=CFG, progress=False, force=True)
    monkeypatch.undo()
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"]

    summary = generate_dataset(mine, 1, seed=1, cfg=CFG, progress=False, force=True)
    assert summary["replaced"] and summary["root"] == str(mine) and summary["complete"]
    assert not (mine / "notes.txt").exists() and (mine / "sequences" / "seq-000000.h5").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"]
    # Other seed: refused as it is, replaced with force; the same seed then extends in place.
    with pytest.raises(SpareTwinError, match="seed 2"):
        generate_dataset(mine, 1, seed=2, cfg=CFG, progress=False)
    generate_dataset(mine, 1, seed=2, cfg=CFG, progress=False, force=True)
    assert json.loads((mine / "dataset.json").read_text())["seed"] == 2
    assert generate_dataset(mine, 2, seed=2, cfg=CFG, progress=False)["generated"] == 1


def test_a_run_killed_before_its_settings_were_written_resumes(tmp_path):
    """Killed after taking its lock but before writing dataset.json, a run leaves the folder holding its
    lock alone (the sequences folder comes after the settings); the rerun resumes there and gives the
    same files as a run never stopped, while a folder holding anything else is still refused."""
    ref, cut, foreign = tmp_path / "ref", tmp_path / "cut", tmp_path / "foreign"
    generate_dataset(ref, 2, seed=5, workers=1, cfg=CFG, progress=False)
    cut.mkdir()
    (cut / ".lock").write_text("999999999")  # a writer that is gone
    generate_dataset(cut, 2, seed=5, workers=1, cfg=CFG, progress=False)
    assert _hashes(cut) == _hashes(ref)
    # killed as it wrote dataset.json (an empty lock is one killed as it wrote the lock), then later
    # killed as it wrote the manifest: each rerun resumes, and the temporaries go
    for left in ([".lock", ".dataset.json.k3x_9q1z.tmp"], [".manifest.json.abcd1234.tmp"]):
        if ".lock" in left:
            shutil.rmtree(cut)
            cut.mkdir()
        for name in left:
            (cut / name).write_text("" if name == ".lock" else '{"format": "spare-twin-d')
        generate_dataset(cut, 2, seed=5, workers=1, cfg=CFG, progress=False)
        assert _hashes(cut) == _hashes(ref) and not list(cut.glob(".*")), left
        assert sorted(p.name for p in cut.iterdir()) == sorted(p.name for p in ref.iterdir())
        assert all((cut / f).read_bytes() == (ref / f).read_bytes() for f in ("dataset.json", "manifest.json"))
    foreign.mkdir()
    (foreign / ".lock").write_text("999999999")
    (foreign / "sequences").mkdir()
    with pytest.raises(SpareTwinError, match="no dataset.json"):
        generate_dataset(foreign, 2, seed=5, workers=1, cfg=CFG, progress=False)
    users = tmp_path / "users"
    users.mkdir()
    (users / ".lock").write_text("my notes")  # not a pid: not ours
    with pytest.raises(SpareTwinError, match="no dataset.json"):
        generate_dataset(users, 2, seed=5, workers=1, cfg=CFG, progress=False)
    assert (users / ".lock").read_text() == "my notes"


def test_print_physics_renders_each_link_where_its_print_put_it(tmp_path):
    """A --print-physics sequence renders each link tilted out of the chain's plane by the angle it drew
    (1-4 degrees, scaled by the print's shrink): the turn about the joint's axis that brings the link's
    points, in the nominal link frame the labels keep, back onto the same link rendered without the
    option is the drawn tilt, to within the search's 0.25-degree step."""
    import h5py
    import numpy as np
    from scipy.spatial import cKDTree

    from spare_twin.observe.points import backproject, rigid
    from spare_twin.sim.rig import axis_angle

    def link_points(root: Path) -> tuple[list[np.ndarray], dict]:
        with h5py.File(root / "sequences" / "seq-000005.h5") as f:  # index 5: six moving links
            depth = f["depth"][:, 0].astype(np.float64) * float(f.attrs["depth_scale"])
            labels, K, T_wc = f["segmentation"][:, 0], f["K"][()], f["T_world_camera"][()]
            T_world_link = f["T_world_link"][0]
            scene = json.loads(f.attrs["scene"])
        links = []
        for k in range(1, 7):  # label k + 1 is link k
            pts = np.concatenate([rigid(T_wc[v], backproject(depth[v], K[v], labels[v] == k + 1)) for v in range(8)])
            links.append(rigid(np.linalg.inv(T_world_link[k]), pts))
        return links, scene

    plain = GenConfig(frames=1)
    assert "print_physics" not in plain.to_dict()  # datasets made before the option keep their settings
    generate_dataset(tmp_path / "plain", 6, seed=4, workers=1, cfg=plain, progress=False)
    printed_cfg = GenConfig(frames=1, print_physics=True)
    generate_dataset(tmp_path / "printed", 6, seed=4, workers=1, cfg=printed_cfg, progress=False)
    nominal, _ = link_points(tmp_path / "plain")
    leaning, scene = link_points(tmp_path / "printed")
    drawn = scene["print"]
    assert all(1.0 <= abs(t) <= 4.0 for t in drawn["tilt_deg"]) and 0.995 <= drawn["scale"] <= 0.998
    trial_deg = np.arange(-5.0, 5.01, 0.25)
    for k, (ref, pts, tilt) in enumerate(zip(nominal, leaning, drawn["tilt_deg"]), 1):
        assert len(ref) > 50 and len(pts) > 50, k
        surface = cKDTree(ref)
        # the tilt that brings the printed link back onto the plain one (points turned about the joint's x axis)
        turned = [pts @ axis_angle(np.array([1.0, 0.0, 0.0]), np.radians(-a)).T for a in trial_deg]
        misfit_m = [np.mean(surface.query(p / drawn["scale"])[0]) for p in turned]
        found = trial_deg[int(np.argmin(misfit_m))]
        assert abs(found - tilt) <= 0.5, (k, tilt, found)
