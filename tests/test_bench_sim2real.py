"""`spare-twin bench sim2real`: predict-only sim-to-real figures on simulated hand-held captures.

The scoring is checked on hand-made predictions; the settings table on its own; the whole benchmark
end to end on two tiny captures (structure, honesty of the capture predict reads, the figures agree
with the per-object scores, a second run reuses everything, an interrupted run resumes)."""

import contextlib
import io
import json
import math

import numpy as np
import pytest
from conftest import run_cli

from spare_twin.compare import batch
from spare_twin.compare.batch import BenchConfig, bench_table, capture_settings, score_prediction

TRUTH = {"n_links": 2, "link_lengths_pu": [1.5, 0.5, 0.4], "joint_angles_rad": [0.3, -0.2]}


def test_score_right_count_exact_answer():
    s = score_prediction(TRUTH, dict(TRUTH))
    assert s["count_correct"] and s["E_L"] == 0.0 and s["joint_angle_error_deg"] == 0.0 and s["joint_angle_sign"] == 1


def test_score_wrong_count_uses_the_seven_slots():
    # one link too many: the invented link's length is the whole error; no angle score on a wrong count
    s = score_prediction(TRUTH, {"n_links": 3, "link_lengths_pu": [1.5, 0.5, 0.4, 0.3], "joint_angles_rad": [0, 0, 0]})
    assert not s["count_correct"] and s["E_L"] == pytest.approx(0.09) and s["joint_angle_error_deg"] is None
    # one link too few: the missed link's length, plus the others' errors
    s = score_prediction(TRUTH, {"n_links": 1, "link_lengths_pu": [1.4, 0.5], "joint_angles_rad": [0.3]})
    assert not s["count_correct"] and s["E_L"] == pytest.approx(0.01 + 0.16)
    # lengths past the predicted count are not the prediction's (the end-to-end rule)
    s = score_prediction(TRUTH, {"n_links": 1, "link_lengths_pu": [1.5, 0.5, 0.4], "joint_angles_rad": None})
    assert s["E_L"] == pytest.approx(0.16)


def test_score_no_answer_is_a_wrong_count_with_all_zero_lengths():
    s = score_prediction(TRUTH, {"n_links": None, "link_lengths_pu": None, "joint_angles_rad": None, "reason": "x"})
    assert not s["count_correct"] and s["E_L"] == pytest.approx(1.5**2 + 0.5**2 + 0.4**2)


def test_score_angles_up_to_one_global_sign_and_wrapped():
    mirrored = {**TRUTH, "joint_angles_rad": [-0.3, 0.2]}
    s = score_prediction(TRUTH, mirrored)
    assert s["joint_angle_error_deg"] == pytest.approx(0.0) and s["joint_angle_sign"] == -1
    # 10 deg off on one joint, right on the other: 5 deg mean
    off = {**TRUTH, "joint_angles_rad": [0.3 + math.radians(10), -0.2]}
    assert score_prediction(TRUTH, off)["joint_angle_error_deg"] == pytest.approx(5.0)
    # near +-180 deg the difference wraps
    t = {"n_links": 2, "link_lengths_pu": [1.5, 0.5, 0.4], "joint_angles_rad": [math.pi - 0.01, 0.5]}
    s = score_prediction(t, {**t, "joint_angles_rad": [-math.pi + 0.01, 0.5]})
    assert s["joint_angle_error_deg"] == pytest.approx(math.degrees(0.01)) and s["joint_angle_sign"] == 1
    # a sign flip of only some joints is not a mirror image
    t2 = {"n_links": 2, "link_lengths_pu": [1.5, 0.5, 0.4], "joint_angles_rad": [0.5, 0.5]}
    s = score_prediction(t2, {**t2, "joint_angles_rad": [0.5, -0.5]})
    assert s["joint_angle_error_deg"] == pytest.approx(math.degrees(0.5))


def _result(n, real, sim=None, predict_s=1.0):
    truth = {"n_links": n, "link_lengths_pu": [1.5] + [0.5] * n, "joint_angles_rad": [0.1] * n}
    sim = sim or {"n_links": n, "link_lengths_pu": truth["link_lengths_pu"]}
    return {
        "truth": truth,
        "sim": {**sim, "score": score_prediction(truth, sim)},
        "real": {**real, "predict_s": predict_s, "score": score_prediction(truth, real)},
    }


def test_bench_table_per_n_and_overall():
    right = {"n_links": 1, "link_lengths_pu": [1.5, 0.5], "joint_angles_rad": [0.1 + math.radians(4)]}
    wrong = {"n_links": 3, "link_lengths_pu": [1.5, 0.5, 0.5, 0.5], "joint_angles_rad": None}
    none = {"n_links": None, "link_lengths_pu": None, "joint_angles_rad": None, "reason": "no object"}
    table = bench_table([_result(1, right, predict_s=2.0), _result(2, wrong, predict_s=4.0), _result(2, none)])
    assert set(table["per_n"]) == {"1", "2"}
    one, two, all_ = table["per_n"]["1"], table["per_n"]["2"], table["overall"]
    assert one["real"]["count_accuracy"] == 1.0 and one["real"]["E_L"] == pytest.approx(0.0)
    assert one["real"]["joint_angle_error_deg"] == pytest.approx(4.0)
    assert two["real"]["count_accuracy"] == 0.0 and two["real"]["no_answer"] == 1
    assert two["real"]["E_L"] == pytest.approx((0.25 + (1.5**2 + 0.25 + 0.25)) / 2)
    assert two["real"]["joint_angle_error_deg"] is None and two["real"]["joint_angle_objects"] == 0
    assert all_["real"]["count_accuracy"] == pytest.approx(1 / 3) and all_["sim"]["count_accuracy"] == 1.0
    assert all_["real"]["predict_s"] == {"mean": pytest.approx(7 / 3), "max": 4.0}
    assert table["count_accuracy_gap_points"] == pytest.approx(100 * 2 / 3)
    assert table["E_L_ratio_real_to_sim"] is None  # the sim side is exact here: no ratio
    assert table["checks"]["joint_angle_error_at_most_5_deg"] and not table["checks"]["real_within_3_points_of_sim"]


def test_capture_settings_table():
    rows = capture_settings(BenchConfig())
    assert len(rows) == 24 and rows == capture_settings(BenchConfig())  # seeded: the same table every time
    assert rows != capture_settings(BenchConfig(seed=8000))
    assert [r.seed for r in rows] == list(range(7000, 7024)) and len({r.name for r in rows}) == 24
    for n in range(1, 7):
        mine = [r for r in rows if r.n_links == n]
        assert len(mine) == 4 and sum(r.hide_poses for r in mine) == 2  # half of each n without poses
    sweeps, frames = [r.sweep_deg for r in rows], [r.frames for r in rows]
    assert min(sweeps) == 120 and max(sweeps) == 360 and len(set(sweeps)) == 24
    assert min(frames) == 15 and max(frames) == 60
    assert {r.resolution: 0 for r in rows}.keys() == {"320x240", "640x480", "848x480"}
    assert [r.resolution for r in rows].count("848x480") == 8
    assert [r.noise for r in rows].count("kinect_v1") == 12 and [r.noise for r in rows].count("realsense_sr300") == 12
    assert sorted({r.clutter for r in rows}) == [0, 1, 2, 3, 4]
    assert all(abs(r.world_x_m) <= 0.05 and abs(r.world_y_m) <= 0.05 and 0 <= r.world_yaw_deg < 360 for r in rows)


@pytest.mark.parametrize(
    "cfg, word",
    [
        (BenchConfig(objects=0), "objects"),
        (BenchConfig(frames=(10, 5)), "frames"),
        (BenchConfig(sweep_deg=(20.0, 360.0)), "sweep_deg"),
        (BenchConfig(resolutions=("big",)), "resolutions"),
        (BenchConfig(noises=("nosuch",)), "noises"),
        (BenchConfig(noises=("none",)), "noises"),
        (BenchConfig(clutter_max=9), "clutter_max"),
    ],
)
def test_bad_config_names_the_parameter(cfg, word, tmp_path):
    from spare_twin.errors import SpareTwinError

    with pytest.raises(SpareTwinError, match=f"^{word}"):
        batch.bench_sim2real(tmp_path / "b", cfg)
    assert not (tmp_path / "b").exists()


TINY = ["--objects", "2", "--frames", "5-6", "--resolutions", "160x120", "--noise", "realsense_sr300"]
TINY += ["--clutter-max", "1", "--sim-frames", "1"]


@pytest.fixture(scope="module")
def tiny_bench(tmp_path_factory):
    """`spare-twin bench sim2real` on two tiny captures (n = 1 and 2; one with poses, one without)."""
    from spare_twin.cli import main

    out = tmp_path_factory.mktemp("bench") / "b"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):
        assert main(["bench", "sim2real", "--out", str(out), *TINY, "--json"]) == 0
    return out, json.loads(buf.getvalue())


def test_bench_end_to_end_structure_and_scores(tiny_bench):
    out, table = tiny_bench
    assert {"overall", "per_n", "objects", "checks", "model", "config", "notes"} <= set(table)
    assert set(table["per_n"]) == {"1", "2"} and table["overall"]["objects"] == 2
    for f in ("sim2real.json", "sim2real.md", "sim2real.png"):
        assert (out / f).is_file()
    assert json.loads((out / "sim2real.json").read_text()) == table
    md = (out / "sim2real.md").read_text()
    assert md.startswith("| n | objects | count acc. sim | count acc. real |") and "| all | 2 |" in md
    objs = table["objects"]
    assert [o["truth"]["n_links"] for o in objs] == [1, 2]
    assert [o["settings"]["hide_poses"] for o in objs] == [False, True]
    for o in objs:
        assert {"settings", "truth", "sim", "real", "capture_s", "sim_render_s"} <= set(o)
        for side in ("sim", "real"):
            assert {"n_links", "link_lengths_pu", "joint_angles_rad", "predict_s", "score"} <= set(o[side])
            assert o[side]["score"] == json.loads(
                json.dumps(
                    score_prediction(
                        o["truth"] if side == "real" else {**o["truth"], "joint_angles_rad": None}, o[side]
                    )
                )
            )
        assert o["real"]["predict_s"] > 0
        assert o["truth"]["link_lengths_pu"] == pytest.approx(
            json.loads((out / o["name"] / "object" / "object.json").read_text())["link_lengths_m"]
        )
    real_acc = np.mean([o["real"]["score"]["count_correct"] for o in objs])
    assert table["overall"]["real"]["count_accuracy"] == pytest.approx(real_acc)
    assert table["overall"]["real"]["E_L"] == pytest.approx(np.mean([o["real"]["score"]["E_L"] for o in objs]))
    assert table["overall"]["sim"]["E_L"] == pytest.approx(np.mean([o["sim"]["score"]["E_L"] for o in objs]))


def test_bench_capture_is_what_a_real_capture_gives(tiny_bench):
    """The recording predict reads: imported, no segmentation, object, ground truth or sign of simulation;
    poses only where the settings keep them, in a table frame where the object stands off the origin."""
    from spare_twin.object.kinematics import base_pose
    from spare_twin.recording import Recording

    out, table = tiny_bench
    for o in table["objects"]:
        c = o["settings"]
        real = Recording.open(out / o["name"] / "real")
        assert real.source["kind"] != "sim" and real.object_config is None and real.rig is None
        assert real.ground_truth() is None and real.segmentation("cam0", 0) is None
        assert real.n_frames == c["frames"] and (real.cameras[0].width, real.cameras[0].height) == (160, 120)
        truth = Recording.open(out / o["name"] / "sensor").ground_truth()["T_world_camera"]
        if c["hide_poses"]:
            assert real.cameras[0].poses == "unknown"
        else:
            T = base_pose(c["world_x_m"], c["world_y_m"], math.radians(c["world_yaw_deg"]))
            got = np.stack([real.T_world_camera("cam0", t) for t in range(real.n_frames)])
            np.testing.assert_allclose(got, T @ truth, atol=1e-6)
        assert not (out / o["name"] / "capture_7scenes").exists()


def test_bench_second_run_reuses_every_object(tiny_bench, capsys, monkeypatch):
    out, table = tiny_bench

    def refuse(*a, **k):
        raise AssertionError("a finished object was predicted again")

    monkeypatch.setattr(batch, "predict_recording", refuse)
    monkeypatch.setattr(batch, "render_recording", refuse)
    code, stdout, err = run_cli(["bench", "sim2real", "--out", str(out), *TINY], capsys)
    assert code == 0, err
    assert "| all | 2 |" in stdout and "wrote" in stdout
    assert json.loads((out / "sim2real.json").read_text())["objects"] == table["objects"]


def test_bench_interrupted_run_resumes_per_object(tmp_path, monkeypatch):
    cfg = BenchConfig(
        objects=2,
        frames=(3, 3),
        resolutions=("96x72",),
        noises=("realsense_sr300",),
        clutter_max=0,
        sim_frames=1,
        sim_resolution="network",
    )
    calls = []

    def fake_predict(rec_dir, model=None, progress=True, **kw):
        calls.append(str(rec_dir))
        from spare_twin.predict.estimate import Estimate, Prediction

        answer = Estimate(1, (1.5, 0.5), (0.0,))
        source = {"n_links": "measurement"}
        return Prediction(answer, source, None, answer, "combined", "profile", None, str(rec_dir), 0.08)

    monkeypatch.setattr(batch, "predict_recording", fake_predict)
    real_capture = batch._capture

    def capture_then_stop(obj_dir, d, c):
        if c.n_links == 2:
            raise KeyboardInterrupt
        return real_capture(obj_dir, d, c)

    monkeypatch.setattr(batch, "_capture", capture_then_stop)
    with pytest.raises(KeyboardInterrupt):
        batch.bench_sim2real(tmp_path / "b", cfg, progress=False)
    assert not (tmp_path / "b").exists() and len(calls) == 2  # object 1: real and sim
    monkeypatch.setattr(batch, "_capture", real_capture)
    table, files = batch.bench_sim2real(tmp_path / "b", cfg, progress=False)
    assert len(calls) == 4  # only object 2 was captured and predicted this time
    assert table["overall"]["objects"] == 2 and (tmp_path / "b" / "sim2real.md").is_file()
