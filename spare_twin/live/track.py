"""Incremental registration: each frame `live` takes is placed against the frame taken before it.

The batch registration (`capture.registration.register_frames`) needs every frame before it starts;
a stream has only what it has seen. So each new frame is matched to the last frame placed, with the
same pairwise step the batch registration chains (`capture.icp.PairRegistrar.edge`: multi-scale
point-to-plane ICP from the previous pair's motion, then from no motion, then FPFH + RANSAC), and its
pose is the last pose times that motion. A frame that overlaps nothing placed (fitness below
`min_fitness` from every guess) is not placed and the next frame is tried against the same last one.

A frame the camera has barely moved from the last placed one (less than `MIN_STEP_DEG` by its rate
between the last two placed frames) is let go unplaced, before it is even decoded: every pair chained
adds its error, so fewer, wider steps drift less (and leave the cores to the estimate).

Chained pairs drift (a few degrees over a 360 degree sweep); the estimate does not rest on it alone:
before each estimate the views are brought into register on the object (`observe.on_object`), which
takes out the slips that blur the chain's layers, and the final answer is `predict`'s own (its batch
registration, loop closures and all) on the recording `live` wrote.

Frames are worked on at most `work_width` pixels wide (every k-th pixel, the intrinsics following):
registration blocks pixels a few millimetres wide anyway, and the estimate's views need no more, so a
640 x 480 stream costs a quarter of the work and memory. Placed frames are kept for the estimate up to
`max_kept`; past that every other one is let go (the kept ones stay spread over the whole stream),
so memory is bounded however long the stream runs. Deterministic: the same frames in the same order
give the same poses (the pairwise step is).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from spare_twin.capture.frames import RGBDFrame, rotation_error_deg
from spare_twin.capture.icp import PairRegistrar, frame_cloud
from spare_twin.capture.registration import RegistrationConfig
from spare_twin.live.sources import StreamFrame

#: A frame is placed only once the camera has turned this far (degrees) or moved this far (metres)
#: since the last placed frame, judged by its rate between the last two placed frames, or after
#: `MAX_GAP_S` whatever the rate. Chained pairs drift with their number: on the bench's 300-frame
#: loop, the last update was 0.007-0.015 pu off the truth where 33-60 frames were placed (6-11
#: degrees apart), 0.014-0.069 where 81-88 were (about 4 degrees apart: a quieter machine placed
#: more), 0.040-0.100 where all 300 were.
MIN_STEP_DEG = 8.0
MIN_STEP_M = 0.05
MAX_GAP_S = 0.5

#: RANSAC draws when a frame's ICP guesses fail (the batch registration's 100,000 take seconds a frame,
#: which a stream cannot wait for; a frame RANSAC misses is simply not placed, and the next one tried).
RANSAC_ITERATIONS = 5000


@dataclass(frozen=True)
class PlacedFrame:
    """A frame placed in the stream's world (the first placed frame's camera)."""

    index: int
    t_s: float
    frame: RGBDFrame
    """Colour and depth at the working resolution, with its intrinsics."""
    T_world_camera: np.ndarray


def working_frame(f: StreamFrame, K: np.ndarray, depth_scale: float, work_width: int) -> RGBDFrame:
    """The frame at most `work_width` wide: every k-th pixel (nearest: depth is never blended across
    an edge), K for the pixel centres kept."""
    k = max(1, -(-f.depth_u16.shape[1] // work_width))
    if k == 1:
        return RGBDFrame(f.color_rgb, f.depth_u16, depth_scale, np.asarray(K, np.float64))
    K2 = np.asarray(K, np.float64).copy()
    K2[0, 0] /= k
    K2[1, 1] /= k
    K2[:2, 2] /= k  # pixel i * k becomes pixel i: u' = u / k
    return RGBDFrame(
        np.ascontiguousarray(f.color_rgb[::k, ::k]), np.ascontiguousarray(f.depth_u16[::k, ::k]), depth_scale, K2
    )


@dataclass
class Tracker:
    """Places frames one by one (see the module doc); `kept` is what the estimate reads."""

    K: np.ndarray
    depth_scale: float
    work_width: int = 320
    max_kept: int = 120
    cfg: RegistrationConfig = field(default_factory=lambda: RegistrationConfig(ransac_iterations=RANSAC_ITERATIONS))
    kept: list[PlacedFrame] = field(default_factory=list)
    path: list[np.ndarray] = field(default_factory=list)
    """Every placed frame's camera-to-world pose, in order (the camera's path)."""
    min_step_deg: float = MIN_STEP_DEG
    min_step_m: float = MIN_STEP_M
    max_gap_s: float = MAX_GAP_S
    placed: int = 0
    not_placed: int = 0
    skipped: int = 0
    """Frames let go unplaced: too little motion since the last placed one (`MIN_STEP_DEG`)."""
    seconds: float = 0.0
    """Wall seconds spent placing frames."""
    _last: tuple | None = None
    """(cloud, pose) of the last placed frame."""
    _motion: np.ndarray = field(default_factory=lambda: np.eye(4))
    _last_t_s: float = 0.0
    _rate: tuple[float, float] | None = None
    """(degrees, metres) a second the camera moved between the last two placed frames."""

    def add(self, f: StreamFrame) -> PlacedFrame | None:
        """Place `f`; None when it overlaps nothing placed."""
        t0 = time.perf_counter()
        try:
            return self._add(f)
        finally:
            self.seconds += time.perf_counter() - t0

    def too_close(self, t_s: float) -> bool:
        """Whether a frame at stream time `t_s` is too little moved from the last placed one to be
        worth placing, by the camera's rate between the last two placed frames (`MIN_STEP_DEG`)."""
        if self._rate is None:
            return False
        dt = t_s - self._last_t_s
        if dt >= self.max_gap_s:
            return False
        deg_s, m_s = self._rate
        return dt * deg_s < self.min_step_deg and dt * m_s < self.min_step_m

    def _add(self, f: StreamFrame) -> PlacedFrame | None:
        if self.too_close(f.t_s):  # before decoding it: a frame let go costs nothing
            self.skipped += 1
            return None
        frame = working_frame(f, self.K, self.depth_scale, self.work_width)
        cloud = frame_cloud(frame, self.cfg)
        if len(cloud.points) < 100:  # nothing within range: a covered or blinded sensor
            self.not_placed += 1
            return None
        if self._last is None:
            pose = np.eye(4)
        else:
            last_cloud, last_pose = self._last
            pair = PairRegistrar([last_cloud, cloud], self.cfg)
            guesses = [self._motion, np.eye(4)] if self.placed > 1 else [np.eye(4)]
            edge = pair.edge(1, 0, guesses, neighbours=True)
            if edge is None:
                self.not_placed += 1
                return None
            self._motion = edge.T_target_source
            pose = last_pose @ edge.T_target_source
            dt = f.t_s - self._last_t_s
            if dt > 0:
                self._rate = (
                    rotation_error_deg(self._motion[:3, :3]) / dt,
                    float(np.linalg.norm(self._motion[:3, 3])) / dt,
                )
        self._last_t_s = f.t_s
        self._last = (cloud, pose)
        self.placed += 1
        self.path.append(pose)
        placed = PlacedFrame(f.index, f.t_s, frame, pose)
        self.kept.append(placed)
        if len(self.kept) > self.max_kept:
            # let every other one go, the newest kept: the rest stay spread over the whole stream
            self.kept = self.kept[-1::-2][::-1]
        return placed
