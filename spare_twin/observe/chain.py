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

`measured_chain` adds the chain measured layer by layer (`observe.layers`) and, where a sweep
registered here gives none as a whole, brings its views into register on the object
(`observe.on_object`) and looks at parts of the sweep alone (see its doc).

Nothing reads the recording's object configuration or ground truth.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from spare_twin.capture.frames import load_frames
from spare_twin.capture.registration import RegistrationConfig, register_frames
from spare_twin.errors import SpareTwinError
from spare_twin.observe.layers import LayerMeasurement, measure_profile
from spare_twin.observe.on_object import register_on_object
from spare_twin.observe.points import ObjectPoints, PointsConfig, PosedView, object_candidates
from spare_twin.observe.profile import ChainProfile, ProfileConfig, chain_profile
from spare_twin.recording import Recording


@dataclass(frozen=True)
class ChainObservation:
    """What the yaw-free network is shown of a recording, and how it was made."""

    object: ObjectPoints
    profile: ChainProfile
    source: str
    """"cameras" (every posed camera at one frame), "sweep" (one camera's posed frames),
    "sweep, registered" (one camera's frames, poses estimated here) or `ON_OBJECT_SWEEP` (those views
    then brought into register on the object, `measured_chain`), the last two maybe naming a part."""
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


#: `recording_views`' source for a sweep whose poses it registered itself.
REGISTERED_SWEEP = "sweep, registered"
#: ... and `measured_chain`'s, once those views were brought into register on the object.
ON_OBJECT_SWEEP = "sweep, registered, brought into register on the object"


def recording_views(
    rec: Recording,
    frame: int | None = None,
    camera: str | None = None,
    max_frames: int = 60,
    progress: bool = False,
    part: tuple[float, float] = (0.0, 1.0),
) -> tuple[list[PosedView], str, float]:
    """(views, source, registration seconds) of a recording; see the module doc. `part`: the share of
    a sweep's frames to use (start, stop), e.g. (0.5, 1.0) its second half."""
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
    start = int(part[0] * len(picks))
    picks = picks[start : max(int(np.ceil(part[1] * len(picks))), start + 1)]
    poses = rec.camera_poses(cam.name)
    if poses is None:
        if len(picks) < 2:
            raise SpareTwinError(f"{rec.root}: one frame and no camera pose; nothing to register")
        t0 = time.perf_counter()
        frames = load_frames(rec, cam.name, picks)
        poses_picked = register_frames(frames, RegistrationConfig(), None, progress).poses
        views = [
            PosedView(fr.depth_u16.astype(np.float32) * np.float32(fr.depth_scale), cam.K, P, fr.color)
            for fr, P in zip(frames, poses_picked)
        ]
        return views, REGISTERED_SWEEP, time.perf_counter() - t0
    views = [PosedView(rec.depth_m(cam.name, f), cam.K, poses[f], rec.color(cam.name, f)) for f in picks]
    return views, "sweep", 0.0


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
    part: tuple[float, float] = (0.0, 1.0),
) -> ChainObservation:
    """The chain's observation in a recording (see the module doc); `part`: see `recording_views`."""
    views, source, registration_s = recording_views(rec, frame, camera, progress=progress, part=part)
    return _observe(views, source, registration_s, print_scale, points_cfg, profile_cfg)


def _observe(views, source, registration_s, print_scale, points_cfg=PointsConfig(), profile_cfg=ProfileConfig()):
    t0 = time.perf_counter()
    obj, profile = find_chain(views, print_scale, points_cfg, profile_cfg)
    timings = {"registration": round(registration_s, 3), "observation": round(time.perf_counter() - t0, 3)}
    return ChainObservation(obj, profile, source, len(views), timings)


#: Parts of a registered sweep looked at again when the whole gives no chain (`measured_chain`).
SWEEP_PARTS = ((0.0, 0.5), (0.5, 1.0), (0.25, 0.75))
#: Fewer registered frames than this are not split.
MIN_FRAMES_TO_SPLIT = 8
#: A part whose chain fits its points this well (RMS, metres) ends the search: the print's own
#: roughness and the sensor's noise leave 0.2-0.5 mm; a part still out of register leaves 5 mm and more.
CLEAN_PART_RMS_M = 0.002


def measured_chain(
    rec: Recording, print_scale: float, frame: int | None = None, camera: str | None = None, progress: bool = False
) -> tuple[ChainObservation, LayerMeasurement]:
    """`observe_chain` and its layer measurement (`observe.layers.measure_profile`); the observation's
    `timings_s` gain "measurement", all summed over the tries.

    A sweep registered here is measured with its views brought into register on the object
    (`observe.on_object`): views that slipped by a degree or a few millimetres along the table blur
    the chain's 6.4 mm layers (a 2-link RealSense sweep fused 14.9 mm RMS off any chain as registered,
    0.3 mm after). Where the views as registered give no chain at all (the fused object too wide, not
    standing on a 12 mm column, or blurred centimetres off any chain), the registration is off by more
    than the object can pull back somewhere, and the sweep's parts are looked at too: its first half,
    its second half and its middle half, each registered on its own and brought into register on the
    object. Registration errors come in runs: a sweep's views slide apart along the table where the
    object shows little (a Kinect at a metre and more), and the half without that run fuses into one
    chain; so does the half of a sweep before (or after) the object was bumped. The try whose chain
    fits its points best (lowest RMS) is kept; one within `CLEAN_PART_RMS_M` ends the search. A
    recording with its own poses, one frame or a rig is looked at once: its views are placed as given."""
    views, source, registration_s = recording_views(rec, frame, camera, progress=progress)
    as_registered = _measure(_observe(views, source, registration_s, print_scale), print_scale)
    if source != REGISTERED_SWEEP:
        return as_registered
    seen, measured = _on_object(views, registration_s, print_scale)
    seconds = _add(seen.timings_s, as_registered[0].timings_s, but="registration")
    if as_registered[1].n_links is not None or len(views) < MIN_FRAMES_TO_SPLIT:
        best = (seen, measured) if measured.n_links is not None else as_registered
        return dataclasses.replace(best[0], timings_s=seconds), best[1]
    why = "the whole did not fuse into one chain"
    best = None
    if measured.n_links is not None:
        best = (dataclasses.replace(seen, source=f"{seen.source}: {why}"), measured)
    for part in SWEEP_PARTS:
        if best is not None and best[1].rms_m <= CLEAN_PART_RMS_M:
            break
        part_views, _, part_registration_s = recording_views(rec, frame, camera, progress=progress, part=part)
        piece, m = _on_object(part_views, part_registration_s, print_scale)
        seconds = _add(seconds, piece.timings_s)
        if m.n_links is not None and (best is None or m.rms_m < best[1].rms_m):
            share = f"frames {100 * part[0]:.0f}-{100 * part[1]:.0f} % of the sweep"
            best = (dataclasses.replace(piece, source=f"{piece.source}, {share}: {why}"), m)
    seen, measured = best or as_registered
    return dataclasses.replace(seen, timings_s=seconds), measured


def _on_object(views: list[PosedView], registration_s: float, print_scale: float):
    """(observation, measurement) of registered views brought into register on the object
    (`observe.on_object`); the time that takes is registration, after `registration_s` spent before."""
    t0 = time.perf_counter()
    on_object = register_on_object(views)
    registration_s += time.perf_counter() - t0
    return _measure(_observe(on_object, ON_OBJECT_SWEEP, registration_s, print_scale), print_scale)


def _add(a: dict, b: dict, but: str | None = None) -> dict:
    """Per-step seconds of two tries summed (`but`: that step's from `a` alone)."""
    return {k: round(a[k] + (0.0 if k == but else b[k]), 3) for k in a}


def _measure(seen: ChainObservation, print_scale: float) -> tuple[ChainObservation, LayerMeasurement]:
    t0 = time.perf_counter()
    if seen.reason is not None:
        measured = LayerMeasurement(None, None, None, ())
    else:
        measured = measure_profile(seen.object, seen.profile, print_scale)
    timings = {**seen.timings_s, "measurement": round(time.perf_counter() - t0, 3)}
    return dataclasses.replace(seen, timings_s=timings), measured
