"""One shared set of input validators: poses, counts and sizes, worker pools, input files and folders
(JSON text: `spare_twin.io.read_json`).

Every reader of user input (recordings, importers, object folders, rig and config files, datasets,
checkpoints) checks through these, so one kind of bad input gets one kind of one-line error naming the
file or the parameter (`SpareTwinError`), before anything is used or written.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from spare_twin.errors import SpareTwinError

# -- poses -------------------------------------------------------------------------------------------

#: Largest deviation of R^T R from the identity, and of det R from +1, accepted in a rotation (a pose
#: written as text with 6 decimals, or a float32 pose, is well within it; a scaled or sheared one is not).
ROTATION_TOLERANCE = 1e-3
#: Largest deviation of a pose's bottom row from [0, 0, 0, 1].
BOTTOM_ROW_TOLERANCE = 1e-6
#: Farthest a camera or object may be from the world origin, metres: a table-top capture spans metres;
#: a kilometre is already implausible, and anything beyond it is a unit or parsing mistake.
MAX_TRANSLATION_M = 1000.0


def pose_problem(T) -> str | None:
    """Why the 4x4 `T` is not a rigid camera or object pose, or None when it is one."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        return f"a pose must be 4x4, got shape {T.shape}"
    if not np.isfinite(T).all():
        return "not finite (NaN or infinity)"
    if np.abs(T[3] - (0.0, 0.0, 0.0, 1.0)).max() > BOTTOM_ROW_TOLERANCE:
        return f"bottom row {' '.join(f'{v:.6g}' for v in T[3])}: must be 0 0 0 1"
    R = T[:3, :3]
    err = np.abs(R.T @ R - np.eye(3)).max()
    if err > ROTATION_TOLERANCE:
        return f"rotation part is not orthonormal (R^T R differs from I by {err:.3g}: scaled or sheared?)"
    det = float(np.linalg.det(R))
    if abs(det - 1.0) > ROTATION_TOLERANCE:
        return f"rotation part has determinant {det:.3g}, not +1 (a reflection)"
    with np.errstate(over="ignore"):  # 1e300 m squared is infinite, and still beyond the bound
        dist_m = float(np.linalg.norm(T[:3, 3]))
    if dist_m > MAX_TRANSLATION_M:
        return f"translation {dist_m:.3g} m is beyond {MAX_TRANSLATION_M:g} m (wrong units?)"
    return None


def check_pose(T, where: str) -> np.ndarray:
    """`T` as a float64 4x4 rigid pose; else a one-line error starting with `where` (a file, a key)."""
    problem = pose_problem(T)
    if problem:
        raise SpareTwinError(f"{where}: not a rigid pose ({problem})")
    return np.asarray(T, dtype=np.float64)


def check_poses(poses, where: str) -> np.ndarray:
    """An (N, 4, 4) stack of rigid poses; the error names the first bad one's index."""
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise SpareTwinError(f"{where}: expected an (N, 4, 4) array of poses, got shape {poses.shape}")
    # all at once (a long recording has a pose per frame); the first bad one is then described
    with np.errstate(all="ignore"):
        R = poses[:, :3, :3]
        ok = np.isfinite(poses).all(axis=(1, 2))
        ok &= np.abs(poses[:, 3] - (0.0, 0.0, 0.0, 1.0)).max(axis=1) <= BOTTOM_ROW_TOLERANCE
        ok &= np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max(axis=(1, 2)) <= ROTATION_TOLERANCE
        ok &= np.abs(np.linalg.det(np.where(np.isfinite(R), R, 0.0)) - 1.0) <= ROTATION_TOLERANCE
        ok &= np.linalg.norm(poses[:, :3, 3], axis=1) <= MAX_TRANSLATION_M
    for i in np.flatnonzero(~ok)[:1]:
        raise SpareTwinError(f"{where}: pose {i} is not a rigid pose ({pose_problem(poses[i])})")
    return poses


# -- counts, sizes, machines -------------------------------------------------------------------------


def usable_cores() -> int:
    """CPU cores this process may run on (its affinity mask, else the machine's count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def memory_bytes() -> int:
    """Physical memory of the machine, bytes (8 GiB when the system will not say)."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 8 * 2**30


def check_whole(name: str, value, least: int = 1) -> int:
    """`value` is a whole number (an int, not a bool) of at least `least`; the error starts with `name`."""
    if isinstance(value, bool) or not isinstance(value, int) or value < least:
        raise SpareTwinError(f"{name} {value!r}: must be a whole number, at least {least}")
    return value


def check_count(name: str, value, upper: int, why: str, lower: int = 1) -> int:
    """`value` is a whole number within lower..upper; `why` says where the upper bound comes from."""
    check_whole(name, value, lower)
    if value > upper:
        raise SpareTwinError(f"{name} {value}: at most {upper:,} ({why})")
    return value


def check_fits_memory(name: str, value: int, bytes_each: float, copies: int = 1, share: float = 0.5) -> int:
    """`value` items of `bytes_each` bytes, held `copies` times at once, fit in `share` of the memory."""
    limit = int(memory_bytes() * share / max(1.0, bytes_each * copies))
    gib = memory_bytes() / 2**30
    return check_count(name, value, max(1, limit), f"{bytes_each * copies / 2**20:.3g} MB each; {gib:.0f} GiB memory")


def cap_workers(workers: int, work: int, name: str = "workers") -> int:
    """Worker processes to start: at most the usable cores and the items of work; a cap is said once
    on stderr (the user's intent, "as parallel as it goes", is clear, so it is not refused)."""
    cores = usable_cores()
    capped = max(1, min(workers, cores, work))
    if capped < workers:
        reasons = [f"{cores} cores" if cores == capped else "", f"{work} to do" if work == capped else ""]
        print(f"note: {name} {workers}: using {capped} ({', '.join(r for r in reasons if r)})", file=sys.stderr)
    return capped


# -- input files and folders -------------------------------------------------------------------------


def check_file(path: str | Path, what: str) -> Path:
    """`path` as a Path if it is a file; else "<path>: no such <what>". Commands check their input files
    with it before they import what reads them (torch, for a checkpoint: seconds of a new process)."""
    path = Path(path)
    if not path.is_file():
        raise SpareTwinError(f"{path}: no such {what}")
    return path


def check_folder(name: str, path: str | Path) -> Path:
    """`path` as a Path if it is a folder; else "<name> <path>: no such folder" (a command says its flag)."""
    path = Path(path)
    if not path.is_dir():
        raise SpareTwinError(f"{name} {path}: no such folder")
    return path
