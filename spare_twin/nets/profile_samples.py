"""Training and test samples of the yaw-free network, made the way real inputs are made.

A dataset sequence stores the training rig's 8 depth views per time step. A sample takes one time
step and turns it into what a hand-held capture of a printed object gives `predict`
(`CaptureAugment`):

- an arc: a run of 3..8 neighbouring rig cameras (90..360 deg of the ring), as a person walking part
  of the way round;
- the fitted noise of a real sensor (capture/rigs/noise_*.json), or none;
- registration error: each view's pose moved by a small random rigid motion, as a registration that
  is right to a few millimetres and a fraction of a degree;
- the whole world turned by any yaw, shifted along the table and tilted a little (the table frame
  must be found again, by the same code as for a real capture);
- clutter, where the dataset rendered it (`spare-twin dataset --sim2real`): the segmentation removes it.

Then exactly the `predict` path: `observe.chain.find_chain` (the points and the profile of the chain on
the table), the layer measurement (`measure.layers`) and the profile levelled by its layers' comb
(`measure.level`), which is what the network reads.
Labels: the count, the 7-slot lengths (paper units) and the joint angles with the sign of the profile
frame the observation chose (its x against the base link's x), so an observation that read the
layer order wrongly teaches the network nothing false.

Every sample is a pure function of (seed, dataset seed, sequence, time step, variant).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import h5py
import numpy as np

from spare_twin.config import MAX_MOVING_LINKS
from spare_twin.dataset.store import lengths_label_pu
from spare_twin.measure.layers import LayerMeasurement, measure_profile
from spare_twin.measure.level import levelled_image
from spare_twin.observe.chain import find_chain
from spare_twin.observe.points import PosedView
from spare_twin.observe.profile import ChainProfile, ProfileConfig
from spare_twin.sim.noise import load_noise


@dataclass(frozen=True)
class CaptureAugment:
    """How a rig time step is made to look like a hand-held capture (metres, degrees)."""

    min_cameras: int = 3
    """Fewest neighbouring rig cameras in an arc (8 = the whole ring)."""
    full_ring_prob: float = 0.25
    noise_models: tuple[str, ...] = ("realsense_sr300", "kinect_v1", "none")
    registration_prob: float = 0.7
    registration_rot_deg: float = 0.3
    """Per-view pose error, std of the rotation angle."""
    registration_trans_m: float = 0.0015
    """Per-view pose error, std per axis."""
    offset_m: float = 0.03
    """Std of the world's shift along the table."""
    tilt_deg: float = 2.0
    """Std of the world's tilt (the table is not assumed level in the world)."""


def _rotation(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle_rad) * K + (1 - math.cos(angle_rad)) * K @ K


def _small_motion(rng: np.random.Generator, rot_deg: float, trans_m: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = _rotation(rng.normal(size=3), math.radians(rng.normal(0.0, rot_deg)))
    T[:3, 3] = rng.normal(0.0, trans_m, 3)
    return T


def augmented_views(
    depth_m: np.ndarray, K: np.ndarray, T_world_camera: np.ndarray, aug: CaptureAugment, rng: np.random.Generator
) -> tuple[list[PosedView], np.ndarray]:
    """(views, G): a hand-held-like capture of one rig time step (`depth_m` (V, H, W) metres) and the
    world motion G applied to it (new world = G @ old world)."""
    V = len(depth_m)
    k = V if rng.random() < aug.full_ring_prob else int(rng.integers(min(aug.min_cameras, V), V + 1))
    start = int(rng.integers(0, V))
    cams = [(start + i) % V for i in range(k)]
    noise = load_noise(str(rng.choice(list(aug.noise_models))))
    if (
        noise is not None
    ):  # the fitted ranges are those of the fitting data (Kinect: >= 1 m); keep the noise, not the range
        noise = replace(noise, min_range_m=min(noise.min_range_m, 0.2), max_range_m=max(noise.max_range_m, 2.0))
    G = np.eye(4)
    G[:3, :3] = _rotation(np.array([0.0, 0.0, 1.0]), rng.uniform(0, 2 * math.pi))
    tilt_axis = np.array([*rng.normal(size=2), 0.0])
    G[:3, :3] = _rotation(tilt_axis, math.radians(rng.normal(0.0, aug.tilt_deg))) @ G[:3, :3]
    G[:2, 3] = rng.normal(0.0, aug.offset_m, 2)
    misregistered = rng.random() < aug.registration_prob
    views = []
    for c in cams:
        d = depth_m[c] if noise is None else noise.apply(depth_m[c], rng)
        T = G @ T_world_camera[c]
        if misregistered:
            T = T @ _small_motion(rng, aug.registration_rot_deg, aug.registration_trans_m)
        views.append(PosedView(d, K[c], T))
    return views, G


@dataclass(frozen=True)
class Sample:
    """One network sample: the network's input and its labels (or the observation's reason for none)."""

    profile: ChainProfile
    image: np.ndarray
    """float32 (C, H, W): the profile levelled by its layers' comb (`measure.level`), as `predict` draws it."""
    n_links: int
    lengths_pu: np.ndarray
    """float32 (7,): the paper's 7-slot label."""
    angles_rad: np.ndarray
    """float32 (6,): joint angles in the profile frame's sign, 0 past the last joint."""
    measurement: LayerMeasurement
    """The chain measured on the points (`spare_twin.measure.layers`)."""


def rig_sample(
    depth_m: np.ndarray,
    K: np.ndarray,
    T_world_camera: np.ndarray,
    T_world_base: np.ndarray,
    joints_rad: np.ndarray,
    n_links: int,
    lengths_label: np.ndarray,
    print_scale: float,
    aug: CaptureAugment | None,
    rng: np.random.Generator | None,
) -> Sample:
    """The sample of one rig time step; `aug` None: the rig's views as they are (the in-rig test)."""
    if aug is None:
        views, G = [PosedView(d, k, T) for d, k, T in zip(depth_m, K, T_world_camera)], np.eye(4)
    else:
        views, G = augmented_views(depth_m, K, T_world_camera, aug, rng)
    obj, profile = find_chain(views, print_scale)
    x_profile = (obj.T_world_table @ profile.T_table_profile)[:3, 0]
    x_base = (G @ T_world_base)[:3, 0]
    sign = 1.0 if x_profile @ x_base >= 0 else -1.0
    angles = np.zeros(MAX_MOVING_LINKS, np.float32)
    angles[:n_links] = sign * np.asarray(joints_rad[:n_links], np.float64)
    measurement = measure_profile(obj, profile, print_scale)
    image = levelled_image(obj, profile, measurement.comb_zero, print_scale, ProfileConfig())
    lengths = np.asarray(lengths_label, np.float32).reshape(7)
    return Sample(profile, image, int(n_links), lengths, angles, measurement)


def stored_sample(f: h5py.File, t: int, aug: CaptureAugment | None, rng: np.random.Generator | None) -> Sample:
    """`rig_sample` of time step `t` of an open dataset sequence (`spare_twin.dataset.store`)."""
    return rig_sample(
        f["depth"][:, t].astype(np.float32) * np.float32(f.attrs["depth_scale"]),
        f["K"][()],
        f["T_world_camera"][()],
        f["T_world_link"][t, 0],
        f["joint_angles_rad"][t],
        int(f.attrs["n_links"]),
        lengths_label_pu(f),
        float(f.attrs["print_scale"]),
        aug,
        rng,
    )
