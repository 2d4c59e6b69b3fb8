"""Any recording as the yaw-free network's input: posed views -> object points -> chain profile.

`observe_chain` is what `predict` runs on every recording. It reduces the recording to posed depth
views (`recording_views`), then goes through the same `observe.points` and `observe.profile` code as
the training samples (`spare_twin.nets.profile_train`), whatever made the recording:

- several cameras with poses (a rig, fixed or not): every camera at one frame (default the middle one),
  because the object may move between frames;
- one camera (a hand-held sweep round a still object): up to `max_frames` of its frames, spread over
  the sweep; its poses from the recording where it has them (a tracked camera, a registered copy),
  otherwise registered here (`capture.registration.register_frames`), in memory: predict never
  writes into the user's recording.

Nothing reads the recording's object configuration or ground truth.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from spare_twin.capture.frames import load_frames
from spare_twin.capture.registration import RegistrationConfig, register_frames
from spare_twin.errors import SpareTwinError
from spare_twin.observe.points import ObjectPoints, PointsConfig, PosedView, object_candidates
from spare_twin.observe.profile import ChainProfile, ProfileConfig, chain_profile
from spare_twin.recording import Recording


@dataclass(frozen=True)
class ChainObservation:
    """What the yaw-free network is shown of a recording, and how it was made."""

    object: ObjectPoints
    profile: ChainProfile
    source: str
    """"cameras" (every posed camera at one frame), "sweep" (one camera's posed frames) or
    "sweep, registered" (one camera's frames, poses estimated here)."""
    views: int
    timings_s: dict = field(default_factory=dict)
    """"registration" and "observation" seconds."""

    @property
    def reason(self) -> str | None:
        """Why there is no chain to measure, or None."""
        return self.profile.reason

    @property
    def T_world_profile(self) -> np.ndarray:
        """The profile frame (base on the table, x = s, y = t, z up) in the recording's world."""
        return self.object.T_world_table @ self.profile.T_table_profile


def recording_views(
    rec: Recording,
    frame: int | None = None,
    camera: str | None = None,
    max_frames: int = 60,
    progress: bool = False,
) -> tuple[list[PosedView], str, float]:
    """(views, source, registration seconds) of a recording; see the module doc."""
    if frame is not None and not 0 <= frame < rec.n_frames:
        raise SpareTwinError(f"frame {frame}: the recording has frames 0..{rec.n_frames - 1}")
    posed = [c for c in rec.cameras if rec.camera_poses(c.name) is not None]
    if len(rec.cameras) > 1 and camera is None:
        if len(posed) < len(rec.cameras):
            raise SpareTwinError(f"{rec.root}: {len(rec.cameras) - len(posed)} of its cameras have no poses")
        f = rec.n_frames // 2 if frame is None else frame
        views = [
            PosedView(rec.depth_m(c.name, f), c.K, rec.T_world_camera(c.name, f), rec.color(c.name, f)) for c in posed
        ]
        return views, "cameras", 0.0
    cam = rec.camera(camera or rec.cameras[0].name)
    picks = np.unique(np.linspace(0, rec.n_frames - 1, min(max_frames, rec.n_frames)).round().astype(int)).tolist()
    poses = rec.camera_poses(cam.name)
    seconds = 0.0
    source = "sweep"
    if poses is None:
        if len(picks) < 2:
            raise SpareTwinError(f"{rec.root}: one frame and no camera pose; nothing to register")
        t0 = time.perf_counter()
        frames = load_frames(rec, cam.name, picks)
        poses_picked = register_frames(frames, RegistrationConfig(), None, progress).poses
        seconds = time.perf_counter() - t0
        source = "sweep, registered"
        views = [
            PosedView(fr.depth_u16.astype(np.float32) * np.float32(fr.depth_scale), cam.K, P, fr.color)
            for fr, P in zip(frames, poses_picked)
        ]
        return views, source, seconds
    views = [PosedView(rec.depth_m(cam.name, f), cam.K, poses[f], rec.color(cam.name, f)) for f in picks]
    return views, source, seconds


def find_chain(
    views: list[PosedView],
    print_scale: float,
    points_cfg: PointsConfig = PointsConfig(),
    profile_cfg: ProfileConfig = ProfileConfig(),
    max_candidates: int = 6,
) -> tuple[ObjectPoints, ChainProfile]:
    """(object, profile) of the first thing on the table, best first, that is a chain
    (`object_candidates`, `chain_profile`); when none is, the first with its reason. A box of
    clutter beside a thin chain holds more points than the chain: it is passed over, not measured."""
    candidates = object_candidates(views, points_cfg)[:max_candidates]
    first = None
    for obj in candidates:
        profile = chain_profile(obj, print_scale, profile_cfg)
        if profile.reason is None:
            return obj, profile
        first = first or (obj, profile)
    return first


def observe_chain(
    rec: Recording,
    print_scale: float,
    frame: int | None = None,
    camera: str | None = None,
    points_cfg: PointsConfig = PointsConfig(),
    profile_cfg: ProfileConfig = ProfileConfig(),
    progress: bool = False,
) -> ChainObservation:
    """The chain's observation in a recording (see the module doc)."""
    views, source, registration_s = recording_views(rec, frame, camera, progress=progress)
    t0 = time.perf_counter()
    obj, profile = find_chain(views, print_scale, points_cfg, profile_cfg)
    timings = {"registration": round(registration_s, 3), "observation": round(time.perf_counter() - t0, 3)}
    return ChainObservation(obj, profile, source, len(views), timings)
