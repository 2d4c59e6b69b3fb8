"""What the sim-to-real bench captures: its configuration (`BenchConfig`), the seeded table of
per-object capture settings (`capture_settings`), a pure function of the configuration, and whether a
run may start (`check_bench`). Light to import (no renderer, no torch): `spare-twin bench sim2real`
checks its options and its folder with it before it loads the stages (5 s of a new process).

Seed ranges (docs/sim2real.md keeps the list): object i is `sample_chain(n = i % 6 + 1, seed = seed + i)`.
7000-19023 were development and earlier held-out ranges of the project's own plain simulated sensor;
`BENCH_SEED` (30000) starts the first range drawn with every capture effect, held out: no dataset
(their chains take 63-bit seeds from `SeedSequence`), test, demo or tuning draws from 20000 up.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spare_twin.config import MAX_MOVING_LINKS
from spare_twin.errors import SpareTwinError
from spare_twin.output import check_output
from spare_twin.sim.choices import MAX_CLUTTER, RENDERERS
from spare_twin.sim.effects import ALL_EFFECTS, CaptureEffects
from spare_twin.sim.noise import load_noise
from spare_twin.validate import check_whole

#: The output kind of the bench's folder (`spare_twin.output`).
BENCH = "bench sim2real"
#: First object seed of the bench by default: the first range drawn with every effect (held out).
BENCH_SEED = 30000
#: Depth sensors of the captures, `NOISE:WxH`: the fitted SR300 and Kinect v1 noise models at their
#: 640 x 480 depth, and the D435's active stereo at its 848 x 480 (capture/rigs/noise_NAME.json).
SENSORS = ("realsense_sr300:640x480", "kinect_v1:640x480", "realsense_d435:848x480")
_SENSOR = re.compile(r"^([A-Za-z0-9_.\-/]+):(\d+)x(\d+)$")


def _whole(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def parse_sensor(text: str, param: str = "sensors") -> tuple[str, str]:
    """`NOISE:WxH` -> (noise model name, "WxH"); errors name `param`."""
    m = _SENSOR.match(str(text))
    if not m:
        raise SpareTwinError(f"{param} {text!r}: expected NOISE:WxH, e.g. realsense_d435:848x480")
    noise, w, h = m.group(1), int(m.group(2)), int(m.group(3))
    if not (16 <= w <= 4096 and 16 <= h <= 4096):
        raise SpareTwinError(f"{param} {text!r}: width and height must be within 16..4096")
    if noise == "none":
        raise SpareTwinError(f"{param} {text!r}: a simulated sensor capture needs a noise model")
    load_noise(noise, param=param)
    return noise, f"{w}x{h}"


@dataclass(frozen=True)
class BenchConfig:
    """What `bench_sim2real` captures and how (docs/sim2real.md)."""

    objects: int = 24
    """Objects; object i has n = i % 6 + 1 moving links (24: four per n)."""
    seed: int = BENCH_SEED
    """Seed of object 0 (object i: seed + i); also seeds the table of capture settings."""
    frames: tuple[int, int] = (15, 60)
    """Frame counts of the captures, spread evenly over this range."""
    sweep_deg: tuple[float, float] = (120.0, 360.0)
    """Arcs of the hand-held paths."""
    sensors: tuple[str, ...] = SENSORS
    """Depth sensors, `NOISE:WxH` each, spread evenly over the objects."""
    renderers: tuple[str, ...] = ("pybullet", "raycast")
    """Renderers of the captures, alternating within each n, so no figure rests on one renderer."""
    effects: CaptureEffects = ALL_EFFECTS
    """What a real print and sensor add (`spare_twin.sim.effects`): every effect on by default."""
    clutter_max: int = 4
    """Clutter items asked for: 0..clutter_max, spread evenly (the clutter effect adds its own)."""
    sim_frames: int = 10
    """Frames of the twin's recording in the training rig (the sim-rig side)."""
    sim_resolution: str = "record"

    def validate(self) -> None:
        """Errors name the parameter (the command says its flag)."""
        if not _whole(self.objects) or self.objects < 1:
            raise SpareTwinError(f"objects {self.objects!r}: need at least 1")
        if not _whole(self.seed) or self.seed < 0:
            raise SpareTwinError(f"seed {self.seed!r}: must be a non-negative integer")
        lo, hi = self.frames
        if not (_whole(lo) and _whole(hi) and 1 <= lo <= hi):
            raise SpareTwinError(f"frames {lo}-{hi}: need whole numbers 1 <= LO <= HI")
        lo, hi = self.sweep_deg
        if not (_number(lo) and _number(hi) and 30 <= lo <= hi <= 360):
            raise SpareTwinError(f"sweep_deg {lo:g}-{hi:g}: need 30 <= LO <= HI <= 360 degrees")
        if not self.sensors:
            raise SpareTwinError("sensors: give at least one NOISE:WxH")
        for s in self.sensors:
            parse_sensor(s)
        if not self.renderers:
            raise SpareTwinError("renderers: give at least one renderer")
        for r in self.renderers:
            if r not in RENDERERS:
                raise SpareTwinError(f"renderers {r!r}: expected one of {', '.join(RENDERERS)}")
        if not isinstance(self.effects, CaptureEffects):
            raise SpareTwinError(f"effects {self.effects!r}: must be a CaptureEffects")
        self.effects.validate("effects")
        if not _whole(self.clutter_max) or not 0 <= self.clutter_max <= MAX_CLUTTER:
            raise SpareTwinError(f"clutter_max {self.clutter_max!r}: must be a whole number, 0..{MAX_CLUTTER}")
        if not _whole(self.sim_frames) or self.sim_frames < 1:
            raise SpareTwinError(f"sim_frames {self.sim_frames!r}: must be a whole number, at least 1")

    def to_json(self) -> dict:
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        d["effects"] = self.effects.to_dict()
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


@dataclass(frozen=True)
class CaptureSettings:
    """How one object is captured by the simulated hand-held sensor."""

    name: str
    """The object's folder in the bench, `seed<S>`."""
    n_links: int
    seed: int
    """Seed of the chain and of its capture (path, held pose, noise, clutter, every effect's draws)."""
    sweep_deg: float
    frames: int
    noise: str
    resolution: str
    renderer: str
    clutter: int
    hide_poses: bool
    """Poses hidden (registration finds them); else kept as a tracker gives them (`pose_error`)."""
    world_x_m: float
    world_y_m: float
    world_yaw_deg: float
    """Where the object stands in the table frame of a capture that keeps its poses."""

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


def _spread(rng: np.random.Generator, values: list) -> list:
    """`values` in a random order: every value is used as often as the list says."""
    return [values[i] for i in rng.permutation(len(values))]


def capture_settings(cfg: BenchConfig) -> list[CaptureSettings]:
    """The seeded table of capture settings, one row per object: arcs, frame counts, sensors and
    clutter each spread evenly over their range and shuffled on their own, so no two go together by
    construction. Within each n, poses are hidden for every other object and the renderer changes every
    second one, so each n gets every combination of the two. A pure function of `cfg`."""
    cfg.validate()
    n_obj = cfg.objects
    rng = np.random.default_rng([cfg.seed, 0xBE7C])
    sweeps = _spread(rng, [round(float(v), 1) for v in np.linspace(*cfg.sweep_deg, n_obj)])
    frames = _spread(rng, [int(v) for v in np.linspace(*cfg.frames, n_obj).round()])
    sensors = _spread(rng, [parse_sensor(cfg.sensors[i % len(cfg.sensors)]) for i in range(n_obj)])
    clutter = _spread(rng, [i % (cfg.clutter_max + 1) for i in range(n_obj)])
    rows = []
    for i in range(n_obj):
        n, k = i % MAX_MOVING_LINKS + 1, i // MAX_MOVING_LINKS
        x, y = (float(v) for v in rng.uniform(-0.05, 0.05, 2).round(4))
        yaw = round(float(rng.uniform(0.0, 360.0)), 2)
        rows.append(
            CaptureSettings(
                name=f"seed{cfg.seed + i}",  # no count in the name: the capture's path tells predict nothing
                n_links=n,
                seed=cfg.seed + i,
                sweep_deg=sweeps[i],
                frames=frames[i],
                noise=sensors[i][0],
                resolution=sensors[i][1],
                renderer=cfg.renderers[(k // 2 + n - 1) % len(cfg.renderers)],
                clutter=clutter[i],
                hide_poses=(k + n - 1) % 2 == 1,
                world_x_m=x,
                world_y_m=y,
                world_yaw_deg=yaw,
            )
        )
    return rows


def check_bench(out: str | Path, cfg: BenchConfig, workers: int = 1, force: bool = False) -> list[CaptureSettings]:
    """`bench_sim2real(out, cfg, workers=workers, force=force)` may start: `cfg` is valid, `workers` at
    least 1, and `out` absent, empty or an earlier bench (`force` replaces anything else); else an error
    naming the parameter or the folder. Returns the capture settings (`capture_settings`)."""
    settings = capture_settings(cfg)
    check_whole("workers", workers)
    check_output(out, BENCH, (), force)
    return settings
