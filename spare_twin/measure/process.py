"""The measurement in a process of its own, beside work its caller does meanwhile; the process never
imports torch.

Two callers run it:
- `live`: placing frames and estimating the chain run side by side instead of taking turns. In one
  process they take turns: placing 20 frames (1.1 s of CPU) and two 8-view estimates (1.4 s of CPU)
  took 4.3 s and 5.3 s alone on the loaded 2-core machine and 9.9 s together on two threads, the sum
  (the interpreter lock: most of both is Python and small NumPy calls). In a process of its own the
  estimate runs beside the tracker on the other core. The request is the placed frames as arrays
  (`measure_arrays`: brought into register on the object, then observed and measured).
- `spare-twin predict`: the recording's views, observation and layer measurement
  (`measure.chain.measured_chain`) run while the command imports torch and loads the network, about
  2-2.5 s of every new `predict` process on this machine that would otherwise come first.

Both callers run the profile network (3 ms) themselves on what comes back (`predict.run.answer_of`).
The process starts in 1-3 s and holds about 150 MB.

It is a fresh interpreter (`python -m spare_twin.measure.process`, talking over two pipes of its
own): not a fork (`live` has threads and torch loaded), and not `multiprocessing`'s spawn, which
imports the caller's main script again in the child (a script calling `live` without a main guard ran
twice). It runs in a session of its own and ignores SIGINT: Ctrl-C is the parent's, which ends this
process. It ends when the parent closes its pipe, or dies.
"""

from __future__ import annotations

import contextlib
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
from spare_twin.measure.chain import ON_OBJECT_SWEEP, measure_views, measured_chain
from spare_twin.observe.on_object import register_on_object
from spare_twin.observe.points import PosedView
from spare_twin.observe.views import PosedViews
from spare_twin.recording import Recording

#: Seconds to wait for the process to start (import NumPy, SciPy and the measurement) on a busy machine.
START_TIMEOUT_S = 120.0


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


def _lines_fd() -> int | None:
    """The file descriptor of the caller's own `sys.stderr`, where the process writes its lines and
    progress bars as the caller would; None where it is no file (a test's captured stream)."""
    try:
        return sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):
        return None


def _main(argv: list[str]) -> None:
    """The process itself: REQUESTS_FD REPLIES_FD LINES_FD. Its file descriptor 2 is its parent's
    (held back where `terminal.library_chatter_held` holds the parent's, so that the libraries'
    chatter is dropped with a failing command's); its `sys.stderr`, the progress bars, is LINES_FD, the
    parent's own `sys.stderr` (-1: descriptor 2 too)."""
    lines_fd = int(argv[2])
    if lines_fd >= 0:
        sys.stderr = open(lines_fd, "w", encoding="utf-8", errors="backslashreplace", buffering=1)  # noqa: SIM115
    _serve(Connection(int(argv[0]), writable=False), Connection(int(argv[1]), readable=False))


class MeasureProcess:
    """The process (see the module doc). `who` names it in its errors. Requests go in order and their
    answers come back in the same order; `wait`: return only once the process has started."""

    def __init__(self, who: str = "live: the estimate's process", wait: bool = True):
        self.who = who
        req_r, req_w = os.pipe()
        rep_r, rep_w = os.pipe()
        lines = _lines_fd()
        fds = (req_r, rep_w, -1 if lines is None else lines)
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "spare_twin.measure.process", *map(str, fds)],
                pass_fds=(req_r, rep_w) + ((lines,) if lines is not None else ()),
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
        self._started = False
        self._recording: tuple | None = None
        self.peak_rss_mb: float | None = None
        if wait:
            try:
                self._start()
            except BaseException:  # Ctrl-C while it starts: it is not left behind
                self.close(kill=True)
                raise

    def _start(self) -> None:
        if self._started:
            return
        if not self._replies.poll(START_TIMEOUT_S):
            self.close(kill=True)
            raise SpareTwinError(f"{self.who} did not start within {START_TIMEOUT_S:g} s")
        self._started = True
        self._reply()

    def _reply(self):
        try:
            reply = self._replies.recv()
        except (EOFError, OSError):
            code = self._proc.wait(10.0)
            raise SpareTwinError(f"{self.who} ended (exit code {code})") from None
        if reply[0] == "error":
            raise SpareTwinError(reply[1])
        if reply[0] == "crash":
            raise RuntimeError(f"{self.who} failed:\n{reply[1]}")
        return reply[1] if len(reply) > 1 else None

    def _ask(self, kind: str, *args):
        if self._recording is not None:
            raise ValueError(f"{self.who}: a recording's measurement is still to be collected (`recording`)")
        self._start()
        self._requests.send((kind, args))
        return self._reply()

    def measure(self, views: list[tuple], frames_in_recording: int, print_scale: float, parts: PartDims, min_arc_deg):
        """`measure_arrays` run in the process."""
        return self._ask("arrays", views, frames_in_recording, print_scale, parts, min_arc_deg)

    def start_recording(self, request: tuple) -> None:
        """Set `measure_recording(*request)` going in the process, without waiting for it:
        `recording(request)` gives the answer."""
        self._recording = tuple(request)
        self._requests.send(("recording", self._recording))

    def recording(self, request: tuple):
        """The answer to `start_recording`, whose request this must be (else ValueError: a caller
        asking of one recording what was set going for another)."""
        if tuple(request) != self._recording:
            raise ValueError(f"{self.who}: measuring {self._recording}, not {tuple(request)}")
        self._recording = None
        self._start()
        return self._reply()

    def close(self, kill: bool = False) -> None:
        """End the process: it finishes the request it is on, if any, or is ended after 10 s; `kill`:
        at once (the caller was interrupted or failed). `peak_rss_mb` is then its peak memory (as it
        said; None where it could not)."""
        if kill:
            self._proc.kill()
            if self._recording is not None and self._recording[4]:  # its progress bar, cut mid-line:
                with contextlib.suppress(OSError, ValueError):  # the caller's next line starts afresh
                    print(file=sys.stderr, flush=True)
        else:
            try:
                self._requests.send(None)
                while self._replies.poll(10.0):
                    reply = self._replies.recv()
                    if reply[0] == "bye":
                        self.peak_rss_mb = float(reply[1])
                        break
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


if __name__ == "__main__":  # python -m spare_twin.measure.process REQUESTS_FD REPLIES_FD LINES_FD
    _main(sys.argv[1:])
