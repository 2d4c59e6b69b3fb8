"""Shared helpers for the capture tests: the real frames copied into tests/data."""

from pathlib import Path

DATA = Path(__file__).resolve().parent / "data"
APC = DATA / "apc_shelf_realsense"
TUM_PAIR = DATA / "tum_desk_pair"
TUM_K = "520.9,521.0,325.1,249.7"
APC_FRAMES = [15, 19, 23, 27]
