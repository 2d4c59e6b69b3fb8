"""`spare-twin demo` end to end, as the README's first command runs it (in a temporary folder)."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
from conftest import refused_before_torch

from spare_twin.compare.demo import ALIGNED_LABEL, DEMO_CHAIN, REAL_LABEL
from spare_twin.predict.run import predict_recording

#: The README's first command, `spare-twin demo` with no arguments: its output goes to ./spare-twin-demo.
#: tests/test_readme.py checks that this is the README's command, so the README test need not run it again.
DEMO_ARGV = ["demo"]


def test_demo_runs_end_to_end(tmp_path):
    exe = shutil.which("spare-twin") or str(Path(sys.executable).parent / "spare-twin")
    out = tmp_path / "spare-twin-demo"
    res = subprocess.run([exe, *DEMO_ARGV], capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    lines = res.stdout.splitlines()
    assert lines[0].startswith("spare-twin demo finished in")
    for label in ("true (printed)", "sim, training rig", "sim, same cameras", REAL_LABEL, ALIGNED_LABEL):
        assert any(label in line and "n = " in line for line in lines), label
    # The printable files, the recordings and a valid Rerun recording with the sim and real entities.
    assert (out / "object" / "demo_chain.urdf").is_file() and (out / "object" / "link3.stl").is_file()
    for rec in ("sim_rig", "sensor_capture", "real", "sim_twin"):
        assert (out / rec / "recording.json").is_file(), rec
    rerun = shutil.which("rerun") or str(Path(sys.executable).parent / "rerun")
    rrd = out / "compare.rrd"
    assert subprocess.run([rerun, "rrd", "verify", str(rrd)], capture_output=True).returncode == 0
    printed = subprocess.run([rerun, "rrd", "print", str(rrd)], capture_output=True, text=True).stdout
    for entity in (
        "/real/network_input",
        "/sim/network_input",
        "/world/real_cloud",
        "/twin_sim/demo_chain/visual_geometries/link3",  # the twin's URDF, posed per frame
        "/real/frame/depth",
    ):
        assert entity in printed, entity
    # The default (yaw-free) model, overruled by the layers measured on the points, counts the twin's
    # links right both in the training rig's eight 96 x 128 views and from the capture's own cameras.
    for label in ("sim, training rig", "sim, same cameras"):
        row = next(line for line in lines if label in line)
        assert "n = 3" in row and "count right" in row, row
    # Sim to real, honestly: the real row is `predict` on the capture alone (the very answer a separate
    # predict_recording gives, nothing from the object folder or the fit), and it is right.
    saved = json.loads((out / "compare.json").read_text())
    alone = predict_recording(out / "real", progress=False).to_json()
    for key in ("n_links", "link_lengths_pu", "source", "network", "measurement"):
        assert saved["real"][key] == alone[key], key
    real_row = next(line for line in lines if REAL_LABEL in line)
    assert f"n = {alone['n_links']} " in real_row, (real_row, alone)
    # the capture's answer is the measurement's: the printed count, and the printed lengths within 0.03
    # paper units each (2.4 mm at the print scale; measured 0.012 at worst)
    assert alone["source"] == "measurement" and alone["n_links"] == alone["measurement"]["n_links"] == 3, alone
    errors_pu = np.subtract(alone["link_lengths_pu"], DEMO_CHAIN.link_lengths_pu)
    assert np.abs(errors_pu).max() < 0.03, errors_pu
    # every answer says where it came from, and what the network and the measurement said on their own
    sources = next(line for line in lines if line.strip().startswith("real: from"))
    assert "from the measurement" in sources and "measurement alone n = 3" in sources, sources
    # the diagnostic (cameras re-aligned on the fitted twin) is there, under its own name
    assert saved["real_twin_aligned"]["n_links"] == 3
    assert any(line.strip().startswith(ALIGNED_LABEL) for line in lines)
    assert "n = 3" in real_row and "count right" in real_row, real_row
    # articulated registration recovers the printed joint angles within 5 degrees
    angles = next(line for line in lines if "joint angles from articulated registration" in line)
    errors = [float(v) for v in angles.split(":")[1].replace("deg", "").split(",")]
    assert len(errors) == 3 and max(errors) < 5.0, angles


def test_a_missing_checkpoint_or_a_folder_not_the_demos_is_said_before_torch_is_loaded(tmp_path):
    """A missing checkpoint or an output that is not a demo's: said before the demo's modules (torch and
    every stage: 5 s of a new process) are imported, and nothing written."""
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("mine")
    (tmp_path / "notes.txt").write_text("mine")
    cases = [
        (["--model", "nope.pt"], ("nope.pt", "no such checkpoint")),
        (["--out", "mine"], ("mine", "--force")),
        (["--out", "notes.txt"], ("notes.txt", "--force")),
        (["--out", "."], ("current folder",)),
    ]
    refused_before_torch([(["demo", *args], words) for args, words in cases], tmp_path)
