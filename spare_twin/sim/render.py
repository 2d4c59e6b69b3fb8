"""Render a twin-simulation recording of one object folder: the rig's fixed cameras or one hand-held
camera, random (or held) joint motion, optional depth-sensor noise, full ground truth.

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

from spare_twin.errors import SpareTwinError
from spare_twin.object.folder import load_object
from spare_twin.recording import SIM_DEPTH_SCALE, Camera, RecordingWriter
from spare_twin.sim.handheld import HandheldPath, handheld_poses
from spare_twin.sim.motion import MotionConfig, object_motion
from spare_twin.sim.noise import load_noise
from spare_twin.sim.rig import Rig, load_rig
from spare_twin.sim.twin import Twin

PATHS = ("rig", "handheld")
MOTIONS = ("moving", "static")


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


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

    def validate(self) -> None:
        if not _is_int(self.frames) or self.frames < 1:
            raise SpareTwinError(f"frames {self.frames!r}: must be a whole number, at least 1")
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


@dataclass(frozen=True)
class RenderResult:
    """What `render_recording` wrote."""

    recording: Path
    cameras: int
    frames: int
    width: int
    height: int
    n_links: int
    motion: str

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
    """Load the object's URDF in pybullet, move its joints and record every camera into `out`.

    Everything is checked (the configuration, the object's meshes, the rig, the noise model, then the
    output path) before anything is written. `out` must be absent, empty or an earlier render; `force`
    replaces anything else, but never the object folder or a folder around it or inside it."""
    cfg.validate()
    obj = load_object(object_dir)
    rig = load_rig(cfg.rig)
    W, H = parse_resolution(cfg.resolution, rig)
    noise = load_noise(cfg.noise, param="noise")
    K = rig.K(W, H)
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
        frame_poses = {"cam0": handheld_poses(HandheldPath(), cfg.frames, cfg.seed)}
        cameras = [Camera("cam0", W, H, K, None, "unknown" if cfg.hide_poses else "per_frame")]
    source = {
        "kind": "sim",
        "sensor_model": noise.sensor if noise else "pybullet-tinyrenderer",
        "seed": cfg.seed,
        "geometry": "print",
        "near_m": rig.near_m,
        "far_m": rig.far_m,
        "path": cfg.path,
        "motion": motion,
        "noise": None if noise is None else noise.to_dict(),
    }
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
            object_config=obj.spec.to_dict(),
            rig=rig.name if cfg.path == "rig" else None,
            kind="render",
            inputs=inputs,
            force=force,
        ) as rec,
        Twin() as twin,
    ):
        twin.load(obj)
        for t in tqdm(
            range(cfg.frames), unit="frame", file=sys.stderr, desc="render", dynamic_ncols=True, disable=not progress
        ):
            twin.set_joints(angles[t])
            link_poses[t] = twin.link_poses()
            for v, cam in enumerate(cameras):
                T = frame_poses[cam.name][t]
                f = twin.render(T, K, W, H, rig.near_m, rig.far_m, segmentation=cfg.segmentation)
                depth = f.depth_m
                if noise is not None:  # one stream per (seed, camera, frame): any subset re-renders identically
                    depth = noise.apply(depth, np.random.default_rng([cfg.seed, 0x5E, v, t]))
                rec.add_frame(
                    cam.name, t, f.rgb, depth, f.segmentation, T_world_camera=T if cam.poses == "per_frame" else None
                )
        gt = dict(
            joint_angles_rad=angles,
            T_world_link=link_poses,
            link_lengths_m=np.asarray(obj.spec.link_lengths_pu),
            n_links=np.asarray(obj.spec.n_links),
            print_scale=np.asarray(obj.spec.print_scale),
        )
        if cfg.path == "handheld":
            gt["T_world_camera"] = frame_poses["cam0"]  # true poses, also when the recording hides them
        rec.set_ground_truth(**gt)
    return RenderResult(Path(out), len(cameras), cfg.frames, W, H, obj.spec.n_links, motion)
