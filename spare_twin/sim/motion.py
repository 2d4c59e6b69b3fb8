"""Random smooth joint motion within the joint limits that keeps every link above the keep-out height.

Each joint follows a sum of a few random sinusoids (smooth, with velocities a person could move the
printed object at), mapped into its limits. Where a pose would dip a link into the foot / socket /
table, the whole pose is pulled towards the upright home pose by a factor alpha(t) in [0, 1]; alpha
is made smooth in time without ever exceeding the largest safe factor at any frame (a min-filter then
a shorter averaging window: an average of values that are each below alpha*(t) stays below it).
Links cannot collide with each other (each lies in its own layer along the joint axes), so the
keep-out height is the only constraint besides the limits.

The keep-out test is `kinematics.plate_lowest_point_m`, the same one the object's joint limits and
pose sampling use.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spare_twin.errors import SpareTwinError
from spare_twin.object.folder import ObjectFolder
from spare_twin.object.kinematics import plate_lowest_point_m as lowest_point_m


@dataclass(frozen=True)
class MotionConfig:
    """Parameters of the random joint motion."""

    n_frames: int = 100
    fps: float = 10.0
    n_waves: int = 3
    """Sinusoids summed per joint."""
    min_freq_hz: float = 0.03
    max_freq_hz: float = 0.25
    """Fastest component; at 10 fps this is 40 frames per period, smooth to the eye and the network."""
    amplitude: float = 0.9
    """Fraction of each joint's half-range the motion may use."""
    clearance_m: float = 0.002
    """Extra height kept above the keep-out when choosing the pull-back factor."""
    alpha_steps: int = 64
    smooth_radius_frames: int = 4


def random_motion(
    limits_rad: np.ndarray,
    lengths_m: np.ndarray,
    keepout_height_m: float,
    half_width_m: float,
    rng: np.random.Generator,
    cfg: MotionConfig = MotionConfig(),
) -> np.ndarray:
    """(n_frames, n) joint angles: smooth, within limits, every link above the keep-out height."""
    limits = np.asarray(limits_rad, dtype=np.float64).reshape(-1, 2)
    lengths = np.asarray(lengths_m, dtype=np.float64)
    n = len(limits)
    if len(lengths) != n + 1:
        raise SpareTwinError(f"motion: {n} joints need {n + 1} link lengths, got {len(lengths)}")
    home = np.clip(0.0, limits[:, 0], limits[:, 1])
    if lowest_point_m(home, lengths, half_width_m) < keepout_height_m:
        raise SpareTwinError("motion: the upright pose is already below the keep-out height")
    t = np.arange(cfg.n_frames) / cfg.fps
    freqs = rng.uniform(cfg.min_freq_hz, cfg.max_freq_hz, size=(n, cfg.n_waves))
    phases = rng.uniform(0, 2 * np.pi, size=(n, cfg.n_waves))
    amps = rng.uniform(0.2, 1.0, size=(n, cfg.n_waves))
    waves = (amps[:, :, None] * np.sin(2 * np.pi * freqs[:, :, None] * t + phases[:, :, None])).sum(1)
    waves /= amps.sum(1, keepdims=True)  # in [-1, 1]
    mid, half = limits.mean(1), (limits[:, 1] - limits[:, 0]) / 2
    raw = (mid[:, None] + cfg.amplitude * half[:, None] * waves).T  # (T, n), within limits

    # Largest safe pull-back factor per frame: safe for every grid value from 0 up to it.
    alphas = np.linspace(0.0, 1.0, cfg.alpha_steps + 1)
    poses = home + alphas[None, :, None] * (raw - home)[:, None, :]  # (T, A, n)
    ok = lowest_point_m(poses, lengths, half_width_m) >= keepout_height_m + cfg.clearance_m
    first_bad = np.where(ok.all(1), len(alphas), np.argmin(ok, axis=1))
    alpha_star = alphas[np.maximum(first_bad - 1, 0)]
    r = cfg.smooth_radius_frames
    padded = np.pad(alpha_star, 2 * r, mode="edge")
    mins = np.array([padded[i : i + 4 * r + 1].min() for i in range(len(alpha_star) + 2 * r)])
    kernel = np.hanning(2 * r + 3)[1:-1]
    alpha = np.convolve(mins, kernel / kernel.sum(), mode="valid")
    alpha = np.minimum(alpha, alpha_star)  # numerically a no-op; makes the guarantee explicit
    angles = home + alpha[:, None] * (raw - home)
    if (lowest_point_m(angles, lengths, half_width_m) < keepout_height_m).any():
        raise AssertionError("motion: a pose dips below the keep-out height")  # guarded above
    return angles


def object_motion(obj: ObjectFolder, rng: np.random.Generator, cfg: MotionConfig) -> np.ndarray:
    """`random_motion` for an object folder: its joint limits, physical link lengths and keep-out."""
    return random_motion(
        obj.joint_limits_rad, obj.printed_lengths_m, obj.keepout_height_m, obj.link_half_width_m, rng, cfg
    )
