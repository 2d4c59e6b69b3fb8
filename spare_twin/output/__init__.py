"""The one output rule (README, "Outputs never destroy"), for every command that writes a folder or a file.

A command writes to an output path only if that path is absent, an empty folder, or an earlier output of
the same kind: a folder holding the marker file `MARKER` with the same command name (written by
`writing` when an output is complete), or, for a single-file output such as a Rerun `.rrd`, a file that
starts with the kind's magic bytes (or is empty). A file type names its producer well enough (any `.rrd`
is a viewer log, never a user's original), and no sidecar file is needed. Anything else is refused with
`OutputRefused`, one line naming the path; `force=True` replaces it, except that force never lets an
output be an input, inside one, around one, the current folder or a folder around it.

Nothing lost. The marker lists every path the command wrote (files, links and folders). Replacing an
earlier output of the same command carries everything else in it (a user's notes, hidden files, links
kept as links, empty folders) into the new output, byte for byte (hard links); should the new output
write one of those paths itself, the run is refused before anything is replaced (`force` lets the new
file win). A marker of an older version ("spare-twin-output/1") lists nothing, and nobody can tell its
files from the user's: the new output replaces it only if it writes every path the earlier one holds,
so no file of the user's is dropped and no stale file of the command's (a frame past the new end of a
recording, say) is mixed into the new output; otherwise the run is refused, and `force` replaces it
whole. A resumable run starts from the earlier output's own files (all of an older marker's output,
which it then lists as its own), and an in-place update (`in_place=True`: a registration written into
a recording) starts from everything in the folder; either way the marker then lists the earlier
output's files and those the run wrote. (`trees`: the copies; `process`: owners beyond the pid.)

`writing` builds the output beside its destination under a hidden temporary name and swaps it in only
when it is complete (an atomic exchange where the file system has one, else rename aside and rename in,
else copies: overlayfs answers EXDEV to both renames of a folder it holds in a lower layer), so an
interrupted run leaves the old output whole. Temporaries are named `.<name>.spare-twin-<owner>.<state>`:
`tmp` (being written, or an old output swapped out and not yet deleted), `partial` (a resumable output,
kept on failure), `old` (an old output moved aside where no atomic exchange exists) or `away` (a copy of
an old output that could not be moved). `<name>` is the output's name, cut short with a hash of the
whole where the temporary's name would pass NAME_MAX. `<owner>` names the writing process beyond its pid,
which a reboot or a long uptime hands to another process: `<pid>-<start time in clock ticks>-<boot id>`
(`process_token`). `clean_stale` removes the temporaries whose owner is gone (restoring an old output
whose swap was cut short); `writing` calls it first, so the next run cleans up after a killed one. A
resumable run adopts the partial output a killed run left. Older temporaries and locks name only a pid:
they count as their owner's while that pid runs a process started before they were last written.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import hashlib
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
from spare_twin.output import trees
from spare_twin.output.process import TOKEN, process_alive, process_token, token_alive, token_pid

__all__ = [
    "MARKER",
    "RRD",
    "OutputKind",
    "OutputRefused",
    "check_output",
    "clean_stale",
    "output_command",
    "output_files",
    "own_files",
    "process_alive",
    "process_token",
    "token_alive",
    "token_pid",
    "writing",
]

#: The marker file inside a complete output folder: {"command": ..., "format": MARKER_FORMAT, "files": [...]}.
MARKER = ".spare-twin-output.json"
MARKER_FORMAT = "spare-twin-output/2"
#: Markers of older versions: the same meaning, but no list of the files the command wrote.
_UNLISTED_FORMATS = ("spare-twin-output/1",)
_STATES = ("tmp", "partial", "old", "away")
#: Temporaries this process is using now (a partial or temporary of our own not in here is stale).
_ACTIVE: set[Path] = set()
_NAME_MAX_BYTES = 255
#: Room a temporary's name needs beyond the output's name: ".", ".spare-twin-", the owner, "." and the state.
_TEMPORARY_EXTRA_BYTES = 64


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


def _marker(folder: str | Path) -> dict | None:
    try:
        marker = json.loads((Path(folder) / MARKER).read_text())
    except (OSError, ValueError, RecursionError):
        return None
    ok = isinstance(marker, dict) and marker.get("format") in (MARKER_FORMAT, *_UNLISTED_FORMATS)
    return marker if ok else None


def output_command(folder: str | Path) -> str | None:
    """The command whose complete output `folder` is (its marker says so), or None."""
    marker = _marker(folder)
    return marker.get("command") if marker else None


def output_files(folder: str | Path) -> set[str] | None:
    """The paths (relative, "/"-separated) the command wrote into the output `folder`, as its marker lists
    them; None where no marker lists them (an older version's, or none at all)."""
    marker = _marker(folder)
    files = marker.get("files") if marker else None
    if not isinstance(files, list) or not all(isinstance(f, str) for f in files):
        return None
    return set(files)


def _starts_with(path: Path, magic: bytes) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(len(magic)) == magic
    except OSError:
        return False


def check_output(
    path: str | Path,
    kind: OutputKind | str,
    inputs: Iterable[str | Path | None] = (),
    force: bool = False,
    in_place: bool = False,
) -> Path:
    """The absolute output path if `kind` may write there; else `OutputRefused` naming `path`.

    `inputs` are the files and folders the command reads: the output may not be one, lie inside
    one, or contain one, whatever `force` says. `in_place`: the command updates the folder at `path`
    (the messages say so).
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
        if in_place:
            raise OutputRefused(
                shown,
                f"is {where}; an update in place swaps in a new folder, which would pull it from under the "
                "shell: run this from outside it",
            )
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
    mine = process_token()
    busy = [owner for p, owner, _ in _temporaries(final) if owner != mine and not _stale(p, owner)]
    if busy:
        raise OutputRefused(shown, f"another spare-twin process (pid {token_pid(busy[0])}) is writing it")
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


def _mtime(path: Path) -> float | None:
    try:
        return os.lstat(path).st_mtime
    except OSError:
        return None


# -- temporaries -------------------------------------------------------------------------------------


def _stem(name: str) -> str:
    """`name`, or where a temporary's name would pass NAME_MAX, its start and a hash of the whole."""
    if len(os.fsencode(name)) + _TEMPORARY_EXTRA_BYTES <= _NAME_MAX_BYTES:
        return name
    budget = _NAME_MAX_BYTES - _TEMPORARY_EXTRA_BYTES - 13
    kept = ""
    for char in name:  # whole characters only: a name cut inside one would not print
        if len(os.fsencode(kept + char)) > budget:
            break
        kept += char
    return f"{kept}~{hashlib.sha256(os.fsencode(name)).hexdigest()[:12]}"


def _temporary(final: Path, state: str, owner: str | None = None) -> Path:
    return final.parent / f".{_stem(final.name)}.spare-twin-{owner or process_token()}.{state}"


def _temporaries(final: Path) -> list[tuple[Path, str, str]]:
    """(path, owner token, state) of every temporary of `final`."""
    pattern = re.compile(rf"\.{re.escape(_stem(final.name))}\.spare-twin-({TOKEN})\.({'|'.join(_STATES)})")
    try:
        names = os.listdir(final.parent)
    except OSError:
        return []
    found = []
    for name in names:
        m = pattern.fullmatch(name)
        if m:
            found.append((final.parent / name, m.group(1), m.group(2)))
    return found


def _stale(path: Path, owner: str) -> bool:
    if owner == process_token():
        return path not in _ACTIVE
    return not token_alive(owner, _mtime(path))


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def clean_stale(path: str | Path, keep_partial: bool = False) -> list[Path]:
    """Remove the temporaries that killed runs left beside `path`; returns what was removed or restored.

    An old output moved aside by a swap that was cut short comes back to `path` if nothing is there,
    and a copy of one that could not be moved comes back over what is left of it while the new output
    had not come in (its temporary is still there). With `keep_partial`, resumable partial outputs stay
    for the caller to adopt.
    """
    final = Path(os.path.abspath(path))
    stale = [(p, owner, state) for p, owner, state in _temporaries(final) if _stale(p, owner)]
    done = []
    for p, owner, state in stale:
        if state == "away" and os.path.lexists(_temporary(final, "tmp", owner)):
            _remove(final)  # half deleted when the run was cut off
        if state in ("old", "away") and not os.path.lexists(final):
            os.rename(p, final)
            done.append(p)
    for p, _, state in stale:
        if os.path.lexists(p) and not (keep_partial and state == "partial"):
            _remove(p)
            done.append(p)
    return done


# -- what the command did not write ------------------------------------------------------------------


def _entries(root: Path) -> list[str]:
    return trees.entries(root, skip=MARKER)


def _keep_users_entries(final: Path, tmp: Path, kind: OutputKind, shown: str, force: bool) -> None:
    """Carry into the new output `tmp` what the earlier output `final` holds that its command did not
    write; refused (`OutputRefused`) where the new output writes one of those paths itself."""
    listed = output_files(final)
    if listed is None:  # an older marker: which files are the command's is not written down
        dropped = trees.split(final, set(_entries(tmp)), skip=MARKER)[1]
        if dropped and not force:
            more = f" and {len(dropped) - 1} more" if len(dropped) > 1 else ""
            raise OutputRefused(
                shown,
                f"an earlier {kind.command} output from an older spare-twin (its files are not listed) holds "
                f"{dropped[0]}{more}, which this run does not write; move what is yours out of it",
                replaceable=True,
            )
        return
    fits, clashes = trees.clashes(final, tmp, trees.split(final, listed, skip=MARKER)[1])
    if clashes and not force:
        more = f" (and {len(clashes) - 1} more)" if len(clashes) > 1 else ""
        raise OutputRefused(
            shown,
            f"holds {clashes[0]}{more}, which {kind.command} did not write there but now writes; move it out",
            replaceable=True,
        )
    for rel in fits:
        (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
        trees.copy_in(final / rel, tmp / rel)


def _written_in_place(tmp: Path, copied: dict[str, int], listed: set[str] | None) -> list[str] | None:
    """What an in-place update's output holds of the command's: what it wrote or replaced (a new inode)
    and what it kept of the earlier output's listed files. None: the earlier output listed nothing."""
    if listed is None:
        return None
    return [rel for rel in _entries(tmp) if copied.get(rel) != os.lstat(tmp / rel).st_ino or rel in listed]


# -- the swap ----------------------------------------------------------------------------------------


def _exchange(a: Path, b: Path) -> int:
    """Swap two paths in one step (Linux renameat2 RENAME_EXCHANGE): 0, or the error number."""
    if not sys.platform.startswith("linux"):
        return errno.ENOSYS
    try:
        renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
    except AttributeError:
        return errno.ENOSYS
    at_fdcwd, rename_exchange = -100, 2
    if renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return 0
    return ctypes.get_errno()


def _rename_exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one step; False where the system or the file system cannot."""
    err = _exchange(a, b)
    if err in (0, errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EXDEV):  # EXDEV: overlayfs, a lower layer
        return err == 0
    raise OSError(err, os.strerror(err), str(b))


def _swap_in(tmp: Path, final: Path) -> None:
    if not os.path.lexists(final):
        os.rename(tmp, final)
    elif _rename_exchange(tmp, final):
        _remove(tmp)  # now the old output
    else:
        old = _temporary(final, "old")
        try:
            os.rename(final, old)
        except OSError as exc:
            if exc.errno != errno.EXDEV:
                raise
            _swap_by_copy(tmp, final)
            return
        os.rename(tmp, final)
        _remove(old)


def _swap_by_copy(tmp: Path, final: Path) -> None:
    """Where the old output cannot be moved (overlayfs: a folder of a lower layer): copy it aside, delete
    it, move the new one in. A run cut off meanwhile leaves the copy, which `clean_stale` puts back."""
    old, away = _temporary(final, "old"), _temporary(final, "away")
    trees.copy_in(final, old)  # a half-made copy is "old" beside a whole output: removed as stale
    os.rename(old, away)  # complete: from here on it is the old output
    try:
        _remove(final)
        os.rename(tmp, final)
    except BaseException:
        if os.path.lexists(tmp):
            _remove(final)
            os.rename(away, final)
        raise
    _remove(away)


# -- writing -----------------------------------------------------------------------------------------


def _claim(final: Path, kind: OutputKind, resumable: bool, in_place: bool) -> tuple[Path, dict[str, int]]:
    """The temporary to write into, and (in place) the inode of each entry copied into it."""
    mine = _temporary(final, "partial" if resumable else "tmp")
    if mine in _ACTIVE:
        raise SpareTwinError(f"{final}: already being written by this process")
    if resumable:  # adopt what a killed run left: the rename is atomic, so two runs cannot both get it
        left = [p for p, owner, state in _temporaries(final) if state == "partial" and _stale(p, owner)]
        for p in sorted(left, key=lambda p: p.stat().st_mtime, reverse=True):
            with contextlib.suppress(OSError):
                os.rename(p, mine)
                break
        for p in left:
            if p != mine and os.path.lexists(p):
                _remove(p)
    copied: dict[str, int] = {}
    if not kind.is_file and not mine.exists():
        os.mkdir(mine)
        if in_place:  # everything: what the update does not change stays as it was
            copied = trees.copy_entries(final, mine, _entries(final))
        elif resumable and os.path.isdir(final) and output_command(final) == kind.command:
            # extend an earlier output from its own files (the user's come in at the end)
            trees.copy_entries(final, mine, trees.split(final, output_files(final), skip=MARKER)[0])
    return mine, copied


def _missing_parents(final: Path) -> list[Path]:
    """The folders above `final` that do not exist yet, outermost first."""
    missing = []
    for parent in final.parents:
        if os.path.lexists(parent):
            break
        missing.append(parent)
    return missing[::-1]


def own_files(folder: str | Path) -> set[str] | None:
    """The paths spare-twin wrote into `folder`, as its marker lists them; none where it has no marker
    (a folder of the user's, updated in place); None where an older marker does not list them."""
    return output_files(folder) if _marker(folder) else set()


@contextlib.contextmanager
def writing(
    path: str | Path,
    kind: OutputKind | str,
    inputs: Iterable[str | Path | None] = (),
    force: bool = False,
    resumable: bool = False,
    in_place: bool = False,
) -> Iterator[Path]:
    """Yield a temporary sibling to write the output into; it replaces `path` once the block completes.

    A folder output yields a folder and gets the marker at the end; a file output (`OutputKind` with
    magic) yields the path of a file to create. On any exception, Ctrl-C included, the temporary is
    removed and `path` is left as it was. File system errors become one-line errors naming the file.
    What an earlier output of the same command holds that the command did not write is kept (module doc).

    With `resumable`, what was written stays on failure, and the next run on the same path gets it back;
    a run over an earlier output of the same kind starts from it (extending a data set, resuming a
    training run). The caller skips the files it finds and writes each file whole under a temporary
    name, then renames it: files of an earlier output are shared (hard links) until the swap.

    With `in_place` (an existing folder at `path`, updated: a registration, calibrated poses), the
    temporary starts as a copy of everything in it (hard links, links as links); the caller writes or
    removes what it updates, each file whole under a temporary name and renamed.
    """
    kind = _as_kind(kind)
    inputs = tuple(inputs)
    final = check_output(path, kind, inputs, force, in_place)
    created = _missing_parents(final)
    try:
        for folder in created:
            os.mkdir(folder)
        clean_stale(final, keep_partial=resumable)
        listed = own_files(final) if in_place else None
        tmp, copied = _claim(final, kind, resumable, in_place)
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
                files = _written_in_place(tmp, copied, listed) if in_place else _entries(tmp)
                if not in_place and os.path.isdir(final) and output_command(final) == kind.command:
                    if not (resumable and output_files(final) is None):  # then it started from all of it
                        _keep_users_entries(final, tmp, kind, str(path), force)
                marker = {"command": kind.command, "format": MARKER_FORMAT, "files": files}
                write_json_atomic(tmp / MARKER, marker)
            check_output(path, kind, inputs, force, in_place)  # what is there may have changed while we wrote
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
