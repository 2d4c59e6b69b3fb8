"""The one output rule (README, "Outputs never destroy"), for every command that writes a folder or a file.

A command writes to an output path only if that path is absent, an empty folder, or an earlier output of
the same kind: a folder holding the marker file `MARKER` with the same command name (written by
`writing` when an output is complete), or, for a single-file output such as a Rerun `.rrd`, a file that
starts with the kind's magic bytes (or is empty). A file type names its producer well enough (any `.rrd`
is a viewer log, never a user's original), and no sidecar file is needed. Anything else is refused with
`OutputRefused`, one line naming the path; `force=True` replaces it, except that force never lets an
output be an input, inside one, around one, the current folder or a folder around it.

`writing` builds the output beside its destination under a hidden temporary name and swaps it in only
when it is complete (an atomic exchange where the file system has one), so an interrupted run leaves the
old output whole. Temporaries are named `.<name>.spare-twin-<pid>.<state>`: `tmp` (being written, or an
old output swapped out and not yet deleted), `partial` (a resumable output, kept on failure) or `old` (an
old output moved aside where no atomic exchange exists). `clean_stale` removes those whose process is
gone (restoring an `old` one whose swap was cut short); `writing` calls it first, so the next run cleans
up after a killed one. A resumable run adopts the partial output a killed run left.

`signals_as_interrupts` turns SIGTERM and SIGHUP into KeyboardInterrupt, so clean-ups run as they do on
Ctrl-C; `single_json_stdout` keeps everything but the one JSON object of `--json` off stdout, C and
C++ libraries' own printing included.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import json
import os
import re
import shutil
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from spare_twin.errors import SpareTwinError
from spare_twin.io import write_json_atomic

#: The marker file inside a complete output folder: {"command": ..., "format": MARKER_FORMAT}.
MARKER = ".spare-twin-output.json"
MARKER_FORMAT = "spare-twin-output/1"
_STATES = ("tmp", "partial", "old")
#: Temporaries this process is using now (a partial or temporary of our own pid not in here is stale).
_ACTIVE: set[Path] = set()


@dataclass(frozen=True)
class OutputKind:
    """What a command writes: a folder (recognised by its marker) or, with `magic`, a single file."""

    command: str
    """The command that writes it, as the user types it ("render", "capture import")."""
    magic: bytes | None = None
    """Single-file outputs: the first bytes of every file of this kind."""

    @property
    def is_file(self) -> bool:
        return self.magic is not None


#: Rerun recordings (`capture view --rrd`, `compare --rrd`): "RRF" and a format version digit.
RRD = OutputKind("rerun", magic=b"RRF")


class OutputRefused(SpareTwinError):
    """An output path the rule refuses; `replaceable` when force would replace it."""

    def __init__(self, path: str | Path, reason: str, replaceable: bool = False):
        self.path, self.reason, self.replaceable = str(path), reason, replaceable
        super().__init__(self.message("force"))

    def message(self, force_flag: str) -> str:
        """The one-line message, naming the force option as the caller spells it (a command: "--force")."""
        return f"{self.path}: {self.reason}" + (f"; {force_flag} replaces it" if self.replaceable else "")


def _as_kind(kind: OutputKind | str) -> OutputKind:
    return kind if isinstance(kind, OutputKind) else OutputKind(kind)


def _within(inner: Path, outer: Path) -> bool:
    return inner == outer or outer in inner.parents


def _real(path: str | Path) -> Path:
    return Path(os.path.realpath(path))


def output_command(folder: str | Path) -> str | None:
    """The command whose complete output `folder` is (its marker says so), or None."""
    try:
        marker = json.loads((Path(folder) / MARKER).read_text())
    except (OSError, ValueError):
        return None
    return marker.get("command") if isinstance(marker, dict) and marker.get("format") == MARKER_FORMAT else None


def _starts_with(path: Path, magic: bytes) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(len(magic)) == magic
    except OSError:
        return False


def check_output(
    path: str | Path, kind: OutputKind | str, inputs: Iterable[str | Path | None] = (), force: bool = False
) -> Path:
    """The absolute output path if `kind` may write there; else `OutputRefused` naming `path`.

    `inputs` are the files and folders the command reads: the output may not be one, lie inside
    one, or contain one, whatever `force` says.
    """
    kind = _as_kind(kind)
    shown = str(path)
    if not shown.strip():
        raise OutputRefused("''", "an output path cannot be empty")
    final = Path(os.path.abspath(path))
    real = _real(final)
    cwd = _real(os.getcwd())
    inputs = [(item, _real(item)) for item in inputs if item is not None]
    for item, inp in inputs:
        if real == inp:
            raise OutputRefused(shown, f"is the input {item}; name a new path for the output")
    # before "contains the input": `--out .` is refused for being the current folder, whatever it holds
    if _within(cwd, real):  # swapping it would pull the folder from under the shell
        where = "the current folder" if real == cwd else "a folder around the current one"
        raise OutputRefused(shown, f"is {where}; name a new folder for the output")
    for item, inp in inputs:
        if _within(real, inp):
            raise OutputRefused(shown, f"lies inside the input {item}; name a path outside it")
        if _within(inp, real):
            raise OutputRefused(shown, f"contains the input {item}; name a path that does not")
    ancestor = final.parent
    while not os.path.lexists(ancestor):
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise OutputRefused(shown, f"{ancestor} is a file, not a folder")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise OutputRefused(shown, f"cannot write in {ancestor} (permission denied or read-only)")
    busy = [pid for _, pid, _ in _temporaries(final) if pid != os.getpid() and process_alive(pid)]
    if busy:
        raise OutputRefused(shown, f"another spare-twin process (pid {busy[0]}) is writing it")
    if not os.path.lexists(final):
        return final
    if final.is_symlink():
        raise OutputRefused(shown, "is a symbolic link; name the folder or file itself")
    problem, replaceable = _problem(final, kind)
    if problem is None or (force and replaceable):
        return final
    raise OutputRefused(shown, problem, replaceable)


def _problem(final: Path, kind: OutputKind) -> tuple[str | None, bool]:
    """Why `kind` may not write over what is at `final` (None: it may), and whether force lets it."""
    if kind.is_file:
        if final.is_dir():  # a file output never replaces a folder, force or not: surely a slip
            return "is a folder; name a file", False
        if final.stat().st_size == 0 or _starts_with(final, kind.magic):
            return None, True
        return f"is not an earlier {kind.command} output", True
    if not final.is_dir():
        return "is a file, not a folder", True
    try:
        if not any(final.iterdir()):
            return None, True
    except OSError as exc:
        return f"cannot be read ({exc.strerror})", False
    found = output_command(final)
    if found == kind.command:
        return None, True
    if found:
        return f"is an earlier {found} output, not a {kind.command} one", True
    return f"is not empty and not an earlier {kind.command} output", True


# -- temporaries -------------------------------------------------------------------------------------


def process_alive(pid: int) -> bool:
    """Whether process `pid` runs (a zombie, killed but not reaped, does not): is a lock or temporary still owned?"""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:  # a killed process not yet reaped by its parent is writing nothing
        return " Z " not in Path(f"/proc/{pid}/stat").read_text().split(")", 1)[1][:4]
    except (OSError, IndexError):
        return True


def _temporary(final: Path, state: str, pid: int | None = None) -> Path:
    return final.parent / f".{final.name}.spare-twin-{os.getpid() if pid is None else pid}.{state}"


def _temporaries(final: Path) -> list[tuple[Path, int, str]]:
    """(path, pid, state) of every temporary of `final`."""
    pattern = re.compile(rf"\.{re.escape(final.name)}\.spare-twin-(\d+)\.({'|'.join(_STATES)})")
    try:
        names = os.listdir(final.parent)
    except OSError:
        return []
    found = []
    for name in names:
        m = pattern.fullmatch(name)
        if m:
            found.append((final.parent / name, int(m.group(1)), m.group(2)))
    return found


def _stale(path: Path, pid: int) -> bool:
    # pids are reused: a temporary whose pid now belongs to another process waits for a later run
    return path not in _ACTIVE if pid == os.getpid() else not process_alive(pid)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def clean_stale(path: str | Path, keep_partial: bool = False) -> list[Path]:
    """Remove the temporaries that killed runs left beside `path`; returns what was removed or restored.

    An old output moved aside by a swap that was cut short comes back to `path` if nothing is there.
    With `keep_partial`, resumable partial outputs stay for the caller to adopt.
    """
    final = Path(os.path.abspath(path))
    stale = [(p, state) for p, pid, state in _temporaries(final) if _stale(p, pid)]
    done = []
    for p, state in stale:
        if state == "old" and not os.path.lexists(final):
            os.rename(p, final)
            done.append(p)
    for p, state in stale:
        if os.path.lexists(p) and not (keep_partial and state == "partial"):
            _remove(p)
            done.append(p)
    return done


def _rename_exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one step (Linux renameat2 RENAME_EXCHANGE); False where that is not available."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
    except AttributeError:
        return False
    at_fdcwd, rename_exchange = -100, 2
    if renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _swap_in(tmp: Path, final: Path) -> None:
    if not os.path.lexists(final):
        os.rename(tmp, final)
    elif _rename_exchange(tmp, final):
        _remove(tmp)  # now the old output
    else:
        old = _temporary(final, "old")
        os.rename(final, old)
        os.rename(tmp, final)
        _remove(old)


def _claim(final: Path, kind: OutputKind, resumable: bool) -> Path:
    mine = _temporary(final, "partial" if resumable else "tmp")
    if mine in _ACTIVE:
        raise SpareTwinError(f"{final}: already being written by this process")
    if resumable:  # adopt what a killed run left: the rename is atomic, so two runs cannot both get it
        left = [p for p, pid, state in _temporaries(final) if state == "partial" and _stale(p, pid)]
        for p in sorted(left, key=lambda p: p.stat().st_mtime, reverse=True):
            with contextlib.suppress(OSError):
                os.rename(p, mine)
                break
        for p in left:
            if p != mine and os.path.lexists(p):
                _remove(p)
    if not kind.is_file and not mine.exists():
        if resumable and os.path.isdir(final) and output_command(final) == kind.command:
            _link_copy(final, mine)  # extend an earlier output: it is where the next run goes on from
        else:
            os.mkdir(mine)
    return mine


def _link_copy(src: Path, dst: Path) -> None:
    """A copy of the folder `src` whose files are hard links (copies across file systems), less the marker."""
    for dirpath, _, filenames in os.walk(src):
        folder = dst / Path(dirpath).relative_to(src)
        folder.mkdir(exist_ok=True)
        for name in filenames:
            if folder == dst and name == MARKER:
                continue
            try:
                os.link(Path(dirpath) / name, folder / name)
            except OSError:
                shutil.copy2(Path(dirpath) / name, folder / name)


def _missing_parents(final: Path) -> list[Path]:
    """The folders above `final` that do not exist yet, outermost first."""
    missing = []
    for parent in final.parents:
        if os.path.lexists(parent):
            break
        missing.append(parent)
    return missing[::-1]


@contextlib.contextmanager
def writing(
    path: str | Path,
    kind: OutputKind | str,
    inputs: Iterable[str | Path | None] = (),
    force: bool = False,
    resumable: bool = False,
) -> Iterator[Path]:
    """Yield a temporary sibling to write the output into; it replaces `path` once the block completes.

    A folder output yields a folder and gets the marker at the end; a file output (`OutputKind` with
    magic) yields the path of a file to create. On any exception, Ctrl-C included, the temporary is
    removed and `path` is left as it was. File system errors become one-line errors naming the file.

    With `resumable`, what was written stays on failure, and the next run on the same path gets it back;
    a run over an earlier output of the same kind starts from it (extending a data set, resuming a
    training run). The caller skips the files it finds and writes each file whole under a temporary
    name, then renames it: files of an earlier output are shared (hard links) until the swap.
    """
    kind = _as_kind(kind)
    inputs = tuple(inputs)
    final = check_output(path, kind, inputs, force)
    created = _missing_parents(final)
    try:
        for folder in created:
            os.mkdir(folder)
        clean_stale(final, keep_partial=resumable)
        tmp = _claim(final, kind, resumable)
    except OSError as exc:
        _remove_empty(created)
        raise SpareTwinError(f"{exc.filename or path}: cannot write ({exc.strerror})") from None
    _ACTIVE.add(tmp)
    try:
        try:
            yield tmp
            if kind.is_file:
                if not tmp.is_file():
                    raise SpareTwinError(f"{path}: nothing was written")
            else:
                write_json_atomic(tmp / MARKER, {"command": kind.command, "format": MARKER_FORMAT})
            check_output(path, kind, inputs, force)  # what is there may have changed while we wrote
            if resumable:  # complete now: under the partial name a killed swap would be adopted as one
                done = _temporary(final, "tmp")
                _ACTIVE.add(done)
                os.rename(tmp, done)
                _ACTIVE.discard(tmp)
                tmp = done
            _swap_in(tmp, final)
        except OSError as exc:
            raise SpareTwinError(f"{exc.filename or path}: cannot write ({exc.strerror})") from None
    except BaseException:
        if not resumable or tmp.name.endswith(".tmp"):
            _remove(tmp)
        clean_stale(final, keep_partial=resumable)  # puts back an old output whose swap was cut short
        _remove_empty(created)
        raise
    finally:
        _ACTIVE.discard(tmp)


def _remove_empty(folders: list[Path]) -> None:
    for folder in reversed(folders):
        with contextlib.suppress(OSError):
            os.rmdir(folder)
