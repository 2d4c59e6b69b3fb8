"""A simulated-sensor capture of a "printed" object, brought in the way a real one is.

The object's twin is recorded by one hand-held camera with the depth-sensor noise model fitted to
real frames and its poses hidden (`render --path handheld --noise ... --hide-poses`), written out as
a 7-Scenes folder and read back by `capture import`, then registered by `capture register` (camera
poses, TSDF fusion, the object on the table). Everything downstream sees only what a real capture
gives. The printed configuration (joint angles, lengths; not the camera poses) is kept with the
imported recording as its ground truth, so `compare` can score joint-angle estimates.

The demo uses it for one object; `spare-twin bench sim2real` for many unseen ones.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: The ground-truth arrays of the simulation that describe the object, not the sensor's path.
OBJECT_TRUTH = ("joint_angles_rad", "link_lengths_m", "n_links", "print_scale")


@dataclass(frozen=True)
class SensorCaptureConfig:
    """How the simulated hand-held capture is made and registered."""

    frames: int = 40
    """One loop round the object: 9 degrees between frames keeps neighbouring views overlapping
    enough for ICP (16 frames, 22.5 degrees apart, registered 6-20 degrees off)."""
    resolution: str = "320x240"
    noise: str = "realsense_sr300"
    """Depth-sensor noise model, capture/rigs/noise_NAME.json."""
    loop_gaps: str = "2,4,8,16"
    """Loop edges for registration: enough to close the drift of a 40-frame sweep, few enough to be quick."""
    seed: int = 0
    """The hand-held path and the sensor noise."""


def run_cli(argv: list[str]) -> None:
    """Run a spare-twin command in-process, its stdout sent to stderr (callers print their own)."""
    from contextlib import redirect_stdout

    from spare_twin import SpareTwinError
    from spare_twin.cli import main

    with redirect_stdout(sys.stderr):
        code = main(argv)
    if code:
        raise SpareTwinError(f"`spare-twin {' '.join(argv)}` failed (exit {code})")


def simulated_capture(object_dir, out_dir, cfg: SensorCaptureConfig = SensorCaptureConfig(), step=None) -> Path:
    """Record, export, import and register; returns the registered recording (`out_dir/real`).

    Writes `out_dir/sensor_capture` (the raw simulation, true poses in its ground truth),
    `out_dir/sensor_capture_7scenes` and `out_dir/real`. `step(what)` is called before each stage."""
    from spare_twin.capture.export import export_7scenes
    from spare_twin.io import write_bytes_atomic
    from spare_twin.recording import Recording, _npz_bytes

    step = step or (lambda what: None)
    out_dir = Path(out_dir)
    sensor = out_dir / "sensor_capture"
    step("simulated sensor: a hand-held RealSense-like camera around the printed object")
    run_cli(["render", str(object_dir), "--out", str(sensor), "--path", "handheld", "--noise", cfg.noise,
             "--hide-poses", "--resolution", cfg.resolution, "--frames", str(cfg.frames), "--seed", str(cfg.seed)])

    step("import: the capture as a 7-Scenes folder, read back by `capture import`")
    export_7scenes(sensor, out_dir / "sensor_capture_7scenes", poses=False)
    real = out_dir / "real"
    run_cli(["capture", "import", str(out_dir / "sensor_capture_7scenes"), "--layout", "7scenes", "--out", str(real), "--fps", "10"])
    truth = Recording.open(sensor).ground_truth()
    write_bytes_atomic(real / "ground_truth.npz", _npz_bytes({k: np.asarray(truth[k]) for k in OBJECT_TRUTH}))

    step("register: camera poses, TSDF fusion, the object on the table")
    run_cli(["capture", "register", str(real), "--object", "require", "--loop-gaps", cfg.loop_gaps])
    return real
