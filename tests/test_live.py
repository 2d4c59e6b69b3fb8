"""`spare-twin live` (issue 29): a simulated hand-held sweep replayed as a stream; the updates converge
to `predict`'s answer on the recording live wrote; Ctrl-C keeps a recording predict reads; the view
is an .rrd Rerun accepts, the twin's URDF in it; a bad source is one line."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli

PREDICT_KEYS = ("n_links", "link_lengths_pu", "link_lengths_mm", "joint_angles_rad", "source", "network", "measurement")
SPARE_TWIN = Path(sys.executable).with_name("spare-twin")


@pytest.fixture(scope="module")
def replayed(sweep, tmp_path_factory):
    """`live --replay --speed 0 --jsonl --rrd` of the hand-held sweep (every frame used: deterministic
    placing), and `predict --json` on the recording it wrote."""
    root = tmp_path_factory.mktemp("live")
    out, rrd = root / "rec", root / "live.rrd"
    argv = ["live", "--replay", str(sweep), "--speed", "0", "--jsonl", "--rrd", str(rrd), "--out", str(out)]
    # the last update, once the stream has ended, reads 16 views: every frame placed, as predict reads them
    cmd = [str(SPARE_TWIN), *argv, "--update-s", "0.2", "--stable-s", "0.3", "--views", "16"]
    live = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert live.returncode == 0, live.stderr[-2000:]
    predict = subprocess.run([str(SPARE_TWIN), "predict", str(out), "--json"], capture_output=True, text=True)
    assert predict.returncode == 0, predict.stderr[-2000:]
    lines = [json.loads(line) for line in live.stdout.splitlines()]
    return lines, json.loads(predict.stdout), out, rrd, live.stderr


def test_updates_converge_to_predict_on_the_recording_live_wrote(replayed):
    lines, predicted, out, _, _ = replayed
    assert len(lines) >= 3  # updates while frames come in, then the final answer
    for line in lines:
        assert all(k in line for k in (*PREDICT_KEYS, "t_s", "frames_used"))
        assert line["format"] == "spare-twin-prediction" and line["version"] == 2
    *updates, final = lines
    assert final["final"] and not any(u["final"] for u in updates)
    assert [u["t_s"] for u in updates] == sorted(u["t_s"] for u in updates)
    assert updates[-1]["frames_placed"] == updates[-1]["frames_received"] == 16  # speed 0: nothing dropped
    # the final answer is predict's on the recording written: the same count, the same lengths
    assert predicted["n_links"] == final["n_links"] == 2
    assert np.allclose(final["link_lengths_pu"], predicted["link_lengths_pu"], atol=0.01)
    # ... and the last update, from the frames placed on the way, already says it
    last = updates[-1]
    assert last["n_links"] == predicted["n_links"]
    assert np.abs(np.subtract(last["link_lengths_pu"], predicted["link_lengths_pu"])).max() < 0.01
    assert last["measurement"] is not None and last["source"] is not None


def test_the_recording_holds_every_frame_of_the_stream(replayed, sweep):
    from spare_twin.recording import Recording

    _, _, out, _, _ = replayed
    src, rec = Recording.open(sweep), Recording.open(out)
    assert rec.n_frames == src.n_frames and rec.camera_poses("cam0") is None  # a sensor's stream: poses unknown
    for f in (0, src.n_frames // 2, src.n_frames - 1):
        assert np.array_equal(rec.depth_raw("cam0", f), src.depth_raw(src.cameras[0].name, f))
        assert np.array_equal(rec.color("cam0", f), src.color(src.cameras[0].name, f))
    assert rec.depth_scale == src.depth_scale and np.allclose(rec.cameras[0].K, src.cameras[0].K)
    # a replay copies its files as they are (nothing decoded and encoded again): byte for byte, every frame
    for kind in ("color", "depth"):
        ours = sorted((out / "cameras" / "cam0" / kind).glob("*.png"))
        theirs = sorted((sweep / "cameras" / src.cameras[0].name / kind).glob("*.png"))
        assert len(ours) == len(theirs) == 16
        assert all(a.read_bytes() == b.read_bytes() for a, b in zip(ours, theirs))


def test_enough_needs_the_answer_held_with_strong_evidence():
    """`held_for_s` and `is_strong`, which say "enough", on updates made up here (a replay's timing
    decides how many real updates there are)."""
    from spare_twin.live.estimate import STRONG_RMS_M, is_strong
    from spare_twin.live.session import Update, enough_words, held_for_s
    from spare_twin.predict.estimate import Estimate, MeasurementEvidence, Prediction

    def update(t_s, n, lengths, rms_m=0.0005):
        m = Estimate(n, lengths, (0.1,) * n, MeasurementEvidence(rms_m, (500, 300, 200))) if n else None
        answer = m or Estimate.none("no chain in view")
        source = {"n_links": "measurement"} if n else None
        pred = Prediction(answer, source, None, m, "measurement", "test", None, "rec", 0.08)
        return Update(pred, t_s, t_s, 8, 10, 10, 0)

    a, b = (1.5, 0.8, 0.7), (1.5, 0.81, 0.7)  # within STABLE_LENGTHS_PU of each other
    ups = [update(0.0, None, None), update(1.0, 2, a), update(2.5, 2, b), update(4.5, 2, a)]
    assert held_for_s(ups[:2]) == 0.0 and held_for_s(ups[:3]) == 1.5 and held_for_s(ups) == 3.5
    assert held_for_s([*ups, update(5.0, 3, (1.5, 0.8, 0.7, 0.4))]) == 0.0  # the count changed: starts again
    assert held_for_s([*ups, update(5.0, 2, (1.5, 0.9, 0.7))]) == 0.0  # a length moved 0.1 pu
    assert is_strong(ups[1].prediction) and not is_strong(ups[0].prediction)
    assert not is_strong(update(1.0, 2, a, rms_m=2 * STRONG_RMS_M).prediction)  # blurred: not strong
    assert enough_words(ups[-1]).startswith("enough: n = 2, lengths 1.500, 0.800, 0.700")


def test_a_full_queue_drops_its_oldest_frame():
    import queue

    from spare_twin.live.session import _offer_newest, _Shared

    q, sh = queue.Queue(maxsize=2), _Shared()
    for f in range(5):
        _offer_newest(q, f, sh)
    assert [q.get_nowait(), q.get_nowait()] == [3, 4] and sh.dropped == 3  # the tracker takes the newest


def test_the_tracker_lets_go_frames_the_camera_has_barely_moved_from():
    from spare_twin.live.track import MAX_GAP_S, MIN_STEP_DEG, Tracker

    tr = Tracker(np.eye(3), 0.001)
    assert not tr.too_close(0.01)  # nothing placed yet: no rate to judge by
    tr._rate, tr._last_t_s = (40.0, 0.1), 1.0  # turning 40 deg/s, moving 0.1 m/s
    assert tr.too_close(1.0 + 0.9 * MIN_STEP_DEG / 40.0)  # not yet MIN_STEP_DEG turned
    assert not tr.too_close(1.0 + 1.1 * MIN_STEP_DEG / 40.0)
    tr._rate = (0.0, 0.0)  # standing still: placed again after MAX_GAP_S all the same
    assert tr.too_close(1.0 + 0.9 * MAX_GAP_S) and not tr.too_close(1.0 + MAX_GAP_S)


def test_while_the_frames_go_too_little_round_the_chain_updates_say_so_without_measuring():
    from spare_twin.live.session import _arc_short_of, _still_too_little
    from spare_twin.live.track import PlacedFrame
    from spare_twin.predict.abstain import MIN_ARC_DEG
    from spare_twin.predict.estimate import Estimate, Prediction

    def frames(span_deg: float) -> list[PlacedFrame]:
        out = []
        for i, a in enumerate(np.radians(np.linspace(0.0, span_deg, 6))):
            T = np.eye(4)
            T[:3, 3] = [0.4 * np.cos(a), 0.4 * np.sin(a), 0.3]  # cameras round the axis at (0, 0)
            out.append(PlacedFrame(i, i / 30, None, T))
        return out

    axis = np.eye(4)
    assert _arc_short_of(frames(45.0), 8, axis) == pytest.approx(45.0, abs=0.1)
    assert _arc_short_of(frames(MIN_ARC_DEG + 1), 8, axis) is None
    assert _arc_short_of(frames(10), 8, None) is None  # no chain seen yet: the update runs and looks

    earlier = Prediction(Estimate.none("the views go 20 deg round it"), None, Estimate(2, (1.0, 0.5, 0.5), (0.1, 0.2)),
                         Estimate.none("x"), "combined", "views", "m.pt", "rec", 0.08)  # fmt: skip
    again = _still_too_little(earlier, 45.0)
    assert again.n_links is None and again.answer.reason.startswith("the views go 45 deg round it")
    assert again.network is None and again.measurement is None and again.source is None  # nothing ran


def test_updates_start_early_enough_to_answer_within_update_s():
    from spare_twin.live.config import LiveConfig
    from spare_twin.live.session import POLL_S, UPDATE_MARGIN, _adapted, _next_start

    cfg = LiveConfig(update_s=1.0)
    for took_s in (0.1, 0.3, 0.5, 0.6):
        start = _next_start(10.0, took_s, cfg)  # the last answer came at 10 s after `took_s`
        assert 10.0 <= start and start + UPDATE_MARGIN * took_s <= 10.0 + cfg.update_s - POLL_S + 1e-9
    assert _next_start(10.0, 0.9, cfg) == 10.0  # as soon as it can: it takes nearly update_s
    assert _adapted(8, 0.3, cfg) == 10 and _adapted(8, 0.9, cfg) == 6 and _adapted(8, 0.6, cfg) == 8


def test_updates_read_few_views_until_the_first_count_and_all_at_the_end():
    from spare_twin.live.config import LiveConfig
    from spare_twin.live.session import MIN_VIEWS, _views_for

    cfg = LiveConfig(views=16)
    assert _views_for(8, ended=False, counted=False, cfg=cfg) == MIN_VIEWS  # the first count comes sooner
    assert _views_for(8, ended=False, counted=True, cfg=cfg) == 8  # then the rate's own choice
    assert _views_for(8, ended=True, counted=False, cfg=cfg) == 16  # the stream has ended: every view asked for


def test_the_estimate_process_answers_as_the_thread_and_ends_with_its_pipe(sweep):
    """The measurement in its own process (`measure.process`) gives the very answer it gives in-thread; a
    one-line error in it is one line here; it ends when the parent closes its pipe (as when it dies)."""
    import threading

    from spare_twin.config import PartDims
    from spare_twin.errors import SpareTwinError
    from spare_twin.live.estimate import estimate_from_frames, load_estimator, view_arrays
    from spare_twin.live.sources import ReplaySource
    from spare_twin.live.track import Tracker
    from spare_twin.measure.process import MeasureProcess
    from spare_twin.predict.abstain import MIN_ARC_DEG

    src = ReplaySource(sweep, speed=0)
    tracker = Tracker(src.info.K, src.info.depth_scale)
    for f in src.frames(threading.Event()):
        tracker.add(f)
    est = load_estimator(None, "measurement", 0.08)
    process = MeasureProcess()
    try:
        here = estimate_from_frames(est, tracker.kept, 8)
        there = estimate_from_frames(est, tracker.kept, 8, process)
        assert here.n_links == 2 and there.to_json() == here.to_json()
        with pytest.raises(SpareTwinError, match="print_scale"):
            process.measure(view_arrays(tracker.kept[:3]), 3, -1.0, PartDims(), MIN_ARC_DEG)
        assert estimate_from_frames(est, tracker.kept, 8, process).to_json() == here.to_json()  # still serving
    finally:
        process.close()
    assert process._proc.returncode == 0 and process.peak_rss_mb > 50.0
    orphan = MeasureProcess()
    orphan._requests.close()  # what the parent's death does to the pipe
    assert orphan._proc.wait(timeout=30) == 0
    orphan._replies.close()


def test_enough_in_the_replay_agrees_with_the_final_answer(replayed):
    lines, _, _, _, stderr = replayed
    enough = [u for u in lines if u["enough"]]
    assert len(enough) <= 1 and stderr.count("enough: n = ") == len(enough)
    for u in enough:
        assert u["n_links"] == lines[-1]["n_links"]


def test_the_rrd_is_accepted_by_rerun_and_poses_the_urdf_twin(replayed):
    _, _, _, rrd, _ = replayed
    rerun = Path(sys.executable).with_name("rerun")
    if not rerun.is_file():
        pytest.skip("no rerun command")
    verify = subprocess.run([str(rerun), "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=120)
    assert verify.returncode == 0, verify.stderr[-2000:]
    printed = subprocess.run([str(rerun), "rrd", "print", str(rrd)], capture_output=True, text=True, timeout=120)
    text = printed.stdout + printed.stderr
    # the twin through Rerun's URDF loader (its meshes as Asset3D under the robot), posed by joint transforms
    assert "visual_geometries/link2" in text and "Asset3D:blob" in text
    assert "/twin0/joints/joint1" in text and "/twin0/root" in text
    for entity in ("/world/camera/image", "/world/points", "/world/chain", "/estimate/length_pu/L0"):
        assert entity + " " in text


def test_until_stable_stops_the_stream_at_enough(sweep, tmp_path, capsys):
    out = tmp_path / "rec"
    # a frame every second: the answer holds for 0.3 s of the stream (3 frames) before its 16 frames are in
    argv = ["live", "--replay", str(sweep), "--speed", "0.1", "--no-viewer", "--jsonl", "--answer", "measurement"]
    code, stdout, err = run_cli([*argv, "--update-s", "0.2", "--stable-s", "0.3", "--until-stable", "--out", str(out)],
                                capsys)  # fmt: skip
    assert code == 0, err
    from spare_twin.recording import Recording

    *updates, final = [json.loads(line) for line in stdout.splitlines()]
    assert updates[-1]["enough"] and not any(u["enough"] for u in updates[:-1])  # no update after enough
    assert final["final"] and Recording.open(out).n_frames == final["frames_received"] < 16
    assert "enough: n = 2" in err


def test_sigint_mid_replay_leaves_a_recording_predict_reads(sweep, tmp_path):
    out = tmp_path / "rec"
    cmd = [str(SPARE_TWIN), "live", "--replay", str(sweep), "--speed", "0.2", "--no-viewer", "--jsonl"]
    proc = subprocess.Popen(
        [*cmd, "--answer", "measurement", "--update-s", "0.3", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    first = proc.stdout.readline()  # the first update: frames are coming in (two a second)
    assert first, proc.stderr.read()[-2000:]
    proc.send_signal(signal.SIGINT)
    rest, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err[-2000:]
    assert "stopped by Ctrl-C after" in err and "Traceback" not in err
    final = json.loads(rest.splitlines()[-1])
    assert final["final"]
    from spare_twin.recording import Recording

    rec = Recording.open(out)
    rec.validate()
    assert 1 <= rec.n_frames < 16 and final["frames_received"] == rec.n_frames
    predict = subprocess.run([str(SPARE_TWIN), "predict", str(out), "--json", "--answer", "measurement"],
                             capture_output=True, text=True)  # fmt: skip
    assert predict.returncode == 0, predict.stderr[-2000:]
    assert not list(tmp_path.glob(".*spare-twin*"))  # no temporary left beside it


def _one_line_error(code: int, err: str, *words: str) -> None:
    assert code == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert all(w in lines[0] for w in words), lines[0]


def test_a_missing_replay_folder_is_one_line(tmp_path, capsys):
    out = tmp_path / "rec"
    code, _, err = run_cli(["live", "--replay", str(tmp_path / "nope"), "--no-viewer", "--out", str(out)], capsys)
    _one_line_error(code, err, "nope", "no such recording folder")
    assert not out.exists()


def test_a_missing_bag_is_one_line(tmp_path, capsys):
    code, _, err = run_cli(
        ["live", "--bag", str(tmp_path / "x.bag"), "--no-viewer", "--out", str(tmp_path / "r")], capsys
    )
    _one_line_error(code, err, "x.bag", "no such file")


def test_no_device_is_one_line(tmp_path, capsys):
    code, _, err = run_cli(["live", "--no-viewer", "--out", str(tmp_path / "r")], capsys)
    _one_line_error(code, err, "RealSense")
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize(
    "source, words",
    [
        ([], ("RealSense",)),
        (["--replay", "nope"], ("nope", "no such recording folder")),
        (["--update-s", "0"], ("--update-s", "positive")),
    ],
)
def test_a_bad_source_or_option_is_said_before_torch_is_loaded(source, words, tmp_path):
    """No device, no such folder or a bad number: said before the estimate's modules (torch, the
    measurement: 5 s of a new process) are imported, and nothing written."""
    probe = (
        "import sys; from spare_twin.cli import main;"
        f"code = main(['live', '--no-viewer', '--out', 'r', *{source!r}]);"
        "print(code, 'torch' in sys.modules, 'spare_twin.measure.layers' in sys.modules)"
    )
    res = subprocess.run([sys.executable, "-c", probe], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert res.stdout.split() == ["1", "False", "False"], (res.stdout, res.stderr)
    _one_line_error(1, res.stderr, *words)
    assert not (tmp_path / "r").exists()


def test_a_corrupt_frame_is_one_line_and_writes_nothing(sweep, tmp_path, capsys):
    bad = tmp_path / "bad"
    shutil.copytree(sweep, bad)
    depth = sorted((bad / "cameras").glob("*/depth/*.png"))[5]
    depth.write_bytes(depth.read_bytes()[:100])  # cut off mid-file
    out = tmp_path / "rec"
    argv = ["live", "--replay", str(bad), "--speed", "0", "--no-viewer", "--answer", "measurement", "--out", str(out)]
    code, _, err = run_cli(argv, capsys)
    _one_line_error(code, err, depth.name)
    assert not out.exists() and not list(tmp_path.glob(".*spare-twin*"))


def test_bad_options_are_one_line(sweep, tmp_path, capsys):
    base = ["live", "--replay", str(sweep), "--no-viewer", "--out", str(tmp_path / "r")]
    for extra, words in (
        (["--speed", "-1"], ("--speed",)),
        (["--stable-s", "0"], ("--stable-s",)),
        (["--views", "1"], ("--views",)),
        (["--rrd", str(tmp_path / "v.rrd"), "--object", str(tmp_path / "no_object")], ("no_object",)),
    ):
        code, _, err = run_cli([*base, *extra], capsys)
        _one_line_error(code, err, *words)
    assert not (tmp_path / "r").exists() and not (tmp_path / "v.rrd").exists()


def test_an_output_that_is_not_a_live_recording_is_refused(sweep, tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    code, _, err = run_cli(["live", "--replay", str(sweep), "--no-viewer", "--out", str(out)], capsys)
    _one_line_error(code, err, "mine")
    assert (out / "notes.txt").read_text() == "mine"
    assert os.listdir(out) == ["notes.txt"]


def test_compare_rrd_poses_the_urdf_twins_per_frame(printed_object, tmp_path):
    """compare's .rrd: the printed twin through Rerun's URDF support, sim posed per frame by the simulated
    angles, real by predict's, their difference a time series; no meshes posed by hand."""
    from spare_twin.compare.rerun_log import ComparisonLog, log_comparison
    from spare_twin.recording import Camera, Recording, RecordingWriter

    K = np.array([[100.0, 0, 31.5], [0, 100.0, 23.5], [0, 0, 1]])
    recs = []
    for name in ("real", "sim"):
        with RecordingWriter(tmp_path / name, [Camera("cam0", 64, 48, K, np.eye(4))], 3, 10.0, {"kind": "sim"}) as w:
            for f in range(3):
                w.add_frame("cam0", f, np.full((48, 64, 3), 100, np.uint8), np.full((48, 64), 0.5, np.float32))
            w.set_ground_truth(joint_angles_rad=np.array([[0.1, 0.2], [0.2, 0.3], [0.3, 0.4]]))
        recs.append(Recording.open(tmp_path / name))
    side = {"n_links": 2, "link_lengths_pu": [1.5, 0.8, 0.7]}
    result = {"truth": side, "sim": side, "real": {**side, "joint_angles_rad": [0.25, 0.25]}, "errors": {}}
    rrd = tmp_path / "cmp.rrd"
    views = np.ones((8, 96, 128))
    log = ComparisonLog(result, np.zeros((5, 3)), np.full((5, 3), 0.5), [], views, views, recs[0], recs[1],
                        urdf_path=printed_object.urdf_path)  # fmt: skip
    log_comparison(rrd, log)
    rerun = Path(sys.executable).with_name("rerun")
    assert subprocess.run([str(rerun), "rrd", "verify", str(rrd)], capture_output=True).returncode == 0
    text = subprocess.run([str(rerun), "rrd", "print", str(rrd)], capture_output=True, text=True).stdout
    robot = printed_object.urdf_path.stem
    for entity in (f"/twin_sim/{robot}/visual_geometries/link2", f"/twin_real/{robot}/visual_geometries/link2",
                   "/twin_sim/joints/joint1", "/twin_real/joints/joint2", "/angle_error_deg/joint2"):  # fmt: skip
        assert entity in text, entity
    assert "/world/twin/link0" not in text


def test_bench_live_reports_its_figures_with_the_estimate_process(sweep):
    """`bench live`'s figures on the tests' sweep (no timing asserted: timings belong to the benchmark):
    the first count's stream time, the last frame's wall time, both processes' memory, the load."""
    from spare_twin.bench.live import LiveBench, bench_live

    fig = bench_live(LiveBench(rec=str(sweep), speed=0.0), log=lambda line: None).to_json()
    assert fig["frames_received"] == fig["frames_placed"] == 16 and fig["frames_dropped"] == 0
    assert 0.0 <= fig["first_estimate_stream_s"] <= fig["stream_s"] and fig["last_frame_wall_s"] >= 0.0
    assert 50.0 < fig["peak_rss_estimate_process_mb"] < fig["peak_rss_mb"]  # its own process ran (no torch in it)
    assert len(fig["load_average"]) == 2 and fig["same_count"] and fig["final"]["n_links"] == 2
