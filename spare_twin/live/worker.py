"""`live`'s measurement in a process of its own, so that placing frames and estimating the chain run
side by side instead of taking turns.

In one process they take turns: placing 20 frames (1.1 s of CPU) and two 8-view estimates (1.4 s of
CPU) took 4.3 s and 5.3 s alone on the loaded 2-core machine and 9.9 s together on two threads, the
sum (the interpreter lock: most of both is Python and small NumPy calls). In a process of its own the
estimate runs beside the tracker on the other core (on a busy machine: it gets its own share of
the cores too).

The process runs the slow part of an update: the views brought into register on the object
(`observe.on_object`) and `predict`'s observation and layer measurement (`measure.chain.measure_views`).
The profile network (3 ms) runs in the parent on what comes back (`predict.run.answer_of`), so the
process never imports torch: it starts in 2-3 s and holds about 150 MB.

It is a fresh interpreter (`python -m spare_twin.live.worker`, talking over two pipes of its own): not
a fork (the parent has threads and torch loaded), and not `multiprocessing`'s spawn, which imports
the caller's main script again in the child (a script calling `live` without a main guard ran twice).
It runs in a session of its own and ignores SIGINT: Ctrl-C is the parent's, which finalises the
recording and then ends this process. It ends when the parent closes its pipe, or dies.
"""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
import time
import traceback
from multiprocessing.connection import Connection
from pathlib import Path

import numpy as np

from spare_twin.config import PartDims
from spare_twin.errors import SpareTwinError
from spare_twin.measure.chain import ON_OBJECT_SWEEP, measure_views
from spare_twin.observe.on_object import register_on_object
from spare_twin.observe.points import PosedView
from spare_twin.observe.views import PosedViews
from spare_twin.predict.abstain import MIN_ARC_DEG

#: Seconds to wait for the process to start (import NumPy, SciPy and the measurement) on a busy machine.
START_TIMEOUT_S = 120.0


def view_arrays(frames) -> list[tuple]:
    """The placed frames (`live.track.PlacedFrame`) as plain arrays: raw uint16 depth travels at half
    the size of metres in float32."""
    return [(p.frame.depth_u16, float(p.frame.depth_scale), p.frame.K, p.T_world_camera, p.frame.color) for p in frames]


def measure_arrays(views: list[tuple], frames_in_recording: int, print_scale: float, parts: PartDims = PartDims()):
    """(observation, measurement) of views given as `view_arrays`: brought into register on the object,
    then observed and measured as `predict` does (`measure.chain.measure_views`, with the printed `parts`)."""
    if not (isinstance(print_scale, float) and np.isfinite(print_scale) and print_scale > 0):
        raise SpareTwinError(f"print_scale {print_scale!r}: must be a positive number (physical m per paper m)")
    posed = [PosedView(d.astype(np.float32) * np.float32(s), K, T, rgb) for d, s, K, T, rgb in views]
    t0 = time.perf_counter()
    on_object = register_on_object(posed)
    seconds = time.perf_counter() - t0  # the update's "registration": the frames were placed as they came
    seen = PosedViews(tuple(on_object), ON_OBJECT_SWEEP, seconds, frames_in_recording=frames_in_recording)
    return measure_views(seen, print_scale, min_arc_deg=MIN_ARC_DEG, parts=parts)


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
    """The process: answer each request until the parent closes its end."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    replies.send(("ready",))
    while True:
        try:
            request = requests.recv()
        except (EOFError, OSError):  # the parent closed the pipe or died
            return
        if request is None:  # the parent is done: say how much memory this process took at most
            replies.send(("bye", _peak_rss_mb()))
            return
        try:
            replies.send(("ok", measure_arrays(*request)))
        except SpareTwinError as err:
            replies.send(("error", str(err)))
        except Exception:  # anything else: the parent raises it with this traceback
            replies.send(("crash", traceback.format_exc()))


class MeasureProcess:
    """The process (see the module doc): `measure(frames, ...)` is `measure_arrays` run in it."""

    def __init__(self):
        req_r, req_w = os.pipe()
        rep_r, rep_w = os.pipe()
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "spare_twin.live.worker", str(req_r), str(rep_w)],
                pass_fds=(req_r, rep_w),
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                start_new_session=True,  # Ctrl-C in a terminal is the parent's to handle
            )
        except BaseException:
            for fd in (req_r, req_w, rep_r, rep_w):
                os.close(fd)
            raise
        os.close(req_r)
        os.close(rep_w)
        self._requests, self._replies = Connection(req_w, readable=False), Connection(rep_r, writable=False)
        self.peak_rss_mb: float | None = None
        if not self._replies.poll(START_TIMEOUT_S):
            self.close()
            raise SpareTwinError(f"live: the estimate's process did not start within {START_TIMEOUT_S:g} s")
        self._reply()

    def _reply(self):
        try:
            reply = self._replies.recv()
        except (EOFError, OSError):
            code = self._proc.wait(10.0)
            raise SpareTwinError(f"live: the estimate's process ended (exit code {code})") from None
        if reply[0] == "error":
            raise SpareTwinError(reply[1])
        if reply[0] == "crash":
            raise RuntimeError(f"live: the estimate's process failed:\n{reply[1]}")
        return reply[1] if len(reply) > 1 else None

    def measure(self, frames, frames_in_recording: int, print_scale: float, parts: PartDims = PartDims()):
        self._requests.send((view_arrays(frames), frames_in_recording, print_scale, parts))
        return self._reply()

    def close(self) -> None:
        """End the process: it finishes the request it is on, if any, or is ended after 10 s;
        `peak_rss_mb` is then its peak memory (as it said; None where it could not)."""
        try:
            self._requests.send(None)
            if self._replies.poll(10.0):
                reply = self._replies.recv()
                self.peak_rss_mb = float(reply[1]) if reply[0] == "bye" else None
        except (OSError, ValueError, EOFError):
            pass
        self._requests.close()
        try:
            self._proc.wait(10.0)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        self._replies.close()

    @property
    def pid(self) -> int:
        return self._proc.pid


if __name__ == "__main__":  # the process itself: python -m spare_twin.live.worker REQUESTS_FD REPLIES_FD
    _serve(Connection(int(sys.argv[1]), writable=False), Connection(int(sys.argv[2]), readable=False))
