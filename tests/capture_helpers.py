"""Shared helpers for the capture tests: the real frames copied into tests/data."""

import shutil
from pathlib import Path

DATA = Path(__file__).resolve().parent / "data"
APC = DATA / "apc_shelf_realsense"
TUM_PAIR = DATA / "tum_desk_pair"
TUM_K = "520.9,521.0,325.1,249.7"
APC_FRAMES = [15, 19, 23, 27]


def seven_scenes(dst: Path, frames=(15, 19)) -> Path:
    """A 7-Scenes folder `dst` of the APC frames `frames` (colour, depth and pose each) and the intrinsics."""
    dst.mkdir(parents=True)
    for n in frames:
        for kind in ("color.png", "depth.png", "pose.txt"):
            shutil.copy(APC / f"frame-{n:06d}.{kind}", dst)
    shutil.copy(APC / "intrinsics.K.txt", dst)
    return dst
