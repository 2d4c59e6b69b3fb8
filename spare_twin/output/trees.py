"""Copies of folders that lose nothing: hidden files, links kept as links (never followed), empty
folders, files shared as hard links (copied where links fail), for the output rule's carries and
in-place updates. Paths are relative to the folder, "/"-separated; `skip` is a name at the top that
is left out (the output marker)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from spare_twin.errors import SpareTwinError


def real_dir(path: Path) -> bool:
    return path.is_dir() and not path.is_symlink()


def split(root: Path, listed: set[str] | None, skip: str) -> tuple[list[str], list[str]]:
    """The entries of the folder `root` that `listed` names (every one; None names all), and those it
    does not (outermost only: a folder it does not name stands for everything it holds). Sorted, so
    a folder comes before what it holds."""
    named, others, stack = [], [], [""]
    while stack:
        rel_dir = stack.pop()
        with os.scandir(root / rel_dir) as it:
            for entry in it:
                rel = f"{rel_dir}/{entry.name}" if rel_dir else entry.name
                if rel == skip:
                    continue
                if listed is not None and rel not in listed:
                    others.append(rel)
                    continue
                named.append(rel)
                if entry.is_dir(follow_symlinks=False):
                    stack.append(rel)
    return sorted(named), sorted(others)


def entries(root: Path, skip: str) -> list[str]:
    """Every path under the folder `root` (files, links, folders), a folder before what it holds."""
    return split(root, None, skip)[0]


def copy_file(src: Path, dst: Path) -> None:
    """A link as a link, anything else as a hard link, or a copy where links fail (another file system,
    overlayfs, a file system without them)."""
    if src.is_symlink():
        os.symlink(os.readlink(src), dst)
        return
    try:
        os.link(src, dst, follow_symlinks=False)
    except OSError:
        try:
            shutil.copy2(src, dst, follow_symlinks=False)
        except shutil.SpecialFileError:
            raise SpareTwinError(f"{src}: a pipe, socket or device file, which cannot be copied") from None


def copy_entries(src: Path, dst: Path, rels: list[str]) -> dict[str, int]:
    """Copy the entries `rels` of the folder `src` (a folder before what it holds) into the folder `dst`:
    a folder made empty (what it holds is named too), a file or link by `copy_file`. Returns each
    copy's inode, by path."""
    inodes = {}
    for rel in rels:
        if real_dir(src / rel):
            os.mkdir(dst / rel)
        else:
            copy_file(src / rel, dst / rel)
        inodes[rel] = os.lstat(dst / rel).st_ino
    return inodes


def copy_in(src: Path, dst: Path) -> None:
    """`dst` (absent) becomes a copy of `src` and everything it holds; folders keep their modes and times."""
    if not real_dir(src):
        copy_file(src, dst)
        return
    os.mkdir(dst)
    rels = entries(src, skip="")
    copy_entries(src, dst, rels)
    for rel in [*reversed(rels), ""]:  # innermost first, once filled: a read-only folder stays read-only
        if real_dir(src / rel):
            shutil.copystat(src / rel, dst / rel, follow_symlinks=False)


def clashes(earlier: Path, new: Path, theirs: list[str]) -> tuple[list[str], list[str]]:
    """Of the entries `theirs` of the folder `earlier`: those that fit into the folder `new` as they are
    (a folder that `new` has too is merged, entry by entry), and those `new` has itself."""
    fits, clash, stack = [], [], list(theirs)
    while stack:
        rel = stack.pop()
        src, dst = earlier / rel, new / rel
        if os.path.lexists(dst):
            if real_dir(src) and real_dir(dst):
                stack.extend(f"{rel}/{name}" for name in os.listdir(src))
            else:
                clash.append(rel)
        elif any(os.path.lexists(new / up) and not real_dir(new / up) for up in Path(rel).parents):
            clash.append(rel)  # where `new` has a file or a link, not a folder
        else:
            fits.append(rel)
    return sorted(fits), sorted(clash)
