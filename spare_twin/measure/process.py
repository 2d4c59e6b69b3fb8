"""The measurement in a process of its own, beside work its caller does meanwhile; the process never
imports torch.

Two callers run it:
- `live`: placing frames and estimating the chain run side by side instead of taking turns. In one
  process they take turns: placing 20 frames (1.1 s of CPU) and two 8-view estimates (1.4 s of CPU)
  took 4.3 s and 5.3 s alone on the loaded 2-core machine and 9.9 s together on two threads, the sum
  (the interpreter lock: most of both is Python and small NumPy calls). In a process of its own the
  estimate runs beside the tracker on the other core. The request is the placed frames as arrays
  (`measure.serve.measure_arrays`: brought into register on the object, then observed and measured).
- `spare-twin predict`: the recording's views, observation and layer measurement
  (`measure.chain.measured_chain`) run while the command imports torch and loads the network, about
  2-3 s of every new `predict` process on this machine that would otherwise come first. The command
  starts the process first of all and asks it once it has checked its options and the folder.

Both callers run the profile network (3 ms) themselves on what comes back (`predict.run.answer_of`).
The process starts in 1-3 s and holds about 150 MB.

It is a fresh interpreter (`python -m spare_twin.measure.serve`, talking over two pipes of its
own): not a fork (`live` has threads and torch loaded), and not `multiprocessing`'s spawn, which
imports the caller's main script again in the child (a script calling `live` without a main guard ran
twice). It runs in a session of its own and ignores SIGINT: Ctrl-C is the parent's, which ends this
process. It ends when the parent closes its pipe, or dies.

This module is the caller's side and imports nothing heavy, so that a command can start the process
before it imports the measurement (or torch) itself: the process's own side, the requests it
answers, is `measure.serve`.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING

from spare_twin.errors import SpareTwinError

if TYPE_CHECKING:
    from spare_twin.config import PartDims

#: Seconds to wait for the process to start (import NumPy, SciPy and the measurement) on a busy machine.
START_TIMEOUT_S = 120.0


def _lines_fd() -> int | None:
    """The file descriptor of the caller's own `sys.stderr`, where the process writes its lines and
    progress bars as the caller would; None where it is no file (a test's captured stream)."""
    try:
        return sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):
        return None


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
                [sys.executable, "-m", "spare_twin.measure.serve", *map(str, fds)],
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
