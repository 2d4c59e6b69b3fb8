"""`spare-twin bench live`: `live` replaying a 640 x 480, 30 fps hand-held sweep in real time, measured.

Figures (wall seconds are counted from the first frame's arrival; the simulated object is in view
from the first frame on):

- time to first estimate: until the first update with a count;
- update interval: between consecutive updates (median and largest, and the largest while frames
  still arrive: once the stream has ended, the last update reads every view and takes longer);
- frames received, placed (used by the estimate) and dropped from it;
- when the first estimate with a count came, in stream seconds too: the frames it read had to go
  60 degrees round the chain (`predict.abstain.MIN_ARC_DEG`), which the rendered sweep does after
  about 1.7 s; the rest is the wait for the update and the update itself;
- when the last frame came (wall seconds; more than the stream's length: the reader fell behind);
- peak RSS of the process (`resource.getrusage`: everything loaded, torch included) and of the
  estimate's own process (`measure.process`, as it says when it ends);
- the load average at the start and the end (the machine may be shared: timings are only comparable
  under like load);
- agreement: the last update against the final answer (`predict` on the recording `live` wrote) and
  both against the truth in the simulated recording.

The sweep is rendered here (a 2-link object, seed 7, noise of an SR300) unless `--rec` names one.
"""

from __future__ import annotations

import os
import resource
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spare_twin.config import sample_chain
from spare_twin.live.run import live
from spare_twin.live.session import Update
from spare_twin.object.folder import build_sim_twin
from spare_twin.recording import Recording
from spare_twin.sim.render import RenderConfig, render_recording


@dataclass(frozen=True)
class LiveBench:
    frames: int = 300
    """Frames of the rendered sweep (300: 10 s at 30 fps)."""
    resolution: str = "640x480"
    fps: float = 30.0
    speed: float = 1.0
    rec: str | None = None
    """A recording to replay instead of the rendered sweep."""
    rrd: str | None = None


@dataclass
class LiveBenchResult:
    figures: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return self.figures


def _sweep(cfg: LiveBench, root: Path, log) -> Path:
    obj = build_sim_twin(sample_chain(2, seed=7), root / "object")
    out = root / "sweep"
    log(f"rendering a {cfg.resolution} hand-held sweep, {cfg.frames} frames at {cfg.fps:g} fps ...")
    rcfg = RenderConfig(frames=cfg.frames, fps=cfg.fps, resolution=cfg.resolution, path="handheld",
                        noise="realsense_sr300", hide_poses=True, seed=2, segmentation=False)  # fmt: skip
    render_recording(obj.root, out, rcfg, progress=False)
    return out


def _truth(rec: Recording) -> tuple[int, list[float]] | None:
    obj = rec.object_config
    if not obj or "n_links" not in obj:
        return None
    return int(obj["n_links"]), [float(v) for v in obj["link_lengths_pu"]]


def _diff(a, b) -> float | None:
    if a is None or b is None or len(a) != len(b):
        return None
    return round(float(np.max(np.abs(np.subtract(a, b)))), 4)


def bench_live(cfg: LiveBench = LiveBench(), log=print) -> LiveBenchResult:
    with tempfile.TemporaryDirectory(prefix="spare-twin-bench-live-") as tmp:
        root = Path(tmp)
        rec_dir = Path(cfg.rec) if cfg.rec else _sweep(cfg, root, log)
        src = Recording.open(rec_dir)
        updates: list[Update] = []
        log(f"live --replay at {cfg.speed:g} x: {src.n_frames} frames of {src.cameras[0].width}x"
            f"{src.cameras[0].height} at {src.fps:g} fps ...")  # fmt: skip
        load_start = os.getloadavg()[0]
        t0 = time.perf_counter()
        res = live(root / "live", replay=rec_dir, speed=cfg.speed, rrd=cfg.rrd, viewer=False,
                   on_update=updates.append, force=cfg.rrd is not None)  # fmt: skip
        wall_s = time.perf_counter() - t0
        peak_rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        load_end = os.getloadavg()[0]
        truth = _truth(src)
    steps = [u for u in updates if not u.final]
    counted = [u for u in steps if u.prediction.n_links is not None]
    gaps = np.diff([u.wall_s for u in steps]) if len(steps) > 1 else np.array([])
    # the intervals ending while frames still arrive: after the stream the last update reads every view
    streaming = gaps[np.array([u.wall_s <= res.stream_wall_s for u in steps[1:]], dtype=bool)] if len(gaps) else gaps
    final, last = res.final.prediction, steps[-1].prediction if steps else None
    fig = {
        "recording": str(rec_dir) if cfg.rec else f"rendered: {cfg.frames} frames {cfg.resolution} at {cfg.fps:g} fps",
        "stream_s": round(res.stream_s, 3),
        "speed": cfg.speed,
        "frames_received": res.frames_received,
        "frames_placed": res.frames_placed,
        "frames_dropped": res.frames_dropped,
        "updates": len(steps),
        "first_update_s": round(steps[0].wall_s, 3) if steps else None,
        "first_estimate_s": round(counted[0].wall_s, 3) if counted else None,
        "first_estimate_stream_s": round(counted[0].t_s, 3) if counted else None,
        "last_frame_wall_s": round(res.stream_wall_s, 3),
        "update_interval_median_s": round(float(np.median(gaps)), 3) if len(gaps) else None,
        "update_interval_max_s": round(float(gaps.max()), 3) if len(gaps) else None,
        "update_interval_max_streaming_s": round(float(streaming.max()), 3) if len(streaming) else None,
        "enough_at_stream_s": None if res.enough_at is None else round(res.enough_at.t_s, 3),
        "final_after_stream_end_s": round(res.final.wall_s - (steps[-1].wall_s if steps else 0.0), 3),
        "wall_s": round(wall_s, 3),
        "peak_rss_mb": round(peak_rss_mb, 1),
        "peak_rss_estimate_process_mb": None
        if res.estimate_process_rss_mb is None
        else round(res.estimate_process_rss_mb, 1),
        "load_average": [round(load_start, 1), round(load_end, 1)],
        "last_update": None if last is None else {"n_links": last.n_links, "link_lengths_pu": last.link_lengths_pu},
        "final": {"n_links": final.n_links, "link_lengths_pu": final.link_lengths_pu},
        "last_update_vs_final_pu": None if last is None else _diff(last.link_lengths_pu, final.link_lengths_pu),
        "same_count": last is not None and last.n_links == final.n_links,
        "truth": None if truth is None else {"n_links": truth[0], "link_lengths_pu": truth[1]},
        "final_vs_truth_pu": None if truth is None else _diff(final.link_lengths_pu, truth[1]),
        "last_update_vs_truth_pu": None if truth is None or last is None else _diff(last.link_lengths_pu, truth[1]),
    }
    return LiveBenchResult(fig)
