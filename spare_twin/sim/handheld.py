"""A hand-held camera path around the object: the twin simulation acting as a person with one RGB-D
camera walking around the printed object (the simulated sensor of `spare-twin render --path handheld`).

The camera circles the object once (azimuth sweep), while its distance, height and aim wander slowly
(sums of a few low-frequency sinusoids of the path parameter, so the path is smooth whatever the frame
count), it rolls a little as a hand does, and every frame adds a small independent jitter (a shaky
hand). Poses are camera-to-world, OpenCV axes, world z up with the object's base at the origin.
Everything is a pure function of (config, frame count, seed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from spare_twin.errors import SpareTwinError
from spare_twin.sim.rig import axis_angle, look_at


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
    """Azimuth covered over the whole path (one loop around the object)."""
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


def _wander(rng: np.random.Generator, s: np.ndarray, n_waves: int) -> np.ndarray:
    """A smooth function of the path parameter s in [0, 1] with peak magnitude <= 1."""
    freqs = rng.uniform(0.5, 2.0, n_waves)
    phases = rng.uniform(0.0, 2 * math.pi, n_waves)
    amps = rng.uniform(0.5, 1.0, n_waves)
    v = (amps[:, None] * np.sin(2 * math.pi * freqs[:, None] * s[None] + phases[:, None])).sum(0)
    return v / amps.sum()


def handheld_poses(cfg: HandheldPath, n_frames: int, seed: int) -> np.ndarray:
    """(n_frames, 4, 4) camera-to-world poses along a seeded hand-held path."""
    if n_frames < 1:
        raise SpareTwinError("handheld path: needs at least one frame")
    rng = np.random.default_rng([seed, 0x4A4E])  # a stream of its own: the motion uses `seed` too
    # s runs over [0, 1) so a full 360 deg loop never repeats its first view at the end
    s = np.arange(n_frames) / n_frames
    az0 = rng.uniform(0.0, 2 * math.pi)
    # speed varies by up to +-15 % around the loop but azimuth stays monotonic
    az = az0 + math.radians(cfg.sweep_deg) * (s + 0.15 / (2 * math.pi) * _wander(rng, s, cfg.n_waves))
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
