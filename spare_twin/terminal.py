"""The terminal side of a command: signals that must unwind like Ctrl-C, and a stdout that holds exactly
one JSON object under `--json` whatever the libraries (C and C++ included) print while the work runs."""

from __future__ import annotations

import contextlib
import ctypes
import io
import json
import os
import signal
import sys
import threading
from collections.abc import Iterator


def _interrupt(signum, frame):
    raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")


@contextlib.contextmanager
def signals_as_interrupts(signals: tuple[int, ...] = (signal.SIGTERM, signal.SIGHUP)) -> Iterator[None]:
    """SIGTERM and SIGHUP raise KeyboardInterrupt in the main thread while the block runs, so the
    clean-ups of `finally` and `writing` run as on Ctrl-C. A signal set to be ignored (nohup) stays
    ignored; elsewhere than in the main thread this does nothing (Python delivers signals there only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {}
    for s in signals:
        if signal.getsignal(s) is not signal.SIG_IGN:
            previous[s] = signal.signal(s, _interrupt)
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, signal.SIG_DFL if handler is None else handler)


class JsonStdout:
    """The one JSON object of a `--json` command, printed on the real stdout when the block ends."""

    def __init__(self) -> None:
        self.text: str | None = None

    @property
    def emitted(self) -> bool:
        return self.text is not None

    def emit(self, obj) -> None:
        self.emit_text(json.dumps(obj))

    def emit_text(self, text: str) -> None:
        """An object already serialised (one line of JSON)."""
        if self.emitted:
            raise RuntimeError("a --json command prints exactly one JSON object")
        self.text = text


class _PrintedJson(io.TextIOBase):
    """Python's stdout inside `single_json_stdout(catch_printed=True)`: a command may `print` its JSON
    object as usual; the last whole line that is a JSON object is kept for the real stdout, and every
    other line (whatever a library prints) goes on to stderr as it comes."""

    def __init__(self, err) -> None:
        self.err, self.partial, self.kept = err, "", None

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        *lines, self.partial = (self.partial + text).split("\n")
        for line in lines:
            self._line(line)
        return len(text)

    def _line(self, line: str) -> None:
        if line.lstrip().startswith("{"):
            try:
                is_object = isinstance(json.loads(line), dict)
            except ValueError:
                is_object = False
            if is_object:
                if self.kept is not None:  # an earlier object was not the command's last word after all
                    self.err.write(self.kept + "\n")
                self.kept = line.strip()
                return
        self.err.write(line + "\n")

    def flush(self) -> None:
        self.err.flush()

    def close_lines(self) -> None:
        if self.partial:
            self._line(self.partial)
            self.partial = ""


def _flush_c_stdio() -> None:
    # C's stdout buffer (printf into a pipe) would otherwise reach the real stdout after the block
    with contextlib.suppress(AttributeError, OSError):
        ctypes.CDLL(None).fflush(None)


@contextlib.contextmanager
def single_json_stdout(enabled: bool = True, catch_printed: bool = False) -> Iterator[JsonStdout]:
    """While the block runs, everything written to stdout (Python's `print`, C's printf, C++ streams)
    goes to stderr; the object given to `emit` is then printed on the real stdout, alone on its line.

    With `catch_printed`, a JSON object that Python code prints on a line of its own counts as emitted
    (the last one, if `emit` was not called): commands print their `--json` object as they always have.
    With `enabled` False nothing is redirected (a command without --json), and `emit` still prints.
    Nothing reaches stdout if the block raises.
    """
    out = JsonStdout()
    saved = None
    printed = None
    if enabled:
        sys.stdout.flush()
        _flush_c_stdio()
        with contextlib.suppress(OSError):
            saved = os.dup(1)
            os.dup2(2, 1)
        printed = _PrintedJson(sys.stderr) if catch_printed else None
    try:
        with contextlib.redirect_stdout(printed or sys.stderr) if enabled else contextlib.nullcontext():
            yield out
            if printed is not None:
                printed.close_lines()
                if printed.kept is not None and not out.emitted:
                    out.emit_text(printed.kept)
                elif printed.kept is not None:
                    sys.stderr.write(printed.kept + "\n")
    finally:
        if saved is not None:
            sys.stderr.flush()
            _flush_c_stdio()
            os.dup2(saved, 1)
            os.close(saved)
    if out.emitted:
        print(out.text, flush=True)
