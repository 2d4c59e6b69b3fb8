"""The sim-to-real table and the comparison's Rerun recording, on hand-made results."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from spare_twin.compare.result import score
from spare_twin.compare.table import sim2real_table, table_markdown, write_table


def _score(truth, pred):
    """`score` of two JSON-like sides, as `compare --json` stores it."""
    return score(truth["n_links"], truth["link_lengths_pu"], pred["n_links"], pred["link_lengths_pu"]).to_json()


def _result(n, sim_n, real_n, angle_err=None):
    truth = {"n_links": n, "link_lengths_pu": [1.5] + [0.5] * n}
    sim = {"n_links": sim_n, "link_lengths_pu": [1.5] + [0.5] * sim_n}
    real = {"n_links": real_n, "link_lengths_pu": [1.4] + [0.5] * real_n}
    return {
        "truth": truth,
        "sim": sim,
        "real": real,
        "errors": {"sim": _score(truth, sim), "real": _score(truth, real), "joint_angles_deg": angle_err},
    }


def test_score_uses_the_end_to_end_rule():
    truth = {"n_links": 2, "link_lengths_pu": [1.5, 0.5, 0.4]}
    exact = _score(truth, {"n_links": 2, "link_lengths_pu": [1.5, 0.5, 0.4]})
    assert exact["count_correct"] and exact["E_L"] == pytest.approx(0.0)
    # One link missing: its squared length is the error; one invented: likewise.
    assert _score(truth, {"n_links": 1, "link_lengths_pu": [1.5, 0.5]})["E_L"] == pytest.approx(0.16)
    extra = _score(truth, {"n_links": 3, "link_lengths_pu": [1.5, 0.5, 0.4, 0.3]})
    assert not extra["count_correct"] and extra["E_L"] == pytest.approx(0.09)
    assert extra["per_link_pu"] == pytest.approx([0, 0, 0, 0.3])


def test_table_per_n_and_overall(tmp_path):
    results = [_result(1, 1, 1, [1.0]), _result(1, 1, 2, [3.0]), _result(2, 2, 2, [2.0, 4.0])]
    table = sim2real_table(results)
    assert table["per_n"]["1"]["instances"] == 2
    assert table["per_n"]["1"]["sim"]["count_accuracy"] == 1.0
    assert table["per_n"]["1"]["real"]["count_accuracy"] == 0.5
    assert table["overall"]["real"]["count_accuracy"] == pytest.approx(2 / 3)
    assert table["count_accuracy_gap_points"] == pytest.approx(100 / 3)
    # real base is 0.1 short everywhere, plus one invented 0.5 link
    assert table["per_n"]["2"]["real"]["E_L"] == pytest.approx(0.01)
    assert table["overall"]["joint_angle_error_deg"] == {"mean": 2.5, "max": 4.0}
    md = table_markdown(table)
    assert "| all | 3 |" in md and md.count("\n") == 5
    files = write_table(table, tmp_path)
    assert json.loads(Path(files["json"]).read_text())["overall"]["instances"] == 3
    import cv2

    img = cv2.imread(files["png"])
    assert img.shape == (360, 900, 3) and (img < 250).any()


def test_comparison_rrd_verifies(tmp_path):
    from spare_twin.compare.rerun_log import ComparisonLog, log_comparison
    from spare_twin.recording import Camera, Recording, RecordingWriter

    K = np.array([[100.0, 0, 31.5], [0, 100.0, 23.5], [0, 0, 1]])
    recs = []
    for name in ("real", "sim"):
        with RecordingWriter(tmp_path / name, [Camera("cam0", 64, 48, K, np.eye(4))], 2, 10.0, {"kind": "sim"}) as w:
            for f in range(2):
                w.add_frame("cam0", f, np.full((48, 64, 3), 100, np.uint8), np.full((48, 64), 0.5, np.float32))
        recs.append(Recording.open(tmp_path / name))
    result = _result(2, 2, 1, [1.0, 2.0])
    result["registration"] = {"joint_angles_rad": [0.1, 0.2]}
    result["real_twin_aligned"] = dict(result["sim"])
    result["errors"]["real_twin_aligned"] = result["errors"]["sim"]
    cube = (
        np.array([[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01]], np.float32),
        np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]], np.uint32),
        (1.0, 0.0, 0.0),
    )
    rrd = tmp_path / "cmp.rrd"
    log_comparison(
        rrd,
        ComparisonLog(
            result,
            np.random.default_rng(0).random((50, 3)),
            np.full((50, 3), 0.5),
            [cube],
            np.ones((8, 96, 128)),
            np.ones((8, 96, 128)),
            recs[0],
            recs[1],
            real_twin_aligned_input=np.ones((8, 96, 128)),
        ),
    )
    rerun = shutil.which("rerun") or str(Path(sys.executable).parent / "rerun")
    res = subprocess.run([rerun, "rrd", "verify", str(rrd)], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    # The sim and real entities are there.
    res = subprocess.run([rerun, "rrd", "print", str(rrd)], capture_output=True, text=True)
    for entity in (
        "/real/network_input",
        "/sim/network_input",
        "/real_twin_aligned/network_input",
        "/lengths/real_twin_aligned",
        "/world/real_cloud",
        "/world/twin/link0",
        "/summary",
        "/real/frame/depth",
        "/sim/frame/color",
    ):
        assert entity in res.stdout, entity
    # the summary names the real side as predict's and the twin-aligned one as a diagnostic
    from spare_twin.compare.rerun_log import summary_markdown

    md = summary_markdown(result)
    assert "| real (predict alone) | 1 |" in md and "| diagnostic: real, twin-aligned | 2 |" in md
    # each estimate beside the answer, as predict --json gives them
    result["real"]["network"] = {"n_links": 3, "link_lengths_pu": [1.4, 0.5, 0.5, 0.3]}
    result["real"]["measurement"] = {"n_links": None, "link_lengths_pu": None, "reason": "no chain measured: x"}
    md = summary_markdown(result)
    assert "| real (predict alone): network alone | 3 | 1.400, 0.500, 0.500, 0.300 | | |" in md
    assert "| real (predict alone): measurement alone | none (no chain measured: x) | - | | |" in md


def _prediction(n, lengths, angles=None, method="posed"):
    from spare_twin.predict.estimate import Estimate, NetworkEvidence, Prediction

    probabilities = tuple(0.9 if k == n - 1 else 0.02 for k in range(6))
    network = Estimate(n, tuple(lengths), angles, NetworkEvidence(probabilities, (0.0, 90.0), 90.0))
    source = {"n_links": "network", "link_lengths_pu": "network", "joint_angles_rad": "network"}
    return Prediction(network, source, network, None, "combined", method, "m.pt", "rec", 0.08)


def test_comparison_json_is_the_compare_object():
    from dataclasses import replace

    from spare_twin.compare.articulated import ArticulatedFit
    from spare_twin.compare.result import SIDE_KEYS, Comparison, Truth
    from spare_twin.object.kinematics import base_pose

    truth = Truth(2, (1.5, 0.5, 0.4), (0.1, -0.2))
    fit = ArticulatedFit(base_pose(0.01, 0.02, 0.3), np.array([0.1 + np.radians(2.0), -0.2]), 0.002, 0.9, 0.001)
    T_world_object = np.eye(4)
    T_world_object[:3, 3] = [0.1, 0.2, 0.0]
    sim = _prediction(2, (1.5, 0.5, 0.4), angles=(0.1, -0.2))
    real = _prediction(2, (1.5, 0.5, 0.3), angles=(0.1 + np.radians(3.0), -0.2), method="fused")
    aligned = _prediction(1, (1.4, 0.5))
    c = Comparison(truth, sim, real, aligned, fit, T_world_object, Path("rec_sim_twin"), {"version": "x"})
    j = json.loads(json.dumps(c.to_json()))
    assert list(j) == [
        "truth",
        "sim",
        "real",
        "real_twin_aligned",
        "registration",
        "errors",
        "sim_recording",
        "model",
        "settings",
    ]
    assert j["truth"] == {"n_links": 2, "link_lengths_pu": [1.5, 0.5, 0.4], "joint_angles_rad": [0.1, -0.2]}
    # every side keeps the same keys, null where the model says nothing (here: no joint angles), and
    # passes through how `predict` made its input
    for side in ("sim", "real", "real_twin_aligned"):
        assert list(j[side])[: len(SIDE_KEYS)] == list(SIDE_KEYS)
    assert j["real_twin_aligned"]["joint_angles_rad"] is None
    assert j["real"]["input"] == "fused" and j["real"]["network"]["yaw_deg"] == 90.0 and "reason" not in j["real"]
    assert j["real"]["source"] == "network" and j["real"]["measurement"] is None
    assert j["real"]["link_lengths_mm"] == pytest.approx([120.0, 40.0, 24.0])  # at the print scale used
    # errors: the real (predict alone) side and the diagnostic under their own keys
    assert j["errors"]["real"] == _score(j["truth"], j["real"]) and j["errors"]["sim"]["E_L"] == 0.0
    assert j["errors"]["real_twin_aligned"] == _score(j["truth"], j["real_twin_aligned"])
    assert j["errors"]["real"]["count_correct"] and not j["errors"]["real_twin_aligned"]["count_correct"]
    assert j["errors"]["joint_angles_deg"] == pytest.approx([2.0, 0.0])
    assert j["errors"]["real_joint_angles_deg"] == pytest.approx([3.0, 0.0])
    # the twin's base in the real recording's world: object frame then base in the object frame
    np.testing.assert_allclose(j["registration"]["T_world_base"], T_world_object @ fit.T_object_base)
    assert j["model"] == "m.pt" and j["sim_recording"] == "rec_sim_twin" and "rrd" not in j
    assert replace(c, rrd="out.rrd").to_json()["rrd"] == "out.rrd"
    # stage timings are for people: the JSON stays the same bytes on every run
    assert replace(c, timings_s={"articulated fit": 1.0}).to_json() == c.to_json()
    lines = c.summary().splitlines()
    assert lines[0].split() == ["truth", "n", "=", "2", "lengths", "[1.500,", "0.500,", "0.400]"]
    assert "real (predict alone)" in lines[2] and "count right" in lines[2]
    assert lines[3].strip().startswith("diagnostic: real, twin-aligned") and "count WRONG" in lines[3]
    assert lines[-1].endswith("error 2.0, 0.0 deg")
    assert "  real, each estimate alone: network n = 2" in lines  # the network's answer beside the answer


def test_no_count_from_predict_is_reported_not_scored_right():
    """`predict` may find no chain (`n_links` null, with a reason): the real side is then wrong, with no E_L."""
    from dataclasses import replace

    from spare_twin.compare.result import Truth, side_json
    from spare_twin.predict.estimate import Estimate

    nothing = Estimate.none("no chain in view: nothing there")
    none = replace(_prediction(2, (1.5, 0.5, 0.4)), answer=nothing, source=None)
    s = Truth(2, (1.5, 0.5, 0.4)).score(none)
    assert not s.count_correct and s.E_L is None
    assert side_json(none)["n_links"] is None and side_json(none)["link_lengths_pu"] is None
