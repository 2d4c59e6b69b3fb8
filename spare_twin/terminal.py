"""The terminal side of a command: signals that must unwind like Ctrl-C, a stdout that holds exactly
one JSON object under `--json` whatever the libraries (C and C++ included) print while the work runs,
text streams that never fail on encoding, and the libraries' own chatter on stderr held back so that a
failing command says one line."""

from __future__ import annotations

import builtins
import contextlib
import ctypes
import io
import json
import math
import os
import select
import signal
import stat
import sys
import threading
import warnings
from collections.abc import Iterator


class _ImportsFinishFirst:
    """`builtins.__import__` wrapped so that an interrupt arriving in the main thread while an `import`
    statement runs is raised once the outermost one has finished. Raised inside an extension's
    initialisation (torch's C++ runs Python code through pybind11 and PyRun_String), a KeyboardInterrupt
    makes CPython exit killed by SIGINT after the command has already returned 130, or abort (SIGABRT):
    both were seen when `predict` was stopped while it imported torch. An import takes at most a few
    seconds, so a stop waits at most that long."""

    def __init__(self, original) -> None:
        self.original = original
        self.depth = 0
        self.pending: int | None = None

    def __call__(self, *args, **kwargs):
        if threading.current_thread() is not threading.main_thread():
            return self.original(*args, **kwargs)
        self.depth += 1
        try:
            return self.original(*args, **kwargs)
        finally:
            self.depth -= 1
            if self.depth == 0 and self.pending is not None:
                signum, self.pending = self.pending, None
                raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")

    def interrupt(self, signum, frame) -> None:
        if self.depth:
            self.pending = signum
            return
        raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")


@contextlib.contextmanager
def signals_as_interrupts(
    signals: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP),
) -> Iterator[None]:
    """SIGINT, SIGTERM and SIGHUP raise KeyboardInterrupt in the main thread while the block runs, so
    the clean-ups of `finally` and `writing` run as on Ctrl-C, but never inside an `import` statement:
    there it waits for the import to finish (`_ImportsFinishFirst`). A signal set to be ignored (nohup)
    stays ignored; elsewhere than in the main thread this does nothing (Python delivers signals there
    only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    imports = _ImportsFinishFirst(builtins.__import__)
    previous = {}
    for s in signals:
        if signal.getsignal(s) is not signal.SIG_IGN:
            previous[s] = signal.signal(s, imports.interrupt)
    builtins.__import__ = imports
    try:
        yield
    finally:
        if builtins.__import__ is imports:
            builtins.__import__ = imports.original
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
        """An object already serialised (one line of JSON); NaN and infinities become null (`strict_json`)."""
        if self.emitted:
            raise RuntimeError("a --json command prints exactly one JSON object")
        self.text = strict_json(text)


def _finite_or_none(value):
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite_or_none(v) for v in value]
    return value


def strict_json(text: str) -> str:
    """`text` (one JSON value, as Python's `json.dumps` writes it) as strict JSON: `json.dumps` writes
    NaN and infinities as the bare words `NaN` and `Infinity`, which JSON readers outside Python refuse.
    Those become null (no number is known there); text without them is returned as it came."""
    non_finite = []

    def constant(word: str) -> float:  # NaN, Infinity, -Infinity
        non_finite.append(word)
        return float("nan")

    def number(digits: str) -> float:  # 1e999 reads as inf
        value = float(digits)
        if not math.isfinite(value):
            non_finite.append(digits)
        return value

    obj = json.loads(text, parse_constant=constant, parse_float=number)
    if not non_finite:
        return text.strip()
    return json.dumps(_finite_or_none(obj), allow_nan=False)


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
                self.kept = strict_json(line)
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


# -- the environment a command starts in -------------------------------------------------------------


def never_fail_on_encoding() -> None:
    """Printing never raises UnicodeEncodeError: a character the terminal's encoding lacks (an `--out`
    named `objét` under PYTHONIOENCODING=ascii) is written as a backslash escape, after the work is done
    as well as before it."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(AttributeError, ValueError, io.UnsupportedOperation):
            stream.reconfigure(errors="backslashreplace")


def fill_closed_stdin_stderr() -> None:
    """A closed stdin or stderr (`2>&-`) gets /dev/null in its place: otherwise the first file the
    command opens would take that number, and what C libraries print on stderr would land in it. Python
    started without a stderr has `sys.stderr` None, which progress bars and warnings cannot write to."""
    for fd in (0, 2):
        try:
            os.fstat(fd)
        except OSError:
            with contextlib.suppress(OSError):
                null = os.open(os.devnull, os.O_RDWR)
                if null != fd:
                    os.dup2(null, fd)
                    os.close(null)
    if sys.stderr is None:
        with contextlib.suppress(OSError):
            sys.stderr = open(2, "w", errors="backslashreplace", buffering=1, closefd=False)


def _pipe_without_reader(fd: int) -> bool:
    """Whether `fd` is a pipe whose reading end is closed (`spare-twin ... | true` after `true` ended):
    Linux reports POLLERR on its writing end."""
    try:
        if not stat.S_ISFIFO(os.fstat(fd).st_mode):
            return False
        poller = select.poll()
        poller.register(fd, select.POLLOUT)
        return any(events & select.POLLERR for _, events in poller.poll(0))
    except (OSError, AttributeError, ValueError):  # no poll on this platform: find out when printing
        return False


def environment_problem() -> str | None:
    """What keeps any command from running here, said before numpy or torch are imported (they fail on
    these with a bare OS error or a fatal oneMKL message): a current folder that was deleted, a stdout
    that is closed (`>&-`) or a pipe nobody reads. A closed stdout must be refused before any file is
    opened: the first one opened would become file descriptor 1 and receive what C libraries print."""
    try:
        os.getcwd()
    except OSError as exc:
        return f"the current folder no longer exists ({exc.strerror}): it was deleted or moved; cd to one that exists"
    if sys.stdout is None:
        return "stdout is closed: nothing the command says could be printed; run it with stdout open (> /dev/null)"
    if sys.stdout is sys.__stdout__:
        try:
            fd = sys.stdout.fileno()
            os.fstat(fd)
        except (OSError, AttributeError, ValueError, io.UnsupportedOperation):
            return "stdout is closed: nothing the command says could be printed; run it with stdout open (> /dev/null)"
        if _pipe_without_reader(fd):
            return "stdout is a pipe that nobody reads (its reader has ended): nothing the command says would be seen"
    return None


def stdout_gone() -> bool:
    """Whether a broken pipe was stdout's (a pipe whose reader ended), not another pipe's. If so, file
    descriptor 1 now points at /dev/null, so that the interpreter's last flush at exit does not add an
    "Exception ignored ... BrokenPipeError" to the one-line error."""
    with contextlib.suppress(OSError, AttributeError, ValueError, io.UnsupportedOperation):
        if sys.stdout is sys.__stdout__ and _pipe_without_reader(sys.stdout.fileno()):
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            os.close(devnull)
            return True
    return False


# -- libraries' chatter on stderr ------------------------------------------------------------------------

#: While `library_chatter_held` runs: Python's own stderr (the process's file descriptor 2, now a file),
#: for the children forked meanwhile (their tracebacks and prints are chatter too).
_forked_stderr = None


def _child_stderr() -> None:
    if _forked_stderr is not None:
        sys.stderr = _forked_stderr


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_child_stderr)


class HeldChatter:
    """Whether what libraries wrote on stderr while a command ran is shown when it ends (`keep`)."""

    #: At most this much is shown: the last bytes (a long run's chatter is not worth a screenful more).
    LIMIT_BYTES = 1 << 20

    def __init__(self) -> None:
        self.keep = True


def _is_process_stderr(stream) -> bool:
    try:
        return stream is sys.__stderr__ and stream.fileno() == 2
    except (AttributeError, ValueError, io.UnsupportedOperation):
        return False


@contextlib.contextmanager
def library_chatter_held() -> Iterator[HeldChatter]:
    """Hold back everything written on stderr's file descriptor while the block runs: the lines that C
    libraries print beside a failure ("libpng error: IDAT: invalid ...", OpenCV's and Open3D's warnings),
    Python warnings, and the output of worker processes (52 tracebacks on Ctrl-C). Python's `sys.stderr`
    (the command's own lines, progress bars) still goes straight to the terminal. When the block ends the
    held text is written out if `keep` is still true (a command that succeeded) and dropped otherwise, so
    a failing command says exactly its one line.

    The held text goes to an unnamed temporary file, not a pipe: a C library that prints while holding
    the GIL could block on a full pipe that only a Python thread would empty. Only for the process's real
    stderr (the console script): in-process callers with their own `sys.stderr` (tests, notebooks) see no
    change. Where nothing can be redirected, nothing is held."""
    global _forked_stderr
    held = HeldChatter()
    if not _is_process_stderr(sys.stderr):
        yield held
        return
    import tempfile  # here: it imports random and shutil, which --help need not wait for

    process_stderr = sys.stderr
    try:
        process_stderr.flush()
        _flush_c_stdio()
        held_file = tempfile.TemporaryFile()
    except OSError:
        yield held
        return
    terminal_fd = os.dup(2)
    os.dup2(held_file.fileno(), 2)
    encoding = getattr(process_stderr, "encoding", None) or "utf-8"
    sys.stderr = open(terminal_fd, "w", encoding=encoding, errors="backslashreplace", closefd=False, buffering=1)
    _forked_stderr = process_stderr  # forked workers' Python output is chatter too
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _warning_to_fd2
            yield held
    finally:
        with contextlib.suppress(OSError, ValueError):
            sys.stderr.flush()
            process_stderr.flush()
        _flush_c_stdio()
        sys.stderr, _forked_stderr = process_stderr, None
        os.dup2(terminal_fd, 2)
        os.close(terminal_fd)
        with contextlib.suppress(OSError), held_file:
            size_bytes = held_file.seek(0, os.SEEK_END)
            if held.keep and size_bytes:
                held_file.seek(max(size_bytes - held.LIMIT_BYTES, 0))
                with open(2, "wb", closefd=False) as terminal:
                    terminal.write(held_file.read())


def _warning_to_fd2(message, category, filename, lineno, file=None, line=None) -> None:
    # warnings.showwarning writes to sys.stderr, which goes to the terminal while chatter is held
    with contextlib.suppress(OSError):
        os.write(2, warnings.formatwarning(message, category, filename, lineno, line).encode(errors="replace"))
