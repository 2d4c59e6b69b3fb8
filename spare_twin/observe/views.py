"""Any recording as posed depth views: what the observation, the measurement and `predict` read.

`recording_views` reduces a recording folder to `PosedViews` in memory, whatever made it:

- several cameras with poses (a rig, fixed or not): every camera at one frame (default the middle one),
  because the object may move between frames;
- one camera (a hand-held sweep round a still object): up to `max_frames` of its frames, spread over
  the sweep, registered here (`capture.registration.register_frames`), in memory: predict never
  writes into the user's recording. Where the recording has poses (a tracked camera, a registered
  copy) they start the registration: a tracker's poses are each a few tenths of a degree and a few
  millimetres off, enough to blur a chain's 6.4 mm layers, so the frames' own matches place them
  (`TRACKED_REGISTRATION`); poses the frames agree with, and frames with too few readings to
  register, keep the poses as given.

Every view's flying pixels (readings between two surfaces at a depth edge) are dropped as it is read
(`observe.points.without_flying_pixels`), before registration or fusion sees them.

A live stream or a dataset builds `PosedViews` itself and goes through the same code from there on.
Nothing here reads the recording's object configuration or ground truth.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from spare_twin.capture.frames import RGBDFrame, load_frames
from spare_twin.capture.registration import RegistrationConfig, register_frames
from spare_twin.errors import SpareTwinError
from spare_twin.observe.chain import ChainObservation, observe_views
from spare_twin.observe.clean import between_surfaces
from spare_twin.observe.points import PointsConfig, PosedView, without_flying_pixels
from spare_twin.observe.profile import ProfileConfig
from spare_twin.recording import Recording
from spare_twin.threads import side_by_side

#: `PosedViews.source` of a sweep whose poses were registered here.
REGISTERED_SWEEP = "sweep, registered"
#: `PosedViews.source` of a sweep with its own (a tracker's) poses, registered here starting from them.
TRACKED_SWEEP = "sweep, registered from its tracker's poses"
#: How a tracked sweep is registered: its tracker's poses guess every pair and stand where a pair's
#: frames do not match, but are not weighed against the frames' matches (a reference weight of 0;
#: at 3 the tracker's own noise stays in the poses). On the 120 development captures with a
#: tracker's poses (seeds 20000-20023 and 30006-30221, every effect on): 116 right / 1 wrong / 3 no
#: answers, against 111 / 2 / 7 when the views were levelled and moved on the object from the
#: tracker's poses and registered again from their frames alone where that fit loosely (0.6.6), in
#: less time (11.7 s a capture against 12.4 s beside a second worker). Near-exact poses (a rig, a
#: robot arm) are kept as given (`TRACKED_AS_GIVEN`): registering them only adds ICP's small errors,
#: which add up over far, flat views (a clean 40-frame render at Kinect distance fused 0.13 mm off
#: its chain as given, 15 mm once registered). On the development set's 24 renders of seeds
#: 30198-30221 through the capture's cameras and its 12 tracked captures, the median disagreement of
#: a neighbouring pair's ICP edge with the given motion was 0.004-0.009 deg and 0.22-0.53 mm for
#: exact poses, 0.197-0.383 deg and 5.6-7.4 mm for the simulated tracker's: the limits sit between.
TRACKED_REGISTRATION = RegistrationConfig(reference_weight=0.0, keep_reference_within=(0.04, 0.0015))
#: `PosedViews.source` of a sweep whose own poses its frames confirm (`TRACKED_REGISTRATION`): read as given.
TRACKED_AS_GIVEN = "sweep, its own poses, confirmed by its frames"


@dataclass(frozen=True)
class PosedViews:
    """Depth views with camera-to-world poses, in memory: the input of `predict`'s core."""

    views: tuple[PosedView, ...]
    source: str
    """"cameras" (every posed camera at one frame), "sweep" (one camera's posed frames, as given),
    `TRACKED_SWEEP` (one camera's frames, registered here from its own poses) or `REGISTERED_SWEEP`
    (one camera's frames, registered here)."""
    registration_s: float = 0.0
    """Seconds spent estimating the poses."""
    frames: tuple[RGBDFrame, ...] | None = None
    """A sweep registered here without poses: its frames as read, so that a part of it can be
    registered on its own (`sweep_part`). A tracked sweep keeps none: its parts are not looked at."""
    frames_in_recording: int | None = None
    """How many frames the source has (a sweep's views are a sample of them)."""


def _without_flying_pixels(fr: RGBDFrame, cfg: PointsConfig = PointsConfig()) -> RGBDFrame:
    """The frame with its flying pixels dropped (`points.without_flying_pixels`), before registration
    matches it: a halo in the air round every edge is no surface to match."""
    if not cfg.remove_flying:
        return fr
    depth_m = fr.depth_u16.astype(np.float32) * np.float32(fr.depth_scale)
    flying = between_surfaces(depth_m, 2, cfg.depth_tolerance_m, cfg.depth_tolerance_per_m2)
    return RGBDFrame(fr.color, np.where(flying, np.uint16(0), fr.depth_u16), fr.depth_scale, fr.K)


def _posed(frames: list[RGBDFrame], poses) -> list[PosedView]:
    """Each frame as a view at its camera-to-world pose."""
    return [
        PosedView(fr.depth_u16.astype(np.float32) * np.float32(fr.depth_scale), fr.K, T, fr.color)
        for fr, T in zip(frames, poses)
    ]


def _registered(frames: list[RGBDFrame], progress: bool, tracked_poses=None) -> tuple[list[PosedView], float, bool]:
    """The frames as views at the poses registration gives them (from `tracked_poses` where given),
    the seconds that took, and whether `tracked_poses` were kept as given (the frames agree)."""
    t0 = time.perf_counter()
    if tracked_poses is None:
        reg = register_frames(frames, RegistrationConfig(), None, progress)
    else:
        reg = register_frames(frames, TRACKED_REGISTRATION, np.asarray(tracked_poses), progress)
    return _posed(frames, reg.poses), time.perf_counter() - t0, reg.reference_kept


def check_views_request(rec: Recording, frame: int | None, camera: str | None, max_frames: int = 60) -> None:
    """`recording_views`' refusals that need no frame read: a frame out of range, cameras without
    poses, an unknown camera, a frame number for a sweep, one frame without a pose. `predict` checks
    them before it sets its measuring process going (`predict.early`)."""
    if frame is not None and not 0 <= frame < rec.n_frames:
        raise SpareTwinError(f"frame {frame}: the recording has frames 0..{rec.n_frames - 1}")
    if len(rec.cameras) > 1 and camera is None:
        unposed = sum(rec.camera_poses(c.name) is None for c in rec.cameras)
        if unposed:
            raise SpareTwinError(f"{rec.root}: {unposed} of its cameras have no poses")
        return
    cam = rec.camera(camera or rec.cameras[0].name)
    if frame is not None:  # a sweep is read whole: a frame number would be silently ignored
        raise SpareTwinError(
            f"frame {frame}: applies to a recording from several posed cameras (every camera at that time "
            f"step); camera {cam.name} is read as a sweep, {min(max_frames, rec.n_frames)} of its frames"
        )
    if rec.camera_poses(cam.name) is None and min(max_frames, rec.n_frames) < 2:
        raise SpareTwinError(f"{rec.root}: one frame and no camera pose; nothing to register")


def recording_views(
    rec: Recording,
    frame: int | None = None,
    camera: str | None = None,
    max_frames: int = 60,
    progress: bool = False,
) -> PosedViews:
    """The posed views of a recording; see the module doc. `frame` applies to several posed cameras
    only, `camera` picks one camera to read as a sweep."""
    check_views_request(rec, frame, camera, max_frames)
    if len(rec.cameras) > 1 and camera is None:  # every camera posed (checked)
        f = rec.n_frames // 2 if frame is None else frame
        views = [
            without_flying_pixels(
                PosedView(rec.depth_m(c.name, f), c.K, rec.T_world_camera(c.name, f), rec.color(c.name, f))
            )
            for c in rec.cameras
        ]
        return PosedViews(tuple(views), "cameras", frames_in_recording=rec.n_frames)
    cam = rec.camera(camera or rec.cameras[0].name)
    picks = np.unique(np.linspace(0, rec.n_frames - 1, min(max_frames, rec.n_frames)).round().astype(int)).tolist()
    poses = rec.camera_poses(cam.name)
    frames = side_by_side(_without_flying_pixels, load_frames(rec, cam.name, picks))
    tracked = None if poses is None else tuple(np.asarray(poses[f], np.float64) for f in picks)
    try:
        views, seconds, kept = _registered(frames, progress, tracked)
    except SpareTwinError:
        if tracked is None:
            raise
        # frames with too little in them to match (a few dozen readings each): the poses stand as given
        return PosedViews(tuple(_posed(frames, tracked)), "sweep", frames_in_recording=rec.n_frames)
    if tracked is None:
        return PosedViews(tuple(views), REGISTERED_SWEEP, seconds, tuple(frames), rec.n_frames)
    source = TRACKED_AS_GIVEN if kept else TRACKED_SWEEP
    return PosedViews(tuple(views), source, seconds, frames_in_recording=rec.n_frames)


def sweep_part(seen: PosedViews, part: tuple[float, float], progress: bool = False) -> PosedViews:
    """A share of a sweep's frames (start, stop), e.g. (0.5, 1.0) its second half or (0, 1) the whole,
    registered on its own."""
    if seen.frames is None:
        raise ValueError("sweep_part: only a sweep read from a recording has its frames")
    n = len(seen.frames)
    start = int(part[0] * n)
    frames = list(seen.frames[start : max(int(np.ceil(part[1] * n)), start + 1)])
    views, seconds, _ = _registered(frames, progress)
    return PosedViews(tuple(views), REGISTERED_SWEEP, seconds, tuple(frames), seen.frames_in_recording)


def observe_chain(
    rec: Recording,
    print_scale: float,
    frame: int | None = None,
    camera: str | None = None,
    points_cfg: PointsConfig = PointsConfig(),
    profile_cfg: ProfileConfig = ProfileConfig(),
    progress: bool = False,
) -> ChainObservation:
    """The chain's observation in a recording folder: `recording_views`, then `observe_views`."""
    seen = recording_views(rec, frame, camera, progress=progress)
    return observe_views(list(seen.views), seen.source, seen.registration_s, print_scale, points_cfg, profile_cfg)
