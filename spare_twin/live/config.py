"""`live`'s settings (`LiveConfig`) and its output's kind: checked before the source is opened, and
light to import (`spare-twin live` checks them before it loads torch and the measurement)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spare_twin.errors import SpareTwinError
from spare_twin.validate import check_whole

#: The command whose output the recording is (its output marker).
LIVE = "live"


@dataclass(frozen=True)
class LiveConfig:
    update_s: float = 1.0
    """An estimate at least this often (seconds of wall time) while new frames are placed."""
    stable_s: float = 3.0
    """"enough" once the answer held this long (seconds of the stream) with strong evidence."""
    until_stable: bool = False
    """Stop the stream at "enough"."""
    queue_frames: int = 2
    """Frames waiting to be placed; more are dropped from the estimate (never from the recording)."""
    views: int = 16
    """The most placed frames an update reads (spread evenly over the stream so far). Updates start
    with `start_views` and read 2 more while an update takes less than 0.4 `update_s`, 2 fewer
    (down to 4) while it takes more than 0.8 `update_s`: the rate holds on a busy machine and a quiet one
    reads more (on a 640 x 480 loop, 8 views measured within 0.015 pu of the truth, 16 within 0.007;
    an update of 8 took 1.2-2.4 s on the loaded 2-core machine, 16 twice that). The last update, once
    the stream has ended, reads `views`."""
    start_views: int = 8
    first_views: int = 3
    """No update before this many frames are placed (two views show too little of the object to count)."""
    work_width: int = 320
    """Frames are placed and estimated at most this wide (`live.track`)."""
    max_kept: int = 120
    """Placed frames kept in memory for the estimate (`live.track`)."""
    estimate_process: bool = True
    """Observe and measure in a process of its own (`measure.process`), beside the tracker; False: on
    the estimator thread, taking turns with the tracker."""

    def __post_init__(self):
        for name in ("update_s", "stable_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise SpareTwinError(f"{name} {v!r}: must be a positive number of seconds")
        for name, least in (("queue_frames", 1), ("views", 2), ("start_views", 2), ("work_width", 32), ("max_kept", 4)):
            check_whole(name, getattr(self, name), least)
