"""A hand-held camera path around the object: the twin simulation acting as a person with one RGB-D
camera walking around the printed object (the simulated sensor of `spare-twin render --path handheld`).

The camera circles the object once, or covers an arc of it (`sweep_deg`), while its distance, height
and aim wander slowly (sums of a few low-frequency sinusoids of the path parameter, so the path is
smooth whatever the frame count), it rolls a little as a hand does, and every frame adds a small
independent jitter (a shaky hand). Poses are camera-to-world, OpenCV axes, world z up with the
object's base at the origin. Everything is a pure function of (config, frame count, seed).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from spare_twin.errors import SpareTwinError
from spare_twin.sim.rig import axis_angle, look_at

#: The narrowest arc a hand-held path may cover (degrees): less sees one side of the object only.
MIN_SWEEP_DEG = 30.0


@dataclass(frozen=True)
class HandheldPath:
    """Where a hand-held camera goes around the object (metres, degrees)."""

    radius_m: float = 0.42
    """Mean horizontal distance from the object's vertical axis (the training rig's radius)."""
    radius_wander_m: float = 0.05
    """Peak slow change of that distance."""
    height_m: float = 0.26
    """Mean camera height above the table; a person looks down on an object on a table."""
    height_wander_m: float = 0.06
    look_at_m: tuple[float, float, float] = (0.0, 0.0, 0.09)
    """Mean point the camera aims at."""
    aim_wander_m: float = 0.015
    """Peak slow drift of the aim point (a person does not keep the object exactly centred)."""
    sweep_deg: float = 360.0
    """Azimuth covered over the whole path: 360 is one loop around the object (the last frame stops one
    step short of the first); a smaller arc runs from its first frame to its last exactly."""
    roll_deg: float = 4.0
    """Peak slow roll about the optical axis."""
    jitter_m: float = 0.002
    """Per-frame position jitter (std), a shaky hand."""
    jitter_deg: float = 0.3
    """Per-frame rotation jitter (std)."""
    n_waves: int = 3
    """Sinusoids per wandering quantity; frequencies 0.5..2 cycles over the path."""

    def __post_init__(self) -> None:
        if self.radius_m - self.radius_wander_m <= 0.05 or self.height_m - self.height_wander_m <= 0.0:
            raise SpareTwinError("handheld path: radius and height must stay positive (radius > 5 cm)")
        if self.n_waves < 1:
            raise SpareTwinError("handheld path: n_waves must be at least 1")
        if not MIN_SWEEP_DEG <= self.sweep_deg <= 360.0:
            raise SpareTwinError(f"sweep_deg {self.sweep_deg!r}: must be within {MIN_SWEEP_DEG:g}..360 degrees")

    def at_distance(self, distance_m: float) -> HandheldPath:
        """The same path with the camera `distance_m` from the mean aim point, at the same elevation
        (a sensor that sees nothing nearer than its minimum range is held farther away)."""
        dz = self.height_m - self.look_at_m[2]
        scale = distance_m / math.hypot(self.radius_m, dz)
        return dataclasses.replace(self, radius_m=self.radius_m * scale, height_m=self.look_at_m[2] + dz * scale)

    @property
    def distance_m(self) -> float:
        """Mean distance of the camera from the mean aim point."""
        return math.hypot(self.radius_m, self.height_m - self.look_at_m[2])


def _waves(rng: np.random.Generator, n_waves: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frequencies (0.5..2 cycles over the path), phases and amplitudes of one wandering quantity."""
    freqs = rng.uniform(0.5, 2.0, n_waves)
    phases = rng.uniform(0.0, 2 * math.pi, n_waves)
    amps = rng.uniform(0.5, 1.0, n_waves)
    return freqs, phases, amps


def _wave_sum(s: np.ndarray, freqs: np.ndarray, phases: np.ndarray, amps: np.ndarray) -> np.ndarray:
    v = (amps[:, None] * np.sin(2 * math.pi * freqs[:, None] * s[None] + phases[:, None])).sum(0)
    return v / amps.sum()


def _wander(rng: np.random.Generator, s: np.ndarray, n_waves: int) -> np.ndarray:
    """A smooth function of the path parameter s in [0, 1] with peak magnitude <= 1."""
    return _wave_sum(s, *_waves(rng, n_waves))


def handheld_poses(cfg: HandheldPath, n_frames: int, seed: int) -> np.ndarray:
    """(n_frames, 4, 4) camera-to-world poses along a seeded hand-held path."""
    if n_frames < 1:
        raise SpareTwinError("handheld path: needs at least one frame")
    rng = np.random.default_rng([seed, 0x4A4E])  # a stream of its own: the motion uses `seed` too
    # a full loop: s runs over [0, 1) so it never repeats its first view at the end; an arc: over [0, 1],
    # its first and last frames are the arc's ends
    full = cfg.sweep_deg >= 360.0
    s = np.arange(n_frames) / (n_frames if full or n_frames == 1 else n_frames - 1)
    az0 = rng.uniform(0.0, 2 * math.pi)
    # speed varies by up to +-15 % along the path, but azimuth stays monotonic and the wander is pinned
    # to 0 at s = 0 and s = 1, so the path covers exactly the asked sweep
    freqs, phases, amps = _waves(rng, cfg.n_waves)
    speed = _wave_sum(s, freqs, phases, amps)
    pin = _wave_sum(np.zeros(1), freqs, phases, amps)[0] * (1 - s) + _wave_sum(np.ones(1), freqs, phases, amps)[0] * s
    az = az0 + math.radians(cfg.sweep_deg) * (s + 0.15 / (2 * math.pi) * (speed - pin))
    radius = cfg.radius_m + cfg.radius_wander_m * _wander(rng, s, cfg.n_waves)
    height = cfg.height_m + cfg.height_wander_m * _wander(rng, s, cfg.n_waves)
    aim = np.asarray(cfg.look_at_m, float)[None] + cfg.aim_wander_m * np.stack(
        [_wander(rng, s, cfg.n_waves) for _ in range(3)], 1
    )
    roll = np.radians(cfg.roll_deg) * _wander(rng, s, cfg.n_waves)
    out = np.zeros((n_frames, 4, 4))
    for t in range(n_frames):
        eye = aim[t] * np.array([1.0, 1.0, 0.0]) + np.array(
            [radius[t] * math.cos(az[t]), radius[t] * math.sin(az[t]), height[t]]
        )
        T = look_at(eye, aim[t])
        R = T[:3, :3] @ axis_angle(np.array([0.0, 0.0, 1.0]), roll[t])  # roll about the optical axis
        axis = rng.normal(size=3)
        R = axis_angle(axis / np.linalg.norm(axis), math.radians(rng.normal(scale=cfg.jitter_deg))) @ R
        T[:3, :3] = R
        T[:3, 3] = eye + rng.normal(scale=cfg.jitter_m, size=3)
        out[t] = T
    return out
