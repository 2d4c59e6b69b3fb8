"""`spare-twin live`: frames in, written as a recording, placed one by one, the chain estimated at
least once a second, and the final answer `predict`'s on what was written.

Three threads and a process share the work:

- the reader takes each frame from the source as it comes (`live.sources`), appends it to the
  recording (`RecordingWriter` as a stream: nothing seen is lost) and offers it to a queue of
  `queue_frames`; when the queue is full the oldest frame waiting is dropped from the estimate (it is
  still in the recording) and counted: frames that come faster than they can be used never pile up,
  and the tracker takes the newest. With `speed` 0 (a replay as fast as it is used) the reader waits
  instead, and no frame is dropped;
- the tracker (the calling thread) places each queued frame against the last one (`live.track`);
- the estimator, every `update_s` seconds that new frames were placed, estimates the chain from the
  frames kept (`live.estimate`; the observation and measurement in a process of its own,
  `measure.process`, so that they run beside the tracker) and reports it: an update (`on_update`), the
  live view, and once the answer has held for `stable_s` seconds of the stream with strong evidence,
  "enough" (with `until_stable`, the stream stops there).

Ctrl-C (SIGINT) stops the reader; the recording is finalised with every frame received, and the final
answer is `predict` on it. Figures a run measures (`LiveResult`): the first estimate's time, the
intervals between updates, frames dropped.
"""

from __future__ import annotations

import dataclasses
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spare_twin.live.config import LIVE, LiveConfig
from spare_twin.live.estimate import Estimator, estimate_and_arc, final_estimate, is_strong, spread
from spare_twin.live.sources import Source, StoredFrame, StreamFrame
from spare_twin.live.track import Tracker
from spare_twin.measure.process import MeasureProcess
from spare_twin.observe.chain import arc_round_deg
from spare_twin.output import check_output
from spare_twin.predict.abstain import MIN_ARC_DEG, too_little_arc
from spare_twin.predict.estimate import Estimate, Prediction
from spare_twin.recording import Camera, RecordingWriter

#: Lengths (paper units) within which two updates count as the same answer for "enough".
STABLE_LENGTHS_PU = 0.02


@dataclass(frozen=True)
class Update:
    """One estimate as `live --jsonl` prints it: `predict`'s answer plus when and from what."""

    prediction: Prediction
    t_s: float
    """Stream seconds of the newest frame it read."""
    wall_s: float
    """Wall seconds since the first frame came in, when it was reported."""
    frames_used: int
    frames_received: int
    frames_placed: int
    frames_dropped: int
    enough: bool = False
    final: bool = False

    def to_json(self) -> dict:
        return {
            **self.prediction.to_json(),
            "t_s": round(self.t_s, 3),
            "frames_used": self.frames_used,
            "frames_received": self.frames_received,
            "frames_placed": self.frames_placed,
            "frames_dropped": self.frames_dropped,
            "wall_s": round(self.wall_s, 3),
            "enough": self.enough,
            "final": self.final,
        }


@dataclass
class LiveResult:
    updates: list[Update] = field(default_factory=list)
    final: Update | None = None
    enough_at: Update | None = None
    interrupted: bool = False
    frames_received: int = 0
    frames_dropped: int = 0
    frames_placed: int = 0
    stream_s: float = 0.0
    """Stream seconds of the last frame received."""
    estimate_process_rss_mb: float | None = None
    """Peak memory of the estimate's process (`measure.process`), None without one."""
    stream_wall_s: float = 0.0
    """Wall seconds from the first frame's arrival to the last's (more than `stream_s`: the reader
    fell behind the source)."""


class _Shared:
    """What the three threads share, under one lock."""

    def __init__(self):
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.done = threading.Event()
        """The reader has ended."""
        self.tracked = threading.Event()
        """The tracker has ended (every frame it will take is placed)."""
        self.error: BaseException | None = None
        self.received = 0
        self.dropped = 0
        self.t0_wall: float | None = None
        self.last_t_s = 0.0
        self.last_wall: float | None = None


def _read(source: Source, writer: RecordingWriter, q: queue.Queue, sh: _Shared, wait: bool) -> None:
    """The reader thread (see the module doc)."""
    try:
        for f in source.frames(sh.stop):
            f.write_to(writer)
            with sh.lock:
                sh.received += 1
                sh.last_t_s, sh.last_wall = f.t_s, time.monotonic()
                if sh.t0_wall is None:
                    sh.t0_wall = sh.last_wall
            if wait:
                while not sh.stop.is_set():
                    try:
                        q.put(f, timeout=0.1)
                        break
                    except queue.Full:
                        continue
            else:
                _offer_newest(q, f, sh)
            if sh.stop.is_set():
                break
    except BaseException as err:  # handed to the calling thread, which raises it
        sh.error = err
    finally:
        sh.done.set()


def _offer_newest(q: queue.Queue, f, sh: _Shared) -> None:
    """Queue `f`; when the queue is full, the oldest frame waiting goes instead (counted as dropped):
    the tracker then always takes the newest frames, and the estimate trails the camera by one
    frame's placing rather than by the queue's length of stale frames."""
    while True:
        try:
            q.put_nowait(f)
            return
        except queue.Full:
            try:
                q.get_nowait()
            except queue.Empty:  # the tracker took it meanwhile
                continue
            with sh.lock:
                sh.dropped += 1


def _same(a: Prediction, b: Prediction) -> bool:
    if a.n_links is None or a.n_links != b.n_links:
        return False
    return float(np.max(np.abs(np.subtract(a.link_lengths_pu, b.link_lengths_pu)))) <= STABLE_LENGTHS_PU


def held_for_s(updates: list[Update]) -> float:
    """Stream seconds the newest update's answer has held (the same count, lengths within
    `STABLE_LENGTHS_PU`) through the updates before it; 0 for no answer."""
    if not updates or updates[-1].prediction.n_links is None:
        return 0.0
    last, start = updates[-1], updates[-1]
    for u in reversed(updates[:-1]):
        if not _same(u.prediction, last.prediction):
            break
        start = u
    return last.t_s - start.t_s


def enough_words(u: Update) -> str:
    p = u.prediction
    mm = ", ".join(f"{v:.1f}" for v in p.link_lengths_mm)
    pu = ", ".join(f"{v:.3f}" for v in p.link_lengths_pu)
    return (
        f"enough: n = {p.n_links}, lengths {pu} (paper units, base first; {mm} mm) at {u.t_s:.1f} s "
        f"of the stream, {u.frames_received} frames"
    )


def run_live(
    source: Source,
    out: str | Path,
    est: Estimator,
    cfg: LiveConfig = LiveConfig(),
    on_update: Callable[[Update], None] = lambda u: None,
    say: Callable[[str], None] = lambda line: None,
    view=None,
    force: bool = False,
    wait_for_use: bool = False,
) -> LiveResult:
    """Run `live` on `source`, writing the recording to `out` (see the module doc). `on_update` gets
    each update and then the final answer; `say` gets lines for a person; `view` (a
    `live.rerun_view.LiveView`) is shown every frame placed and every update. `wait_for_use`: the
    reader waits for the tracker instead of dropping frames (a replay at speed 0)."""
    info = source.info
    inputs = (info.path,) if info.path is not None else ()
    check_output(out, LIVE, inputs, force)
    camera = Camera("cam0", info.width, info.height, info.K, None, "unknown")
    tracker = Tracker(info.K, info.depth_scale, cfg.work_width, cfg.max_kept)
    res, sh = LiveResult(), _Shared()
    q: queue.Queue = queue.Queue(maxsize=cfg.queue_frames)
    writer = RecordingWriter(out, [camera], None, info.fps, info.source, depth_scale=info.depth_scale,
                             kind=LIVE, inputs=inputs, force=force)  # fmt: skip
    # started (and waited for) before the stream, so that its start-up takes nothing from the first frames
    process = MeasureProcess() if cfg.estimate_process else None
    try:
        _run(source, writer, est, cfg, tracker, res, sh, q, on_update, say, view, wait_for_use, process)
    finally:
        if process is not None:
            process.close()
            res.estimate_process_rss_mb = process.peak_rss_mb
    # dropped from the estimate: by the full queue, or let go by the tracker as too little moved
    res.frames_received, res.frames_dropped, res.frames_placed = (
        sh.received,
        sh.dropped + tracker.skipped,
        tracker.placed,
    )
    res.stream_s = sh.last_t_s
    res.stream_wall_s = 0.0 if sh.t0_wall is None else sh.last_wall - sh.t0_wall
    pred = final_estimate(est, out)
    picked = min(res.frames_received, 60)  # predict's own pick of a sweep's frames
    final = Update(pred, sh.last_t_s, _wall(sh), picked, sh.received, tracker.placed, res.frames_dropped, final=True)
    res.final = final
    on_update(final)
    if view is not None:
        view.show_update(final, tracker)
    return res


def _run(source, writer, est, cfg, tracker, res, sh, q, on_update, say, view, wait_for_use, process) -> None:
    """The three threads over the written recording (see the module doc)."""
    with writer:
        reader = threading.Thread(target=_read, args=(source, writer, q, sh, wait_for_use), daemon=True)
        loop_args = (est, tracker, cfg, sh, res, on_update, say, view, process)
        estimator = threading.Thread(target=_estimate_loop, args=loop_args, daemon=True)
        try:
            reader.start()
            estimator.start()
            _track(tracker, q, sh, view)
            sh.tracked.set()
            while estimator.is_alive():  # the last update, from every frame placed
                estimator.join(0.1)
        except KeyboardInterrupt:
            res.interrupted = True
        finally:
            sh.tracked.set()
            sh.stop.set()
            while reader.is_alive():  # a reader waiting on a full queue lets go once it is drained
                _drain(q)
                reader.join(0.1)
            estimator.join()
            source.close()
        if sh.error is not None:
            raise sh.error
        if res.interrupted:
            say(f"stopped by Ctrl-C after {writer.frames_written} frames; recording finalised")


def _drain(q: queue.Queue) -> None:
    try:
        while True:
            q.get_nowait()
    except queue.Empty:
        pass


def _wall(sh: _Shared) -> float:
    return 0.0 if sh.t0_wall is None else time.monotonic() - sh.t0_wall


def _track(tracker: Tracker, q: queue.Queue, sh: _Shared, view) -> None:
    """The tracker: place queued frames until the reader is done and the queue empty."""
    while not (sh.done.is_set() and q.empty()):
        try:
            f: StreamFrame | StoredFrame = q.get(timeout=0.1)
        except queue.Empty:
            continue
        placed = tracker.add(f)
        if view is not None:
            view.show_frame(f, placed, tracker)
        if sh.error is not None:
            return


#: Fewest views an update reads when updates take too long.
MIN_VIEWS = 4


def _adapted(views: int, took_s: float, cfg: LiveConfig) -> int:
    """The views the next update reads, after one that took `took_s` (`LiveConfig.views`)."""
    if took_s < 0.4 * cfg.update_s:
        return min(cfg.views, views + 2)
    if took_s > 0.8 * cfg.update_s:  # the next may take longer: keep the answers within update_s
        return max(min(MIN_VIEWS, cfg.views), views - 2)
    return views


#: How long the estimator sleeps between looks at the tracker.
POLL_S = 0.05
#: An update may take this much longer than the one before it and still answer within `update_s`.
UPDATE_MARGIN = 1.5


def _next_start(finished: float, took_s: float, cfg: LiveConfig) -> float:
    """When the next update starts: early enough that its answer comes within `update_s` of this one's,
    if it takes up to `UPDATE_MARGIN` times as long (starting `update_s` after this one started gave
    answers 1.00-1.08 s apart, median, for a 1 s goal)."""
    return finished + max(0.0, cfg.update_s - UPDATE_MARGIN * took_s - POLL_S)


def _views_for(views: int, ended: bool, counted: bool, cfg: LiveConfig) -> int:
    """The views an update reads: `views` (adapted to the rate), all `cfg.views` once the stream has
    ended (no rate to keep), and `MIN_VIEWS` until an update has given a count: the first count waits
    for the frames to go 60 degrees round the chain and then for one update, and 4 views took 1.7 s
    where 6 took 2.6 s on the loaded 2-core machine (an answer from 4 views is rougher, and the next
    updates read more)."""
    if ended:
        return cfg.views
    return views if counted else min(views, MIN_VIEWS)


def _arc_short_of(kept, n_views: int, axis: np.ndarray | None) -> float | None:
    """How far round the chain (degrees, about `axis`, the last update's, where it saw the chain but
    too little of it) the frames an update would read go, where that is too little for it to measure
    anything but the same again; None otherwise."""
    if axis is None:
        return None
    arc_deg = arc_round_deg(spread(kept, n_views), axis)
    return round(float(arc_deg), 1) if arc_deg < MIN_ARC_DEG else None


def _still_too_little(pred: Prediction, arc_deg: float) -> Prediction:
    """`pred` (an update that saw too little of the chain) said again for views that go `arc_deg` round
    it: no estimator ran, the tracker's poses alone tell."""
    return dataclasses.replace(pred, answer=Estimate.none(too_little_arc(arc_deg)), source=None, network=None,
                               measurement=None, timings_s={})  # fmt: skip


def _estimate_loop(est: Estimator, tracker: Tracker, cfg: LiveConfig, sh: _Shared, res: LiveResult, on_update, say,
                   view, process: MeasureProcess | None = None) -> None:  # fmt: skip
    """The estimator thread: an update at least every `update_s` while new frames are placed, and a
    last one from `views` placed frames once the tracker has ended. Until the frames go far enough
    round the chain to tell its layers apart (`MIN_ARC_DEG`, `_arc_short_of`), the updates say so
    from the tracker's poses alone: measuring would only say it again, and on a busy machine a
    measurement under way held the first estimate with a count back by a whole update's time."""
    used_placed, next_at, views, last_full = 0, None, min(cfg.start_views, cfg.views), False
    axis = None  # the chain's axis, while the views went too little round it to measure
    counted = False  # an update has given a count
    said_at = 0.0  # monotonic seconds of the last update

    def report(u: Update) -> None:
        nonlocal said_at
        said_at = time.monotonic()
        res.updates.append(u)
        if res.enough_at is None and is_strong(u.prediction) and held_for_s(res.updates) >= cfg.stable_s:
            u = dataclasses.replace(u, enough=True)
            res.updates[-1] = u
            res.enough_at = u
            say(enough_words(u))
            if cfg.until_stable:
                sh.stop.set()
        on_update(u)
        if view is not None:
            view.show_update(u, tracker)

    try:
        while not sh.stop.is_set():
            ended = sh.tracked.is_set()  # read before the snapshot: then every frame placed is in it
            with sh.lock:
                kept, placed, received = list(tracker.kept), tracker.placed, sh.received
                dropped = sh.dropped + tracker.skipped
            if ended and (last_full or len(kept) < 2):
                return
            now = time.monotonic()
            waiting = next_at is not None and now < next_at
            if not ended and (waiting or len(kept) < min(cfg.first_views, cfg.views) or placed == used_placed):
                sh.stop.wait(POLL_S)
                continue
            n_views = _views_for(views, ended, counted, cfg)
            short_arc_deg = None if ended else _arc_short_of(kept, n_views, axis)
            if short_arc_deg is not None:
                if now - said_at >= cfg.update_s - POLL_S:
                    pred = _still_too_little(res.updates[-1].prediction, short_arc_deg)
                    report(Update(pred, kept[-1].t_s, _wall(sh), min(len(kept), n_views), received, placed, dropped))
                sh.stop.wait(POLL_S)
                continue
            pred, arc_deg = estimate_and_arc(est, kept, n_views, process)
            axis = pred.T_world_profile if arc_deg is not None and arc_deg < MIN_ARC_DEG else None
            counted = counted or pred.n_links is not None
            finished = time.monotonic()
            next_at = None if axis is not None else _next_start(finished, finished - now, cfg)
            views = _adapted(n_views, finished - now, cfg)  # from the views it read: the first read fewer
            used_placed, last_full = placed, ended
            report(Update(pred, kept[-1].t_s, _wall(sh), min(len(kept), n_views), received, placed, dropped))
    except BaseException as err:  # handed to the calling thread
        sh.error = err
        sh.stop.set()
