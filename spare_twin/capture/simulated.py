"""A simulated-sensor capture of a "printed" object, brought in the way a real one is.

The object's twin is recorded by one hand-held camera with the depth-sensor noise model fitted to
real frames and its poses hidden (`render_recording` on a hand-held path), written out as
a 7-Scenes folder and read back by `capture import`, then registered by `capture register` (camera
poses, TSDF fusion, the object on the table). Everything downstream sees only what a real capture
gives. The printed configuration (joint angles, lengths; not the camera poses) is kept with the
imported recording as its ground truth, so `compare` can score joint-angle estimates.

The demo uses it for one object; `spare-twin bench sim2real` for many unseen ones.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spare_twin.capture.export import export_7scenes
from spare_twin.capture.importers import ImportOptions, import_folder
from spare_twin.capture.pipeline import register_recording
from spare_twin.capture.registration import RegistrationConfig
from spare_twin.recording import Recording
from spare_twin.sim.effects import NO_EFFECTS, CaptureEffects
from spare_twin.sim.render import RenderConfig, render_recording

#: The ground-truth arrays of the simulation that describe the object, not the sensor's path.
OBJECT_TRUTH = ("joint_angles_rad", "link_lengths_pu", "n_links", "print_scale")


@dataclass(frozen=True)
class SensorCaptureConfig:
    """How the simulated hand-held capture is made and registered."""

    frames: int = 40
    """One loop round the object: 9 degrees between frames keeps neighbouring views overlapping
    enough for ICP (16 frames, 22.5 degrees apart, registered 6-20 degrees off)."""
    resolution: str = "320x240"
    noise: str = "realsense_sr300"
    """Depth-sensor noise model, capture/rigs/noise_NAME.json."""
    loop_gaps: str = "2"
    """Loop edges for registration: enough to close the drift of a 40-frame sweep, few enough to be quick."""
    seed: int = 0
    """The hand-held path and the sensor noise."""
    effects: CaptureEffects = NO_EFFECTS
    """What a real print and a real sensor add (`spare_twin.sim.effects`; `parse_effects("all")` for
    every one); none by default, the capture the project was developed on."""
    renderer: str = "pybullet"
    """pybullet or raycast (open3d's ray caster: an independent renderer of the same capture)."""


def simulated_capture(
    object_dir, out_dir, cfg: SensorCaptureConfig = SensorCaptureConfig(), step=None, progress: bool = True
) -> Path:
    """Record, export, import and register; returns the registered recording (`out_dir/real`).

    Writes `out_dir/sensor_capture` (the raw simulation, true poses in its ground truth),
    `out_dir/sensor_capture_7scenes` and `out_dir/real`. `step(what)` is called before each stage."""
    step = step or (lambda what: None)
    out_dir = Path(out_dir)
    sensor = out_dir / "sensor_capture"
    step("simulated sensor: a hand-held RealSense-like camera around the printed object")
    render_recording(
        object_dir,
        sensor,
        RenderConfig(
            path="handheld",
            noise=cfg.noise,
            hide_poses=True,
            resolution=cfg.resolution,
            frames=cfg.frames,
            seed=cfg.seed,
            effects=cfg.effects,
            renderer=cfg.renderer,
        ),
        progress=progress,
    )

    step("import: the capture as a 7-Scenes folder, read back as a real capture is")
    # out_dir is this function's: its intermediate folders are replaced whatever an earlier run left
    export_7scenes(sensor, out_dir / "sensor_capture_7scenes", poses=False, force=True)
    real = out_dir / "real"
    import_folder(
        out_dir / "sensor_capture_7scenes", "7scenes", real, ImportOptions(fps=10.0, progress=progress), force=True
    )
    truth = Recording.open(sensor).ground_truth()
    Recording.open(real).write_ground_truth({k: np.asarray(truth[k]) for k in OBJECT_TRUTH})

    step("register: camera poses, TSDF fusion, the object on the table")
    register_recording(
        real,
        RegistrationConfig(loop_gaps_frames=tuple(int(g) for g in cfg.loop_gaps.split(","))),
        find="require",
        progress=progress,
    )
    return real
