"""Render a twin-simulation recording of one object folder: the rig's fixed cameras or one hand-held
camera (a full loop or an arc), random (or held) joint motion, optional depth-sensor noise, optional
clutter on the table, or the same scene with no object at all; full ground truth.

`spare-twin render` is a thin adapter over `render_recording`; the simulated sensor capture
(`spare_twin.capture.simulated`) and the demo call it directly.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from spare_twin.config import ChainSpec
from spare_twin.errors import SpareTwinError
from spare_twin.object.folder import load_object
from spare_twin.object.kinematics import forward_kinematics, link_half_width_m, link_segment_m
from spare_twin.object.urdf import check_urdf
from spare_twin.recording import SIM_DEPTH_SCALE, Camera, RecordingWriter
from spare_twin.recording.format import MAX_FRAMES
from spare_twin.sim.choices import MAX_CLUTTER, RENDERERS
from spare_twin.sim.effects import NO_EFFECTS, CaptureEffects
from spare_twin.sim.handheld import MIN_SWEEP_DEG, HandheldPath, handheld_poses
from spare_twin.sim.motion import MotionConfig, object_motion
from spare_twin.sim.noise import load_noise
from spare_twin.sim.raycast import make_renderer
from spare_twin.sim.render_effects import EffectsRun
from spare_twin.sim.rig import Rig, load_rig
from spare_twin.sim.scene import add_clutter, sample_clutter
from spare_twin.validate import check_count, check_fits_memory

PATHS = ("rig", "handheld")
#: The source's sensor model of a render without a noise model, per renderer.
CLEAN_SENSOR_MODEL = {"pybullet": "pybullet-tinyrenderer", "raycast": "open3d-raycast"}
MOTIONS = ("moving", "static")


#: A hand-held sensor is held at least this many times its minimum range from the object.
MIN_RANGE_FACTOR = 1.3


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


@dataclass(frozen=True)
class RenderConfig:
    """How a twin-simulation recording is made."""

    rig: str = "spare8"
    """Rig name in capture/rigs/ or a rig JSON file."""
    frames: int = 100
    """Frames to record."""
    fps: float = 10.0
    """Frame rate."""
    seed: int = 0
    """Seed of the motion, the hand-held path and the sensor noise."""
    resolution: str = "record"
    """record (the rig's high resolution), network (96x128) or WxH (the rig's field of view)."""
    segmentation: bool = True
    """Write the link segmentation images."""
    path: str = "rig"
    """rig: the rig's fixed cameras; handheld: one camera carried round the object on a seeded path."""
    noise: str = "none"
    """Depth-sensor noise model capture/rigs/noise_NAME.json or a JSON file; none for clean depth."""
    motion: str | None = None
    """moving or static joints; None: moving for the rig, static for a hand-held path."""
    hide_poses: bool = False
    """handheld only: keep the camera poses only as ground truth (poses 'unknown'), as a real sensor does."""
    sweep_deg: float = 360.0
    """handheld only: azimuth the path covers (30..360 degrees; 360 = one loop round the object)."""
    distance_m: float | None = None
    """handheld only: mean camera distance from the aim point; None: arm's length (0.45 m), or 1.3 x the
    noise model's minimum range where that is farther (a Kinect v1 sees nothing nearer than 1 m)."""
    clutter: int = 0
    """Boxes and cylinders (2-12 cm, seeded sizes and colours) standing on the table 12..35 cm from the
    base axis, clear of the posed object: a desk, which segmentation has to remove."""
    empty: bool = False
    """The same scene (table, clutter, cameras, path) with no object on the table: ground truth says
    there is none (no n_links), segmentation is all background."""
    effects: CaptureEffects = NO_EFFECTS
    """What a real print and a real sensor add (joint play, shadows, flying pixels, ...): see
    `spare_twin.sim.effects`; none by default."""
    renderer: str = "pybullet"
    """pybullet (TinyRenderer) or raycast (open3d's ray caster on the object's meshes, independent of pybullet)."""

    def validate(self) -> None:
        check_count("frames", self.frames, MAX_FRAMES, "frame files are numbered with 6 digits")
        if not (isinstance(self.fps, (int, float)) and math.isfinite(self.fps) and self.fps > 0):
            raise SpareTwinError(f"fps {self.fps!r}: must be a positive number")
        if not _is_int(self.seed) or self.seed < 0:
            raise SpareTwinError(f"seed {self.seed!r}: must be a non-negative integer")
        if self.path not in PATHS:
            raise SpareTwinError(f"path {self.path!r}: expected one of {', '.join(PATHS)}")
        if self.motion is not None and self.motion not in MOTIONS:
            raise SpareTwinError(f"motion {self.motion!r}: expected one of {', '.join(MOTIONS)}")
        if self.hide_poses and self.path != "handheld":
            raise SpareTwinError("hide_poses: only for a hand-held path (a rig's cameras are calibrated)")
        if not (_is_number(self.sweep_deg) and MIN_SWEEP_DEG <= self.sweep_deg <= 360.0):
            raise SpareTwinError(f"sweep_deg {self.sweep_deg!r}: must be within {MIN_SWEEP_DEG:g}..360 degrees")
        if self.sweep_deg != 360.0 and self.path != "handheld":
            raise SpareTwinError("sweep_deg: only for a hand-held path (a rig's cameras stand still)")
        if self.distance_m is not None:
            if not (_is_number(self.distance_m) and 0.2 <= self.distance_m <= 3.0):
                raise SpareTwinError(f"distance_m {self.distance_m!r}: must be within 0.2..3 metres")
            if self.path != "handheld":
                raise SpareTwinError("distance_m: only for a hand-held path (the rig fixes its cameras)")
        if not _is_int(self.clutter) or not 0 <= self.clutter <= MAX_CLUTTER:
            raise SpareTwinError(f"clutter {self.clutter!r}: must be a whole number, 0..{MAX_CLUTTER}")
        if not isinstance(self.empty, bool):
            raise SpareTwinError(f"empty {self.empty!r}: must be true or false")
        if self.renderer not in RENDERERS:
            raise SpareTwinError(f"renderer {self.renderer!r}: expected one of {', '.join(RENDERERS)}")
        if not isinstance(self.effects, CaptureEffects):
            raise SpareTwinError(f"effects {self.effects!r}: must be a CaptureEffects")
        self.effects.validate("effects")

    def handheld_path(self, min_range_m: float | None = None) -> HandheldPath:
        """The hand-held path this configuration asks for; `min_range_m` is the sensor's minimum range."""
        path = HandheldPath(sweep_deg=float(self.sweep_deg))
        distance = self.distance_m
        if distance is None and min_range_m is not None and MIN_RANGE_FACTOR * min_range_m > path.distance_m:
            distance = MIN_RANGE_FACTOR * min_range_m
        return path if distance is None else path.at_distance(float(distance))


@dataclass(frozen=True)
class RenderResult:
    """What `render_recording` wrote."""

    recording: Path
    cameras: int
    frames: int
    width: int
    height: int
    n_links: int | None
    """Moving links of the object rendered; None for an empty table."""
    motion: str
    clutter: int = 0

    def to_json(self) -> dict:
        return {**dataclasses.asdict(self), "recording": str(self.recording)}


def parse_resolution(text: str, rig: Rig) -> tuple[int, int]:
    """(width, height) from record | network | WxH."""
    if text == "record":
        return rig.record_width, rig.record_height
    if text == "network":
        return rig.width, rig.height
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise SpareTwinError(f"resolution {text!r}: expected record, network or WxH (e.g. 640x480)") from None
    if not (16 <= w <= 4096 and 16 <= h <= 4096):
        raise SpareTwinError(f"resolution {text!r}: width and height must be within 16..4096")
    return w, h


def render_recording(
    object_dir: str | Path,
    out: str | Path,
    cfg: RenderConfig = RenderConfig(),
    progress: bool = True,
    force: bool = False,
) -> RenderResult:
    """Load the object's URDF in pybullet (or the raycast renderer), move its joints and record every camera into
    `out`, with the capture effects `cfg.effects` asks for.

    With `cfg.empty` the object folder still sets the scene (the motion drawn for it places the clutter
    clear of it, so the empty render is the same scene less the object) but is not put on the table.
    Everything is checked (the configuration, the object's meshes, the rig, the noise model, then the
    output path) before anything is written. `out` must be absent, empty or an earlier render; `force`
    replaces anything else, but never the object folder or a folder around it or inside it."""
    cfg.validate()
    obj = load_object(object_dir)
    # the motion and link poses of every frame are held in memory (a few kB a frame)
    check_fits_memory("frames", cfg.frames, (obj.spec.n_links + 12) * 16 * 8 * 2)
    if not cfg.empty:
        check_urdf(obj.urdf_path, obj.spec.n_links)  # before the output exists: pybullet may crash on a bad one
    rig = load_rig(cfg.rig)
    W, H = parse_resolution(cfg.resolution, rig)
    noise = load_noise(cfg.noise, param="noise")
    fx = EffectsRun(cfg.effects, cfg.seed, obj.spec, W, noise.sensor if noise else None, cfg.empty)
    K = fx.intrinsics(rig.K(W, H))
    angles = object_motion(
        obj,
        np.random.default_rng(cfg.seed),
        MotionConfig(n_frames=cfg.frames, fps=cfg.fps),
    )
    motion = cfg.motion or ("static" if cfg.path == "handheld" else "moving")
    if motion == "static":  # one pose of the seeded motion (so it respects limits and keep-out), held still
        angles = np.repeat(angles[len(angles) // 2][None], cfg.frames, axis=0)
    if cfg.path == "rig":
        poses = rig.poses()
        cameras = [Camera(name, W, H, K, poses[i]) for i, name in enumerate(rig.camera_names())]
        frame_poses = {c.name: np.repeat(c.T_world_camera[None], cfg.frames, axis=0) for c in cameras}
    else:
        path = fx.handheld_path(cfg.handheld_path(noise.min_range_m if noise else None))
        frame_poses = {"cam0": handheld_poses(path, cfg.frames, cfg.seed)}
        cameras = [Camera("cam0", W, H, K, None, "unknown" if cfg.hide_poses else "per_frame")]
    clutter = sample_clutter(  # a stream of its own: clutter never changes the motion, path or noise
        fx.clutter_config(cfg.clutter),
        np.random.default_rng([cfg.seed, 0xC1A7]),
        footprint_segments_xy_m(obj.spec, angles),
        link_half_width_m(obj.spec),
    )
    source = {
        "kind": "sim",
        "sensor_model": noise.sensor if noise else CLEAN_SENSOR_MODEL[cfg.renderer],
        "seed": cfg.seed,
        "geometry": "print",
        "near_m": rig.near_m,
        "far_m": rig.far_m,
        "path": cfg.path,
        "motion": motion,
        "noise": None if noise is None else noise.to_dict(),
    }
    if cfg.path == "handheld" and cfg.sweep_deg != 360.0:
        source["sweep_deg"] = float(cfg.sweep_deg)
    if clutter:
        source["clutter"] = clutter
    if cfg.empty:
        source["object"] = False  # the table without the object: nothing to find
    if cfg.renderer != "pybullet":
        source["renderer"] = cfg.renderer
    if fx.active:
        source["effects"] = fx.source()
    link_poses = np.zeros((cfg.frames, obj.spec.n_links + 1, 4, 4))
    depth_scale = noise.unit_m if noise else SIM_DEPTH_SCALE  # the sensor's own unit, as a real capture stores it
    # the rig and noise files read, when they are files (not names of shipped ones), are inputs too
    inputs = [object_dir, *(p for p in (cfg.rig, cfg.noise) if Path(p).is_file())]
    with (
        RecordingWriter(  # first: the output path is checked before pybullet starts
            out,
            cameras,
            cfg.frames,
            cfg.fps,
            source,
            depth_scale=depth_scale,
            object_config=None if cfg.empty else obj.spec.to_dict(),
            rig=rig.name if cfg.path == "rig" else None,
            kind="render",
            inputs=inputs,
            force=force,
        ) as rec,
        make_renderer(cfg.renderer) as twin,
        fx.object_folder(obj) as printed,  # obj itself unless joint play / print error perturb a copy
    ):
        if not cfg.empty:
            twin.load(printed)
        add_clutter(twin, clutter)
        no_labels = np.zeros((H, W), np.uint8)
        for t in tqdm(
            range(cfg.frames), unit="frame", file=sys.stderr, desc="render", dynamic_ncols=True, disable=not progress
        ):
            if not cfg.empty:
                twin.set_joints(angles[t])
                link_poses[t] = fx.link_poses(twin.link_poses())
            for v, cam in enumerate(cameras):
                T = frame_poses[cam.name][t]
                f = twin.render(T, K, W, H, rig.near_m, rig.far_m, segmentation=cfg.segmentation or fx.needs_labels)
                depth = fx.depth(f.depth_m, f.segmentation, K, v, t)
                if noise is not None:  # one stream per (seed, camera, frame): any subset re-renders identically
                    depth = noise.apply(depth, np.random.default_rng([cfg.seed, 0x5E, v, t]), f.depth_m)
                seg = f.segmentation if f.segmentation is not None or not cfg.segmentation else no_labels
                seg = seg if cfg.segmentation else None
                T_rec = fx.recorded_pose(T, t) if cam.poses == "per_frame" else None  # a tracker's, not the truth
                rec.add_frame(cam.name, t, f.rgb, depth, seg, T_world_camera=T_rec)
        gt = {}
        if not cfg.empty:
            gt = dict(
                joint_angles_rad=angles,
                T_world_link=link_poses,
                link_lengths_pu=np.asarray(obj.spec.link_lengths_pu),
                n_links=np.asarray(obj.spec.n_links),
                print_scale=np.asarray(obj.spec.print_scale),
                **fx.ground_truth(),
            )
        if cfg.path == "handheld":
            gt["T_world_camera"] = frame_poses["cam0"]  # true poses, also when the recording hides them
        if gt:
            rec.set_ground_truth(**gt)
    n_links = None if cfg.empty else obj.spec.n_links
    return RenderResult(Path(out), len(cameras), cfg.frames, W, H, n_links, motion, len(clutter))


def footprint_segments_xy_m(spec: ChainSpec, angles_rad: np.ndarray) -> np.ndarray:
    """(S, 2, 2) the links' centre lines seen from above, over every distinct pose of `angles_rad`
    (frames, n): where table clutter must not stand."""
    segs = []
    for a in np.unique(np.asarray(angles_rad, dtype=np.float64).reshape(len(angles_rad), -1), axis=0):
        T = forward_kinematics(spec, a)
        for k in range(spec.n_links + 1):
            z0, z1 = link_segment_m(spec, k)
            ends = T[k] @ np.array([[0.0, 0.0, z0, 1.0], [0.0, 0.0, z1, 1.0]]).T
            segs.append(ends[:2].T)
    return np.asarray(segs)
