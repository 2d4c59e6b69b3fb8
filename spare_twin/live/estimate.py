"""`live`'s one door into `predict`: the chain estimated from the frames placed so far, and the final
answer on the recording `live` wrote.

An update reads `views` placed frames spread evenly over everything kept (the same rule `predict`
uses to pick a sweep's frames: evenly spaced through the stream), brings them into register on the
object (`observe.on_object`, as `predict` does for a sweep it registered) and goes through
`predict`'s core: the same observation and measurement (`measure.chain.measure_views`, in a process
of its own: `measure.process`), network and combination (`predict.run.answer_of`), so an update's
answer has `predict --json`'s keys and sources. The final answer is
`predict.run.predict_recording` on the written recording, so the last line `live` prints is what
`predict` says of that recording.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spare_twin.config import PartDims
from spare_twin.errors import SpareTwinError
from spare_twin.live.track import PlacedFrame
from spare_twin.measure.process import MeasureProcess
from spare_twin.measure.serve import measure_arrays
from spare_twin.nets import checkpoint as ckpt
from spare_twin.predict.abstain import MIN_ARC_DEG
from spare_twin.predict.early import check_options
from spare_twin.predict.estimate import MeasurementEvidence, NetworkEvidence, Prediction
from spare_twin.predict.run import answer_of, predict_recording

#: An answer is strong evidence when the measurement gave it and its chain fits its points this well
#: (RMS, metres; `measure.chain.CLEAN_PART_RMS_M`: a sweep in register fits to 0.2-0.5 mm) ...
STRONG_RMS_M = 0.002
#: ... or the network gave the count with at least this probability.
STRONG_PROBABILITY = 0.9


@dataclass(frozen=True)
class Estimator:
    """The loaded network and `predict`'s options, ready for `estimate_from_frames`."""

    model: object
    net: object
    model_name: str | None
    answer: str
    print_scale: float
    parts: PartDims = PartDims()
    """The parts the chain was printed with (`predict --parts`)."""


def load_estimator(
    model_path: str | Path | None, answer: str, print_scale: float, parts: PartDims | None = None
) -> Estimator:
    """The network `predict` would load (its default profile network unless `model_path`); only a
    profile network reads posed views in memory, so another one is refused."""
    check_options(print_scale=print_scale, answer=answer, parts=parts)
    parts = parts or PartDims()
    if answer == "measurement":
        if model_path is not None:
            raise SpareTwinError("--model: --answer measurement runs no network")
        return Estimator(None, None, None, answer, float(print_scale), parts)
    import torch

    # one thread: live's own three threads keep the cores busy, and torch's intra-op threads fighting them
    # made the profile network take 0.4 s instead of 3 ms on the loaded 2-core machine
    torch.set_num_threads(1)
    path = model_path or ckpt.default_model("predict")
    model, net, _ = ckpt.load_model(path, "cpu")
    if net.arch != "profile":
        raise SpareTwinError(f"--model {path}: live runs the yaw-free profile network; this is a {net.arch} network")
    return Estimator(model, net, str(path), answer, float(print_scale), parts)


def spread(kept: list[PlacedFrame], views: int) -> list[PlacedFrame]:
    """At most `views` of `kept`, evenly spaced from the first to the last."""
    picks = np.unique(np.linspace(0, len(kept) - 1, min(views, len(kept))).round().astype(int))
    return [kept[i] for i in picks]


def estimate_from_frames(
    est: Estimator, kept: list[PlacedFrame], views: int = 16, process: MeasureProcess | None = None
) -> Prediction:
    """`predict`'s answer from `views` of the placed frames (see the module doc); the observation and
    measurement in `process` (`measure.process`) when one is given, else here."""
    return estimate_and_arc(est, kept, views, process)[0]


def view_arrays(frames: list[PlacedFrame]) -> list[tuple]:
    """The placed frames as plain arrays (`measure.process.measure_arrays`): raw uint16 depth travels
    at half the size of metres in float32."""
    return [(p.frame.depth_u16, float(p.frame.depth_scale), p.frame.K, p.T_world_camera, p.frame.color) for p in frames]


def estimate_and_arc(
    est: Estimator, kept: list[PlacedFrame], views: int = 16, process: MeasureProcess | None = None
) -> tuple[Prediction, float | None]:
    """`estimate_from_frames`, and how far round the chain the views went (degrees; None where no
    chain was seen)."""
    chosen = spread(kept, views)
    if process is not None:
        obs, m = process.measure(view_arrays(chosen), len(kept), est.print_scale, est.parts, MIN_ARC_DEG)
    else:
        obs, m = measure_arrays(view_arrays(chosen), len(kept), est.print_scale, est.parts, MIN_ARC_DEG)
    pred = answer_of(obs, m, est.model, est.net, est.model_name, est.answer, est.print_scale, parts=est.parts)
    return pred, (None if obs.reason is not None else obs.arc_deg)


def final_estimate(est: Estimator, rec_dir: str | Path) -> Prediction:
    """`predict` on the recording `live` wrote, with the same network and options."""
    return predict_recording(
        rec_dir, est.model_name, print_scale=est.print_scale, progress=False, answer=est.answer, parts=est.parts
    )


def is_strong(pred: Prediction) -> bool:
    """Whether the evidence for `pred`'s answer is strong (`STRONG_RMS_M`, `STRONG_PROBABILITY`)."""
    if pred.n_links is None:
        return False
    m = pred.measurement
    if m is not None and m.n_links == pred.n_links and isinstance(m.evidence, MeasurementEvidence):
        if m.evidence.rms_m is not None and m.evidence.rms_m <= STRONG_RMS_M:
            return True
    n = pred.network
    if n is not None and isinstance(n.evidence, NetworkEvidence) and n.evidence.probabilities is not None:
        return n.n_links == pred.n_links and max(n.evidence.probabilities) >= STRONG_PROBABILITY
    return False
