"""`spare-twin predict` with the default (yaw-free) model on recordings from any cameras: joint angles,
no chain -> no answer, the same bytes on every run (issue 13's contract, DESIGN.md's predict JSON)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
from capture_helpers import TUM_K, TUM_PAIR


def _predict(rec, *extra) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "spare_twin", "predict", str(rec), *extra]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600)


def test_predict_json_has_joint_angles_and_is_the_same_bytes_every_run(sweep, printed_object):
    """The second run names the default network: the command then measures in-process, not in its
    measuring process (`predict.early`), and says the same."""
    from spare_twin.nets.checkpoint import default_model

    first, second = _predict(sweep, "--json"), _predict(sweep, "--json", "--model", str(default_model("predict")))
    assert first.returncode == 0, first.stderr[-2000:]
    assert first.stdout == second.stdout  # registration, observation, network and chain fit: deterministic
    res = json.loads(first.stdout)
    assert res["format"] == "spare-twin-prediction" and res["version"] == 2
    assert res["n_links"] == 2 and len(res["joint_angles_rad"]) == 2  # the printed object's count
    assert len(res["link_lengths_pu"]) == 3 and res["source"] == "measurement" and "reason" not in res
    assert len(res["network"]["probabilities"]) == 6 and "probabilities" not in res
    assert res["measurement"]["n_links"] == 2 and res["measurement"]["rms_m"] < 0.002
    # the printed lengths within 0.03 paper units each (2.4 mm at the print scale; measured 0.010 at worst)
    errors_pu = np.subtract(res["link_lengths_pu"], printed_object.spec.link_lengths_pu)
    assert np.abs(errors_pu).max() < 0.03, errors_pu
    assert res["network"]["n_links"] == 2  # the shipped profile network alone is sure of it too (p = 0.99)


def test_tum_desk_pair_is_no_object(tmp_path, capsys):
    """A real Kinect pair of a desk: no chain on the table, so no count, and a reason."""
    from spare_twin.cli import main

    rec = tmp_path / "tum"
    assert main(["capture", "import", str(TUM_PAIR), "--layout", "tum", "--intrinsics", TUM_K, "--out", str(rec)]) == 0
    capsys.readouterr()
    assert main(["predict", str(rec), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["n_links"] is None and res["link_lengths_pu"] is None and res["reason"].startswith("no chain in view")
    assert res["network"] is None and res["source"] is None  # nothing to show the network
    assert main(["predict", str(rec)]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and "no chain in view" in out[0]


def test_an_empty_table_render_is_no_object(printed_object, tmp_path, capsys):
    from spare_twin.cli import main

    rec = tmp_path / "empty"
    argv = ["render", str(printed_object.root), "--out", str(rec), "--path", "handheld", "--empty", "--clutter", "2"]
    assert main([*argv, "--frames", "10", "--resolution", "320x240"]) == 0
    capsys.readouterr()
    assert main(["predict", str(rec), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    # what stands on the table is clutter, far wider at its foot than a chain's base link
    assert res["n_links"] is None and res["reason"].startswith("no chain in view: "), res["reason"]
    assert res["link_lengths_pu"] is None and res["source"] is None
