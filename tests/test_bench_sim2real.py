"""`spare-twin bench sim2real` (spare_twin/bench/): the sim-to-real bench with every capture effect and
each network's own figures.

The scoring and the table's counting (wrong apart from none, refused never scored) are checked on
hand-made answers; the settings table on its own; the whole bench end to end on two tiny captures
(rows and columns, the effects each capture drew, the clean render on the capture's own camera path,
a model that cannot read the captures recorded as refused, the same results with 1 and 2 workers, a
second run reusing everything, a run with a changed model predicting again on the kept captures)."""

import contextlib
import io
import json
import math

import numpy as np
import pytest
from conftest import refused_before_torch, run_cli

from spare_twin.bench import capture, sim2real
from spare_twin.bench.scoring import answer_stats, bench_markdown, bench_table, score_prediction
from spare_twin.bench.settings import BenchConfig, capture_settings
from spare_twin.compare import answers as compare_answers
from spare_twin.errors import SpareTwinError
from spare_twin.predict.images import CaptureRefused
from spare_twin.sim.effects import EFFECTS

TRUTH = {"n_links": 2, "link_lengths_pu": [1.5, 0.5, 0.4], "joint_angles_rad": [0.3, -0.2]}


def test_score_right_count_exact_answer():
    s = score_prediction(TRUTH, dict(TRUTH))
    assert s["count_correct"] and s["answered"] and s["E_L"] == 0.0
    assert s["joint_angle_error_deg"] == 0.0 and s["joint_angle_sign"] == 1


def test_score_wrong_count_uses_the_seven_slots():
    # one link too many: the invented link's length is the whole error; no angle score on a wrong count
    s = score_prediction(TRUTH, {"n_links": 3, "link_lengths_pu": [1.5, 0.5, 0.4, 0.3], "joint_angles_rad": [0, 0, 0]})
    assert not s["count_correct"] and s["answered"] and s["E_L"] == pytest.approx(0.09)
    assert s["joint_angle_error_deg"] is None
    # one link too few: the missed link's length, plus the others' errors
    s = score_prediction(TRUTH, {"n_links": 1, "link_lengths_pu": [1.4, 0.5], "joint_angles_rad": [0.3]})
    assert not s["count_correct"] and s["E_L"] == pytest.approx(0.01 + 0.16)


def test_score_no_answer_is_not_right_and_not_answered():
    s = score_prediction(TRUTH, {"n_links": None, "link_lengths_pu": None, "joint_angles_rad": None, "reason": "x"})
    assert not s["count_correct"] and not s["answered"] and s["E_L"] == pytest.approx(1.5**2 + 0.5**2 + 0.4**2)


def test_score_angles_up_to_one_global_sign_and_wrapped():
    s = score_prediction(TRUTH, {**TRUTH, "joint_angles_rad": [-0.3, 0.2]})
    assert s["joint_angle_error_deg"] == pytest.approx(0.0) and s["joint_angle_sign"] == -1
    off = {**TRUTH, "joint_angles_rad": [0.3 + math.radians(10), -0.2]}
    assert score_prediction(TRUTH, off)["joint_angle_error_deg"] == pytest.approx(5.0)
    t = {"n_links": 2, "link_lengths_pu": [1.5, 0.5, 0.4], "joint_angles_rad": [math.pi - 0.01, 0.5]}
    s = score_prediction(t, {**t, "joint_angles_rad": [-math.pi + 0.01, 0.5]})
    assert s["joint_angle_error_deg"] == pytest.approx(math.degrees(0.01))
    # no angle truth (the rig's moving joints): no angle score
    assert score_prediction({**TRUTH, "joint_angles_rad": None}, dict(TRUTH))["joint_angle_error_deg"] is None


def _scored(answer, truth=TRUTH):
    return {**answer, "score": score_prediction(truth, answer)}


RIGHT = {"n_links": 2, "link_lengths_pu": [1.5, 0.5, 0.4], "joint_angles_rad": [0.3, -0.2 + math.radians(4)]}
WRONG = {"n_links": 3, "link_lengths_pu": [1.5, 0.5, 0.4, 0.3], "joint_angles_rad": None}
NONE = {"n_links": None, "link_lengths_pu": None, "joint_angles_rad": None, "reason": "no chain"}
REFUSED = {"n_links": None, "link_lengths_pu": None, "joint_angles_rad": None, "refused": "reads 100 frames"}


def test_wrong_and_none_counted_apart_and_refused_never_scored():
    s = answer_stats([_scored(RIGHT), _scored(WRONG), _scored(NONE), _scored(NONE), REFUSED])
    assert s["objects"] == 4 and s["refused"] == 1
    assert s["count_accuracy"] == pytest.approx(0.25) and s["wrong"] == 1 and s["none"] == 2
    assert s["E_L"] == pytest.approx((0 + 0.09 + 2 * (1.5**2 + 0.5**2 + 0.4**2)) / 4)
    assert s["joint_angle_error_deg"] == pytest.approx(2.0) and s["joint_angle_objects"] == 1
    only_refused = answer_stats([REFUSED, REFUSED])
    assert only_refused["objects"] == 0 and only_refused["refused"] == 2 and only_refused["count_accuracy"] is None


def _result(n, answers_by_side, frames=30, resolution="640x480", predict_s=2.0):
    truth = {"n_links": n, "link_lengths_pu": [1.5] + [0.5] * n, "joint_angles_rad": [0.1] * n}
    sides = {
        side: {"answers": {k: a if a.get("refused") else _scored(a, truth) for k, a in answers.items()}}
        for side, answers in answers_by_side.items()
    }
    settings = {"frames": frames, "resolution": resolution}
    return {
        "truth": truth,
        "sides": sides,
        "settings": settings,
        "times_s": {"predict": {"real": {"combined": predict_s}}},
    }


def test_bench_table_rows_sides_per_n_and_goals():
    one = {"n_links": 1, "link_lengths_pu": [1.5, 0.5], "joint_angles_rad": [0.1]}
    good = {"combined": one, "measurement": one, "net": one}
    bad = {"combined": NONE, "measurement": NONE, "net": REFUSED}
    r1 = _result(1, {"sim_rig": good, "sim_cameras": good, "real": good})
    r2 = _result(1, {"sim_rig": good, "sim_cameras": good, "real": bad})
    table = bench_table([r1, r2], ["net"])
    assert table["rows"] == ["combined", "measurement", "net"]
    assert table["sides"] == ["sim_rig", "sim_cameras", "real"] and list(table["per_n"]) == ["1"]
    c = table["overall"]["answers"]["combined"]
    assert c["sim_rig"]["count_accuracy"] == 1.0 and c["real"]["count_accuracy"] == 0.5 and c["real"]["none"] == 1
    net = table["overall"]["answers"]["net"]["real"]
    assert net["objects"] == 1 and net["refused"] == 1 and net["count_accuracy"] == 1.0
    assert not table["goals"]["combined_real_count_at_least_0.95"]
    assert table["goals"]["net_real_count_at_least_0.90"]
    assert table["goals"]["predict_at_most_10_s_up_to_30_frames_640x480"]
    # a network that refuses every real capture (a fixed-rig network on hand-held sweeps) is judged on
    # none: it refuses them, as issue 28 asks, neither meeting nor missing the count goals
    r3 = _result(1, {"sim_rig": good, "sim_cameras": bad, "real": bad})
    rig_only = bench_table([r3], ["net"])
    assert rig_only["goals"]["net_real_count_at_least_0.90"] == "refused"
    assert rig_only["goals"]["net_real_within_5_points_of_sim_rig"] == "refused"
    assert "refuses every capture here" in bench_markdown(rig_only)


def test_time_goal_judged_on_captures_of_30_frames_at_640x480_or_less():
    one = {"n_links": 1, "link_lengths_pu": [1.5, 0.5], "joint_angles_rad": [0.1]}
    good = {"combined": one, "measurement": one}
    sides = {"sim_rig": good, "sim_cameras": good, "real": good}
    big = [_result(1, sides, frames=48, predict_s=18.0), _result(1, sides, resolution="848x480", predict_s=12.0)]
    table = bench_table(big, [])
    assert table["goals"]["predict_at_most_10_s_up_to_30_frames_640x480"] is None  # no capture of that size
    assert table["overall"]["predict_combined_real_s"]["max"] == 18.0
    slow = bench_table([*big, _result(1, sides, frames=30, predict_s=10.5)], [])
    assert slow["overall"]["predict_combined_real_s_up_to_30_frames_640x480"] == {"captures": 1, "max": 10.5}
    assert slow["goals"]["predict_at_most_10_s_up_to_30_frames_640x480"] is False


def test_capture_settings_table():
    rows = capture_settings(BenchConfig())
    assert len(rows) == 24 and rows == capture_settings(BenchConfig())  # seeded: the same table every time
    assert [r.seed for r in rows] == list(range(30000, 30024)) and len({r.name for r in rows}) == 24
    for n in range(1, 7):
        mine = [r for r in rows if r.n_links == n]
        assert len(mine) == 4 and sum(r.hide_poses for r in mine) == 2  # half of each n without poses
        combos = {(r.renderer, r.hide_poses) for r in mine}
        assert len(combos) == 4  # each n: both renderers, each with and without poses
    sensors = [(r.noise, r.resolution) for r in rows]
    assert sensors.count(("realsense_d435", "848x480")) == 8 and sensors.count(("kinect_v1", "640x480")) == 8
    sweeps, frames = [r.sweep_deg for r in rows], [r.frames for r in rows]
    assert min(sweeps) == 120 and max(sweeps) == 360 and min(frames) == 15 and max(frames) == 60
    assert sorted({r.clutter for r in rows}) == [0, 1, 2, 3, 4]
    assert rows != capture_settings(BenchConfig(seed=30100))


@pytest.mark.parametrize(
    "cfg, word",
    [
        (BenchConfig(objects=0), "objects"),
        (BenchConfig(frames=(10, 5)), "frames"),
        (BenchConfig(sweep_deg=(20.0, 360.0)), "sweep_deg"),
        (BenchConfig(sensors=("realsense_sr300",)), "sensors"),
        (BenchConfig(sensors=("nosuch:640x480",)), "sensors"),
        (BenchConfig(sensors=("none:640x480",)), "sensors"),
        (BenchConfig(renderers=("blender",)), "renderers"),
        (BenchConfig(clutter_max=9), "clutter_max"),
    ],
)
def test_bad_config_names_the_parameter(cfg, word, tmp_path):
    with pytest.raises(SpareTwinError, match=f"^{word}"):
        sim2real.bench_sim2real(tmp_path / "b", cfg)
    assert not (tmp_path / "b").exists()


@pytest.mark.parametrize(
    "args, flag",
    [
        (["--effects", "shadows,nosuch"], "--effects"),
        (["--models", "nosuch-model"], "--models"),
        (["--workers", "0"], "--workers"),
        (["--sensors", "kinect_v1:9x9"], "--sensors"),
    ],
)
def test_bad_flags_are_one_line_naming_the_flag(args, flag, tmp_path, capsys):
    code, out, err = run_cli(["bench", "sim2real", "--out", str(tmp_path / "b"), *args], capsys)
    assert code != 0 and err.strip().count("\n") == 0 and flag in err and "Traceback" not in err
    assert not (tmp_path / "b").exists()


def test_a_bad_option_or_folder_is_said_before_torch_is_loaded(tmp_path):
    """A count out of range or a folder that is not a bench's: said before the bench's modules (torch, the
    measurement: 5 s of a new process) are imported, and nothing written."""
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("mine")
    cases = [
        (["--objects", "0"], ("--objects 0",)),
        (["--objects", "-3"], ("--objects -3",)),
        (["--workers", "0"], ("--workers 0",)),
        (["--clutter-max", "-1"], ("--clutter-max -1",)),
        (["--sim-frames", "0"], ("--sim-frames 0",)),
        (["--sensors", "kinect_v1:9x9"], ("--sensors",)),
        (["--out", "mine"], ("mine", "--force")),
    ]
    refused_before_torch([(["bench", "sim2real", "--out", "b", *args], words) for args, words in cases], tmp_path)


# the profile network's own estimate comes from the combined run; the temporal grey network reads 100
# frames, so it refuses these captures (the shipped image networks cost seconds a recording: left out)
TINY = ["--objects", "2", "--frames", "5-6", "--sensors", "realsense_sr300:160x120,realsense_d435:160x120"]
TINY += ["--clutter-max", "1", "--sim-frames", "1", "--models", "profile-multitask,grey-tmp-multitask"]


def _bench(out, *extra):
    from spare_twin.cli import main

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):
        assert main(["bench", "sim2real", "--out", str(out), *TINY, *extra, "--json"]) == 0
    return json.loads(buf.getvalue())


@pytest.fixture(scope="module")
def tiny_bench(tmp_path_factory):
    """`spare-twin bench sim2real` on two tiny captures (n = 1 and 2; pybullet with tracked poses, raycast
    with hidden ones), one worker."""
    out = tmp_path_factory.mktemp("bench") / "b"
    return out, _bench(out, "--workers", "1")


def test_bench_rows_columns_and_scores(tiny_bench):
    out, table = tiny_bench
    rows = ["combined", "measurement", "profile-multitask", "grey-tmp-multitask"]
    assert table["rows"] == rows and table["sides"] == ["sim_rig", "sim_cameras", "real"]
    assert set(table["per_n"]) == {"1", "2"} and table["overall"]["objects"] == 2
    assert json.loads((out / "sim2real.json").read_text()) == table and (out / "sim2real.png").is_file()
    md = (out / "sim2real.md").read_text()
    head = md.splitlines()[0]
    for side in ("sim rig", "sim, capture's cameras", "real"):
        for col in ("count acc.", "wrong", "none", "E_L", "angle err. (deg)"):
            assert f"| {col} {side} |" in head
    assert all(f"| 2 | {r} |" in md for r in rows)
    objs = table["objects"]
    assert [o["truth"]["n_links"] for o in objs] == [1, 2]
    assert [(o["settings"]["renderer"], o["settings"]["hide_poses"]) for o in objs] == [
        ("pybullet", False),
        ("raycast", True),
    ]
    for row in rows[:3]:
        for side in table["sides"]:
            answers = [o["sides"][side]["answers"][row] for o in objs]
            for a in answers:  # predict --json's keys, and the score of exactly this answer
                assert {"n_links", "link_lengths_pu", "joint_angles_rad", "source", "score"} <= set(a)
                truth = objs[answers.index(a)]["truth"]
                truth = {**truth, "joint_angles_rad": None} if side == "sim_rig" else truth
                assert a["score"] == json.loads(json.dumps(score_prediction(truth, a)))
            s = table["overall"]["answers"][row][side]
            true_n = [o["truth"]["n_links"] for o in objs]
            right = sum(a["n_links"] == n for a, n in zip(answers, true_n))
            wrong = sum(a["n_links"] not in (None, n) for a, n in zip(answers, true_n))
            assert s["count_accuracy"] == pytest.approx(right / 2)
            assert (s["wrong"], s["none"]) == (wrong, sum(a["n_links"] is None for a in answers))
            assert s["E_L"] == pytest.approx(np.mean([a["score"]["E_L"] for a in answers]))
    for o in objs:
        real = o["sides"]["real"]["answers"]
        assert real["combined"]["source"] in (None, "measurement", "network") or isinstance(
            real["combined"]["source"], dict
        )
        assert real["measurement"]["source"] in (None, "measurement")
        assert real["profile-multitask"]["source"] in (None, "network")


def test_refused_model_recorded_as_refused(tiny_bench):
    _, table = tiny_bench
    for o in table["objects"]:
        for side in table["sides"]:
            a = o["sides"][side]["answers"]["grey-tmp-multitask"]
            # the rig's single time step is too short for it; a hand-held camera is not what it reads
            why = "100 consecutive frames" if side == "sim_rig" else "reads a fixed camera only"
            assert why in a["refused"] and "score" not in a
    for side in table["sides"]:
        s = table["overall"]["answers"]["grey-tmp-multitask"][side]
        assert s["refused"] == 2 and s["objects"] == 0 and s["count_accuracy"] is None and s["wrong"] == 0


def test_every_capture_drew_every_effect_and_the_clean_render_follows_its_path(tiny_bench):
    """The capture predict reads is imported (no ground truth, no segmentation); its simulation drew every
    effect; the clean render has none but the hand's path and goes along exactly the same cameras."""
    from spare_twin.recording import Recording

    out, table = tiny_bench
    for o in table["objects"]:
        d = out / o["name"]
        sensor = Recording.open(d / "sensor")
        assert sensor.source["effects"]["on"] == list(EFFECTS) and o["effects_drawn"] == sensor.source["effects"]
        assert sensor.source.get("renderer", "pybullet") == o["settings"]["renderer"]
        assert "tilt_deg" in o["effects_drawn"]["drawn"]["print"]
        clean = Recording.open(d / "sim_cameras_sensor")
        assert clean.source["effects"]["on"] == ["hand"] and clean.source["noise"] is None
        np.testing.assert_array_equal(clean.ground_truth()["T_world_camera"], sensor.ground_truth()["T_world_camera"])
        real = Recording.open(d / "real")
        assert real.source["kind"] != "sim" and real.ground_truth() is None and real.segmentation("cam0", 0) is None
        assert real.n_frames == o["settings"]["frames"]
        assert (real.cameras[0].width, real.cameras[0].height) == (160, 120)
        assert (real.cameras[0].poses == "unknown") == o["settings"]["hide_poses"]
        if not o["settings"]["hide_poses"]:  # the tracker's poses (pose_error), not the true ones
            got = np.stack([real.T_world_camera("cam0", t) for t in range(real.n_frames)])
            true = sensor.ground_truth()["T_world_camera"]
            assert 0 < np.abs(got[:, :3, 3] - true[:, :3, 3]).max()


def _without_times(objects):
    return [{k: v for k, v in o.items() if k != "times_s"} for o in objects]


def test_the_same_results_with_two_workers(tiny_bench, tmp_path):
    _, table = tiny_bench
    two = _bench(tmp_path / "b2", "--workers", "2")
    assert _without_times(two["objects"]) == _without_times(table["objects"])
    assert two["overall"]["answers"] == table["overall"]["answers"] and two["per_n"] == table["per_n"]


def test_second_run_reuses_every_object(tiny_bench, capsys, monkeypatch):
    out, table = tiny_bench

    def refuse(*a, **k):
        raise AssertionError("a finished object was drawn or predicted again")

    monkeypatch.setattr(compare_answers, "predict_recording", refuse)
    monkeypatch.setattr(capture, "render_recording", refuse)
    code, stdout, err = run_cli(["bench", "sim2real", "--out", str(out), *TINY], capsys)
    assert code == 0, err
    assert "| 2 | combined |" in stdout and "wrote" in stdout
    assert json.loads((out / "sim2real.json").read_text())["objects"] == table["objects"]


def test_changed_predict_key_predicts_again_on_the_kept_captures(tiny_bench, capsys, monkeypatch):
    """An object whose stored result was made by other models (or code) is predicted again, on the
    captures it already has; the other object is kept as it was."""
    out, table = tiny_bench
    stale = out / "seed30001" / "result.json"
    r = json.loads(stale.read_text())
    r["key"]["predict"]["version"] = "0.0.0"
    stale.write_text(json.dumps(r))
    calls = []

    def fake_predict(rec, *a, **k):
        from spare_twin.predict.estimate import Estimate, Prediction

        calls.append(rec.parent.name)
        answer = Estimate(1, (1.5, 0.5), (0.0,))
        return Prediction(answer, {"n_links": "measurement"}, None, answer, "combined", "profile", None, str(rec), 0.08)

    def refuse(*a, **k):
        raise AssertionError("a kept capture was drawn again")

    monkeypatch.setattr(compare_answers, "predict_recording", fake_predict)
    monkeypatch.setattr(capture, "render_recording", refuse)
    code, _, err = run_cli(["bench", "sim2real", "--out", str(out), *TINY], capsys)
    assert code == 0, err
    assert set(calls) == {"seed30001"} and len(calls) == 3 * 2  # three sides: combined and the temporal net
    again = json.loads((out / "sim2real.json").read_text())["objects"]
    assert _without_times(again[:1]) == _without_times(table["objects"][:1])  # kept as it was
    assert again[1]["sides"]["real"]["answers"]["measurement"]["n_links"] == 1  # predicted again


def test_compare_batch_reports_each_answer_alone(tmp_path, monkeypatch):
    """`compare --batch`: per pair, the combined answer and its estimates from compare's own predictions,
    each other network alone on both sides; the rows in the table (JSON and Markdown), wrong apart from
    none, a network that refuses a recording recorded as refused."""
    from spare_twin.compare import batch

    truth = {"n_links": 2, "link_lengths_pu": [1.5, 0.5, 0.4], "joint_angles_rad": [0.3, -0.2]}
    one = {"n_links": 1, "link_lengths_pu": [1.5, 0.9], "joint_angles_rad": [0.3]}

    def side(answer, network, measurement):
        return {**answer, "source": "measurement", "network": network, "measurement": measurement}

    class FakeComparison:
        def __init__(self, sim_dir):
            self.sim_dir = sim_dir

        def to_json(self):
            sim = side(TRUTH, one, TRUTH)
            real = side({**NONE, "source": None}, WRONG, None)
            errors = {s: {"count_correct": s == "sim", "E_L": 0.0} for s in ("sim", "real", "real_twin_aligned")}
            return {
                "truth": truth,
                "sim": sim,
                "real": real,
                "real_twin_aligned": real,
                "errors": {**errors, "joint_angles_deg": None, "real_joint_angles_deg": None},
                "sim_recording": str(self.sim_dir),
                "model": "m",
                "settings": batch.CompareConfig().settings(),
            }

    def fake_compare(object_dir, real_dir, model=None, sim_dir=None, force=False):
        return FakeComparison(sim_dir)

    def fake_predict(rec, model, progress=False, answer="combined", parts=None):
        raise CaptureRefused("the temporal model reads 100 consecutive frames of one camera")

    for name in ("a", "b"):
        for sub in ("object", "real", "sim_twin"):
            (tmp_path / "pairs" / name / sub).mkdir(parents=True)
    monkeypatch.setattr(batch, "compare", fake_compare)
    monkeypatch.setattr(compare_answers, "predict_recording", fake_predict)
    table, files = batch.compare_batch(
        tmp_path / "pairs", tmp_path / "t", progress=False, models=["profile-multitask", "grey-tmp-multitask"]
    )
    a = table["answers"]
    assert a["rows"] == ["combined", "measurement", "profile-multitask", "grey-tmp-multitask"]
    assert a["sides"] == ["sim", "real"] and list(a["per_n"]) == ["2"]
    real, sim = {r: a["overall"][r]["real"] for r in a["rows"]}, {r: a["overall"][r]["sim"] for r in a["rows"]}
    assert (real["combined"]["none"], real["combined"]["wrong"], real["combined"]["count_accuracy"]) == (2, 0, 0.0)
    assert real["measurement"]["none"] == 2  # the measurement gave nothing
    assert (real["profile-multitask"]["wrong"], real["profile-multitask"]["none"]) == (2, 0)  # the network's own
    assert sim["combined"]["count_accuracy"] == 1.0 and sim["profile-multitask"]["wrong"] == 2
    assert real["grey-tmp-multitask"] == {**real["grey-tmp-multitask"], "refused": 2, "objects": 0}
    stored = json.loads((tmp_path / "pairs" / "a" / "compare.json").read_text())["answers"]
    assert "100 consecutive frames" in stored["sides"]["real"]["answers"]["grey-tmp-multitask"]["refused"]
    md = (tmp_path / "t" / "sim2real.md").read_text()
    assert "Each answer alone" in md and "| 2 | grey-tmp-multitask | refused |" in md
    assert "| count acc. sim, real cameras |" in md and "| 2 | measurement |" in md


@pytest.mark.parametrize(
    "text, on",
    [("all", list(EFFECTS)), ("none", []), ("shadows,joint_play", ["joint_play", "shadows"]), ("FILE", ["hand"])],
)
def test_effects_flag_reaches_the_bench(text, on, tmp_path, capsys, monkeypatch):
    """--effects all|none|A,B|FILE.json: the switches (and a file's ranges) the bench captures with."""
    seen = {}

    def fake_bench(out, cfg, models, workers, force=False):
        seen["cfg"] = cfg
        return {"rows": []}, {}

    monkeypatch.setattr(sim2real, "bench_sim2real", fake_bench)
    if text == "FILE":
        text = str(tmp_path / "fx.json")
        (tmp_path / "fx.json").write_text(json.dumps({**{e: False for e in EFFECTS}, "hand": True, "roll_deg": 3.0}))
    code, _, err = run_cli(["bench", "sim2real", "--out", str(tmp_path / "b"), "--effects", text, "--json"], capsys)
    assert code == 0, err
    assert list(seen["cfg"].effects.on) == on
    if text.endswith(".json"):
        assert seen["cfg"].effects.roll_deg == 3.0
