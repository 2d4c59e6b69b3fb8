"""The measuring process's own side (`measure.process` starts it): the requests it answers, a
recording's measurement (`measure_recording`) and placed frames' (`measure_arrays`), and its loop.

`python -m spare_twin.measure.serve REQUESTS_FD REPLIES_FD LINES_FD`; it never imports torch.
"""

from __future__ import annotations

import resource
import signal
import sys
import time
import traceback
from multiprocessing.connection import Connection
from pathlib import Path

import numpy as np

from spare_twin.config import PartDims
from spare_twin.errors import SpareTwinError
from spare_twin.measure.chain import ON_OBJECT_SWEEP, measure_views, measured_chain
from spare_twin.observe.on_object import register_on_object
from spare_twin.observe.points import PosedView
from spare_twin.observe.views import PosedViews
from spare_twin.recording import Recording


def measure_arrays(
    views: list[tuple], frames_in_recording: int, print_scale: float, parts: PartDims, min_arc_deg: float
):
    """(observation, measurement) of views given as plain arrays, (raw uint16 depth, depth scale, K,
    T_world_camera, RGB or None) each: brought into register on the object, then observed and measured
    as `predict` does (`measure.chain.measure_views`, with the printed `parts`; not measured where the
    views go less than `min_arc_deg` round the chain)."""
    if not (isinstance(print_scale, float) and np.isfinite(print_scale) and print_scale > 0):
        raise SpareTwinError(f"print_scale {print_scale!r}: must be a positive number (physical m per paper m)")
    posed = [PosedView(d.astype(np.float32) * np.float32(s), K, T, rgb) for d, s, K, T, rgb in views]
    t0 = time.perf_counter()
    on_object = register_on_object(posed)
    seconds = time.perf_counter() - t0  # the update's "registration": the frames were placed as they came
    seen = PosedViews(tuple(on_object), ON_OBJECT_SWEEP, seconds, frames_in_recording=frames_in_recording)
    return measure_views(seen, print_scale, min_arc_deg=min_arc_deg, parts=parts)


def measure_recording(rec_dir: str, print_scale: float, frame, camera, progress: bool, parts: PartDims, min_arc_deg):
    """`measure.chain.measured_chain` of the recording folder `rec_dir`: what `predict` measures of a
    recording, in its caller or in the process (`MeasureProcess.start_recording`)."""
    return measured_chain(Recording.open(rec_dir), print_scale, frame, camera, progress, parts, min_arc_deg)


_REQUESTS = {"arrays": measure_arrays, "recording": measure_recording}


def _peak_rss_mb() -> float:
    """This process's own peak resident memory (MB). Not getrusage's ru_maxrss: that survives the
    exec this process was started with, so it says at least the parent's size at the fork (1.6 GB
    under pytest); the kernel's high-water mark of this process's own memory map (VmHWM) starts anew
    at the exec."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _serve(requests: Connection, replies: Connection) -> None:
    """The process: answer each request, (kind, arguments), until the parent closes its end."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        replies.send(("ready",))
    except OSError:  # the parent went away while this process started
        return
    while True:
        try:
            request = requests.recv()
        except (EOFError, OSError):  # the parent closed the pipe or died
            return
        if request is None:  # the parent is done: say how much memory this process took at most
            replies.send(("bye", _peak_rss_mb()))
            return
        kind, args = request
        try:
            reply = ("ok", _REQUESTS[kind](*args))
        except SpareTwinError as err:
            reply = ("error", str(err))
        except Exception:  # anything else: the parent raises it with this traceback
            reply = ("crash", traceback.format_exc())
        try:
            replies.send(reply)
        except OSError:  # the parent went away while this was measured: nobody to tell
            return


def _main(argv: list[str]) -> None:
    """The process itself: REQUESTS_FD REPLIES_FD LINES_FD. Its file descriptor 2 is its parent's
    (held back where `terminal.library_chatter_held` holds the parent's, so that the libraries'
    chatter is dropped with a failing command's); its `sys.stderr`, the progress bars, is LINES_FD, the
    parent's own `sys.stderr` (-1: descriptor 2 too)."""
    lines_fd = int(argv[2])
    if lines_fd >= 0:
        sys.stderr = open(lines_fd, "w", encoding="utf-8", errors="backslashreplace", buffering=1)  # noqa: SIM115
    _serve(Connection(int(argv[0]), writable=False), Connection(int(argv[1]), readable=False))


if __name__ == "__main__":  # python -m spare_twin.measure.serve REQUESTS_FD REPLIES_FD LINES_FD
    _main(sys.argv[1:])
