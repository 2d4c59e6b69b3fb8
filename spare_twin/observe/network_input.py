"""Any recording as an image network's input (`observe_recording`): where a Recording becomes what
a multi-view or temporal network trained on the rig's images reads (the yaw-free profile network reads
the chain's profile instead, `observe.chain`).

The recording's views are brought into the network's input space: 96 x 128, centre-cropped to the
4:3 aspect and resized, with the intrinsics adjusted to match (depth resized with nearest
neighbour, so no depth is invented at edges). A recording from the training rig is used as it is.
Any other recording is brought into the canonical object frame (base at the origin on the table, z up,
chain in x-z; see `spare_twin.observe.canonical`): networks that fuse posed views take the recording's
own views moved into that frame, the image networks see it re-rendered into the training rig
(`to_rig_views`). A real recording's object frame is known only up to a yaw hypothesis (a quarter
turn), so there is one input per hypothesis; `spare_twin.predict.images` keeps the most confident
output. Unregistered real recordings are registered in a temporary copy first.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spare_twin.capture.frames import fit_view
from spare_twin.config import DEFAULT_PRINT_SCALE
from spare_twin.errors import SpareTwinError
from spare_twin.observe.canonical import CanonicalConfig, CanonicalViews, object_frame, registered, to_rig_views
from spare_twin.recording import Recording


@dataclass(frozen=True)
class InputSpec:
    """What a network reads (the input side of its configuration)."""

    input: str = "depth"
    """"depth" (metres, 0 = no reading) or "grey" (in [0, 1])."""
    mode: str = "mv"
    """"mv": `frames` cameras at one time step; "tmp": `frames` time steps of one camera."""
    frames: int = 8
    height: int = 96
    width: int = 128
    posed: bool = False
    """The network fuses posed views (the geometry-aware voxel networks): it needs camera poses, and
    takes them from any cameras."""


@dataclass(frozen=True)
class NetworkInput:
    """One sample in the layout of docs/design.md ("Network sample"), without the batch axis."""

    x: np.ndarray
    """float32 (V, H, W): depth in metres (0 = no reading) or grey in [0, 1]."""
    K: np.ndarray
    """(C, 3, 3) intrinsics at H x W; C = V for mv, 1 for tmp (one camera)."""
    T_world_camera: np.ndarray
    """(C, 4, 4) camera-to-world, the identity where a pose is unknown."""
    print_scale: float
    """Physical metres per paper metre."""


@dataclass(frozen=True)
class Observation:
    """What a network is shown of a recording: one input per yaw hypothesis of the object frame."""

    inputs: tuple[NetworkInput, ...]
    yaws_rad: tuple[float, ...]
    method: str
    """"rig" (the recording is the training rig, or the model names none), "posed" (posed views in
    the canonical frame), "posed-given" (posed views in a given base frame), "fused" or "sim-views"
    (re-rendered into the training rig, see `to_rig_views`)."""


def print_scale_of(rec: Recording, print_scale: float | None = None) -> float:
    """`print_scale` if given, else the recording's object's, else the default."""
    if print_scale is not None:
        return float(print_scale)
    obj = rec.object_config or {}
    return float(obj.get("print_scale", DEFAULT_PRINT_SCALE))


def _view(rec: Recording, cam: str, frame: int, spec: InputSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    import cv2

    c = rec.camera(cam)
    if spec.input == "depth":
        img, K = fit_view(rec.depth_m(cam, frame), c.K, spec.height, spec.width, nearest=True)
    else:
        grey = cv2.cvtColor(rec.color(cam, frame), cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
        img, K = fit_view(grey, c.K, spec.height, spec.width, nearest=False)
    return img.astype(np.float32), K, rec.T_world_camera(cam, frame)


def _input(views: list, spec: InputSpec, print_scale: float) -> NetworkInput:
    """A NetworkInput from (image, K, T_world_camera or None) views."""
    Ks = np.stack([v[1] for v in views])
    Ts = np.stack([v[2] if v[2] is not None else np.eye(4) for v in views])
    if spec.mode == "tmp":  # one camera: its intrinsics and pose once
        Ks, Ts = Ks[:1], Ts[:1]
    return NetworkInput(np.stack([v[0] for v in views]).astype(np.float32), Ks, Ts, float(print_scale))


def recording_input(
    rec: Recording,
    spec: InputSpec,
    frame: int | None = None,
    camera: str | None = None,
    print_scale: float | None = None,
) -> NetworkInput:
    """The network input from a recording's own views, its world as it is: every camera at `frame`
    (mv, default the middle frame) or `spec.frames` frames of `camera` spread over the recording (tmp)."""
    if spec.mode == "mv":
        if len(rec.cameras) != spec.frames:
            raise SpareTwinError(
                f"{rec.root}: the network takes {spec.frames} views, the recording has {len(rec.cameras)} cameras"
            )
        frame = rec.n_frames // 2 if frame is None else frame
        views = [_view(rec, c.name, frame, spec) for c in rec.cameras]
    else:
        cam = camera or rec.cameras[0].name
        picks = np.linspace(0, rec.n_frames - 1, spec.frames).round().astype(int)  # resample to T frames
        views = [_view(rec, cam, int(f), spec) for f in picks]
        views = [(img, views[0][1], views[0][2]) for img, _, _ in views]
    if spec.posed and any(T is None for _, _, T in views):
        raise SpareTwinError(f"{rec.root}: camera poses unknown; run `spare-twin capture register` first")
    return _input(views, spec, print_scale_of(rec, print_scale))


def _posed_views(
    rec: Recording,
    spec: InputSpec,
    frame: int | None,
    camera: str | None,
    T_canonical_world: np.ndarray,
    camera_poses: dict | None = None,
) -> list:
    """spec.frames posed views for a network that fuses them, poses moved into the canonical frame:
    the recording's cameras at `frame` when it has that many posed ones, else frames of one camera
    spread over the recording (a hand-held sweep round a still object). `camera_poses` ({(camera,
    frame): T_world_camera}) overrides the recording's poses where it has them."""
    posed = [c for c in rec.cameras if c.poses != "unknown"]
    if not posed:
        raise SpareTwinError(f"{rec.root}: camera poses unknown; run `spare-twin capture register` first")
    if len(posed) == spec.frames:
        f = rec.n_frames // 2 if frame is None else frame
        picks = [(c.name, f) for c in posed]
    else:
        registered_camera = rec.registration.camera if rec.registration is not None else None
        cam = camera or registered_camera or posed[0].name
        picks = [(cam, int(f)) for f in np.linspace(0, rec.n_frames - 1, spec.frames).round()]
    views = []
    for cam, f in picks:
        img, K, T = _view(rec, cam, f, spec)
        T = (camera_poses or {}).get((cam, f), T)
        views.append((img, K, T_canonical_world @ T))
    return views


def _rig_input(cv: CanonicalViews, k: int, spec: InputSpec, camera: str | None, print_scale: float) -> NetworkInput:
    """The network input from yaw hypothesis k of the training rig's views."""
    imgs = cv.depth_m[k] if spec.input == "depth" else cv.grey[k]
    V = len(imgs)
    if spec.mode == "mv":
        if V != spec.frames:
            raise SpareTwinError(f"the network takes {spec.frames} views, its training rig has {V} cameras")
        views = [(imgs[i], cv.K[i], cv.T_world_camera[i]) for i in range(V)]
    else:
        # a fused recording is one still object: the temporal network sees one rig camera's view repeated
        i = int(camera[3:]) if camera and camera.startswith("cam") and camera[3:].isdigit() else 0
        if not 0 <= i < V:
            raise SpareTwinError(f"camera {camera}: the training rig has cameras cam0..cam{V - 1}")
        views = [(imgs[i], cv.K[i], cv.T_world_camera[i])] * spec.frames
    return _input(views, spec, print_scale)


def observe_recording(
    rec: Recording | str | Path,
    spec: InputSpec,
    training_rig: str | None,
    frame: int | None = None,
    camera: str | None = None,
    print_scale: float | None = None,
    workdir: str | Path | None = None,
    progress: bool = True,
    yaw_hypotheses: int = 4,
    T_world_base: np.ndarray | None = None,
    camera_poses: dict | None = None,
) -> Observation:
    """What a network trained on `training_rig` (None: any) is shown of a recording; methods:

    - "rig": the recording is the training rig (or the model does not name its rig): its own views;
    - "posed": networks that fuse posed views take them directly, in the canonical object frame (a
      simulation world as it is; a real recording registered, its poses moved by the inverse object
      pose of each yaw hypothesis of `canonical.object_frame`);
    - "fused" / "sim-views": other networks see `canonical.to_rig_views`;
    - "posed-given": `T_world_base` (the object's base pose in the recording's world, e.g. from
      articulated registration) is the canonical frame, for posed networks on posed recordings;
      `camera_poses` ({(camera, frame): T_world_camera}) may refine the recording's camera poses.
    """
    rec = rec if isinstance(rec, Recording) else Recording.open(rec)
    if frame is not None and not 0 <= frame < rec.n_frames:
        raise SpareTwinError(f"frame {frame}: the recording has frames 0..{rec.n_frames - 1}")
    ps = print_scale_of(rec, print_scale)
    cfg = CanonicalConfig(yaw_hypotheses=yaw_hypotheses)
    if training_rig is None or rec.rig == training_rig:
        return Observation((recording_input(rec, spec, frame, camera, print_scale),), (0.0,), "rig")
    if spec.posed and spec.mode == "mv":
        if T_world_base is not None:
            views = _posed_views(rec, spec, frame, camera, np.linalg.inv(T_world_base), camera_poses)
            return Observation((_input(views, spec, ps),), (0.0,), "posed-given")
        if rec.in_sim_world:
            if len(rec.cameras) == spec.frames:
                return Observation((recording_input(rec, spec, frame, camera, print_scale),), (0.0,), "posed")
            return Observation((_input(_posed_views(rec, spec, frame, camera, np.eye(4)), spec, ps),), (0.0,), "posed")
        with tempfile.TemporaryDirectory(dir=workdir) as tmp:
            reg = registered(rec, tmp, progress)
            obj = object_frame(reg, cfg)
            inputs = tuple(
                _input(_posed_views(reg, spec, frame, camera, np.linalg.inv(obj.T_world_canonical(k))), spec, ps)
                for k in range(len(obj.yaws_rad))
            )
        return Observation(inputs, obj.yaws_rad, "posed")
    if spec.posed and rec.in_sim_world and rec.camera(camera or rec.cameras[0].name).poses == "fixed":
        # a fixed camera in the canonical world: its own frames keep the motion the temporal net reads
        return Observation((recording_input(rec, spec, frame, camera, print_scale),), (0.0,), "posed")
    cv = to_rig_views(rec, training_rig, frame=frame, cfg=cfg, workdir=workdir, progress=progress)
    inputs = tuple(_rig_input(cv, k, spec, camera, ps) for k in range(len(cv.yaws_rad)))
    return Observation(inputs, cv.yaws_rad, cv.method)
