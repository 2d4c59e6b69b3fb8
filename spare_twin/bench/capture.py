"""Drawing one object's recordings for the sim-to-real bench: the object, its capture with effects
(real), the same camera path through the nominal twin with no effect (sim through the capture's
cameras), the twin in the training rig (sim rig), and the truth they are scored on.

Captures go through a 7-Scenes folder and `capture import`, as a real capture does, so the recording
`predict` reads has no segmentation, no object configuration, no ground truth and no sign that it
was simulated; the poses it keeps (half of the captures) are the ones a tracker reports
(`pose_error`), moved into a table frame where the object stands off the origin.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
from pathlib import Path

import numpy as np

from spare_twin.bench.settings import BenchConfig, CaptureSettings
from spare_twin.capture.export import export_7scenes
from spare_twin.capture.importers import ImportOptions, import_folder
from spare_twin.config import ChainSpec, sample_chain
from spare_twin.object.folder import build_object
from spare_twin.object.kinematics import base_pose
from spare_twin.recording import Recording
from spare_twin.sim.effects import CaptureEffects
from spare_twin.sim.noise import load_noise
from spare_twin.sim.render import RenderConfig, render_recording

#: The sides every answer is scored on, in the table's column order.
SIDES = ("sim_rig", "sim_cameras", "real")
SIDE_TITLES = {"sim_rig": "sim rig", "sim_cameras": "sim, capture's cameras", "real": "real"}
#: Effects that move the camera rather than change what it sees: the clean render keeps them, so it
#: follows the capture's own camera path.
PATH_EFFECTS = ("hand",)


def clean_effects(effects: CaptureEffects) -> CaptureEffects:
    """The capture's effects less everything but its camera path (the same path, the nominal twin)."""
    return effects.only(name for name in PATH_EFFECTS if getattr(effects, name))


def build(d: Path, c: CaptureSettings) -> Path:
    """The printable object folder `d/object` of `c`'s chain."""
    return build_object(sample_chain(n_links=c.n_links, seed=c.seed), d / "object", preview=False, force=True).root


def _handheld(obj_dir: Path, out: Path, c: CaptureSettings, effects: CaptureEffects, noise: str, clutter: int) -> None:
    cfg = RenderConfig(
        path="handheld",
        frames=c.frames,
        seed=c.seed,
        resolution=c.resolution,
        noise=noise,
        hide_poses=c.hide_poses,
        sweep_deg=c.sweep_deg,
        clutter=clutter,
        effects=effects,
        renderer=c.renderer,
    )
    # the sensor's minimum range sets the path's distance (a Kinect is held farther off): a render
    # without that noise model is held as far, so it follows the same path
    sensor_path = cfg.handheld_path(load_noise(c.noise).min_range_m)
    if sensor_path != cfg.handheld_path(None):
        cfg = dataclasses.replace(cfg, distance_m=sensor_path.distance_m)
    render_recording(obj_dir, out, cfg, progress=False, force=True)


def _as_real(sensor: Path, out: Path, c: CaptureSettings) -> Path:
    """`sensor` (a simulation) brought in as a real capture at `out`: its 7-Scenes export imported
    back, with the poses it records (a tracker's: `pose_error` is in them) only where `c` keeps them."""
    scenes = out.parent / f"{out.name}_7scenes"
    export_7scenes(sensor, scenes, poses=False, force=True)
    if not c.hide_poses:
        T_table_sim = base_pose(c.world_x_m, c.world_y_m, math.radians(c.world_yaw_deg))
        rec = Recording.open(sensor)
        for t in range(rec.n_frames):
            T = rec.T_world_camera("cam0", t)
            np.savetxt(scenes / f"frame-{t:06d}.pose.txt", T_table_sim @ T, fmt="%.9f")
    import_folder(scenes, "7scenes", out, ImportOptions(fps=10.0, progress=False), force=True)
    shutil.rmtree(scenes)  # an intermediate: `out` holds the same frames
    return out


def draw_real(obj_dir: Path, d: Path, c: CaptureSettings, effects: CaptureEffects) -> Path:
    """The capture with `effects` (`d/sensor`: the raw simulation with its ground truth and the
    effects it drew; `d/real`: what `predict` reads)."""
    _handheld(obj_dir, d / "sensor", c, effects, c.noise, c.clutter)
    return _as_real(d / "sensor", d / "real", c)


def draw_sim_cameras(obj_dir: Path, d: Path, c: CaptureSettings, effects: CaptureEffects) -> Path:
    """The nominal twin along the capture's own camera path, same renderer, frames and resolution, with
    no noise, no clutter and no effect but the path's (`d/sim_cameras`), brought in the same way."""
    _handheld(obj_dir, d / "sim_cameras_sensor", c, clean_effects(effects), "none", 0)
    return _as_real(d / "sim_cameras_sensor", d / "sim_cameras", c)


def draw_sim_rig(obj_dir: Path, d: Path, c: CaptureSettings, cfg: BenchConfig) -> Path:
    """The twin in the training rig (`d/sim_rig`): what the networks were trained on."""
    render_recording(
        obj_dir,
        d / "sim_rig",
        RenderConfig(frames=cfg.sim_frames, seed=c.seed, resolution=cfg.sim_resolution),
        progress=False,
        force=True,
    )
    return d / "sim_rig"


def truth(obj_dir: Path, sensor: Path) -> dict:
    """The object's count and nominal lengths (paper units), and the joint angles it held in the capture."""
    gt = Recording.open(sensor).ground_truth()
    lengths = ChainSpec.from_json_file(obj_dir / "object.json").link_lengths_pu  # older folders' key too
    return {
        "n_links": int(gt["n_links"]),
        "link_lengths_pu": [float(v) for v in lengths],
        "joint_angles_rad": [float(v) for v in np.asarray(gt["joint_angles_rad"])[0]],
    }


def effects_drawn(sensor: Path) -> dict | None:
    """What the capture's effects drew, as its recording keeps them (`source.effects`)."""
    return Recording.open(sensor).source.get("effects")
