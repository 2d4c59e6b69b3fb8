"""What `predict` does before it imports torch: its options checked (`check_options`), and a recording's
observation and layer measurement set going in a process of its own (`start_measuring`).

`spare-twin predict` does both first, then imports torch and loads the network while the process
measures: a new `predict` process spent 2-2.5 s of this machine importing torch before it read a
frame. `predict_recording` takes the process as `measuring` and collects the same observation and
measurement it would have made itself (`measuring_request` says which, for both)."""

from __future__ import annotations

import math

import numpy as np

from spare_twin.config import DEFAULT_PRINT_SCALE, MAX_MOVING_LINKS, MIN_MOVING_LINKS, PartDims
from spare_twin.errors import SpareTwinError
from spare_twin.measure.process import MeasureProcess
from spare_twin.observe.views import check_views_request
from spare_twin.predict.abstain import MIN_ARC_DEG
from spare_twin.predict.estimate import ANSWERS
from spare_twin.recording import Recording


def _is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def check_options(
    frame: int | None = None,
    print_scale: float | None = None,
    n_links: int | None = None,
    yaw_hypotheses: int | None = None,
    device: str = "cpu",
    answer: str = "combined",
    parts: PartDims | None = None,
) -> None:
    """`predict_recording`'s options are usable; else an error naming the parameter. Checked before the
    model and the recording are read, so a typo costs no registration. torch only for `device="cuda"`:
    `spare-twin predict` checks them before it imports it."""
    if frame is not None and (not _is_int(frame) or frame < 0):
        raise SpareTwinError(f"frame {frame!r}: must be a frame index, 0 or more")
    if print_scale is not None and (
        isinstance(print_scale, bool)
        or not isinstance(print_scale, (int, float))
        or not math.isfinite(print_scale)
        or print_scale <= 0
    ):
        raise SpareTwinError(f"print_scale {print_scale!r}: must be a positive number (physical m per paper m)")
    if n_links is not None and (not _is_int(n_links) or not MIN_MOVING_LINKS <= n_links <= MAX_MOVING_LINKS):
        raise SpareTwinError(f"n_links {n_links!r}: must be {MIN_MOVING_LINKS}..{MAX_MOVING_LINKS} moving links")
    if yaw_hypotheses is not None and (yaw_hypotheses not in (1, 2, 4) or isinstance(yaw_hypotheses, bool)):
        raise SpareTwinError(f"yaw_hypotheses {yaw_hypotheses!r}: must be 1, 2 or 4")
    if device not in ("cpu", "cuda"):
        raise SpareTwinError(f"device {device!r}: must be cpu or cuda")
    if device == "cuda" and not _cuda_available():
        raise SpareTwinError("device cuda: no CUDA device is available here; use cpu")
    if answer not in ANSWERS:
        raise SpareTwinError(f"answer {answer!r}: must be one of {', '.join(ANSWERS)}")
    if parts is not None and not isinstance(parts, PartDims):
        raise SpareTwinError(f"parts {type(parts).__name__}: must be the printed parts' dimensions (a PartDims)")


def _cuda_available() -> bool:
    import torch

    return torch.cuda.is_available()


def print_scale_or_default(print_scale: float | None) -> float:
    """The print scale `predict` measures with: `print_scale` (`--print-scale`) or the default."""
    return float(print_scale) if print_scale is not None else DEFAULT_PRINT_SCALE


def measuring_request(rec_dir, frame, camera, print_scale, parts, progress: bool) -> tuple:
    """The arguments of `measure.process.measure_recording` that `predict_recording` measures a
    recording's views with: the folder, the print scale (or its default), the frame, the camera,
    progress, the parts (or the defaults) and `predict.abstain.MIN_ARC_DEG`."""
    return str(rec_dir), print_scale_or_default(print_scale), frame, camera, progress, parts or PartDims(), MIN_ARC_DEG


def start_measuring(
    rec_dir, frame=None, camera=None, print_scale=None, parts=None, progress=True, process: MeasureProcess | None = None
) -> MeasureProcess:
    """The measurement `predict_recording` would make of `rec_dir` with these options, set going in a
    process of its own (`measure.process`), which this returns; give it to `predict_recording` as
    `measuring`, with the same options, and close it after (`close(kill=True)` where the caller stops
    early). `process`: one the caller started already and has not asked anything (`spare-twin predict`
    starts it first of all), and closes itself. A folder that is no recording, or options it cannot
    take, are refused here, before the process is started or asked: an error the process gave would
    only be collected after the command had imported torch (4-5 s)."""
    check_views_request(Recording.open(rec_dir), frame, camera)
    request = measuring_request(rec_dir, frame, camera, print_scale, parts, progress)
    if process is not None:
        process.start_recording(request)
        return process
    process = MeasureProcess("predict: the measuring process", wait=False)
    try:
        process.start_recording(request)
    except BaseException:
        process.close(kill=True)
        raise
    return process
