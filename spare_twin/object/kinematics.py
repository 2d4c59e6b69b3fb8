"""Forward kinematics and joint limits of the planar SPARE chain (physical metres, z up).

The same joint layout is written into the URDF, so these functions and any URDF loader agree.
"""

from __future__ import annotations

import math

import numpy as np

from spare_twin.config import ChainSpec

JOINT_AXIS = np.array([0.0, 1.0, 0.0])
#: Links keep this far above the foot's socket (metres), so the printed object never touches it.
KEEPOUT_MARGIN_M = 0.002


def printed_lengths_m(spec: ChainSpec) -> np.ndarray:
    """(n + 1,) link lengths of the printed object (physical metres), base first."""
    return np.asarray(spec.link_lengths_pu, dtype=np.float64) * spec.print_scale


def link_half_width_m(spec: ChainSpec) -> float:
    """Half the width of a link plate (physical metres): the radius of its rounded ends."""
    return spec.parts.link_width_mm / 2000.0


def joint_origin(spec: ChainSpec, k: int) -> np.ndarray:
    """4x4 origin of joint k (1..n) in link k-1's frame (metres)."""
    T = np.eye(4)
    T[1, 3] = spec.layer_pitch_mm / 1000.0
    T[2, 3] = printed_lengths_m(spec)[k - 1]
    return T


def rot_y(angle_rad: float) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    T = np.eye(4)
    T[0, 0], T[0, 2], T[2, 0], T[2, 2] = c, s, -s, c
    return T


def base_pose(x_m: float, y_m: float, yaw_rad: float) -> np.ndarray:
    """4x4 pose of a base standing on the table (z = 0): at (x, y), turned by yaw about z."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:2, 3] = x_m, y_m
    return T


def param_bounds(limits_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) of a fit's parameter vector (base x, y, yaw unbounded, then the joint limits)."""
    limits_rad = np.asarray(limits_rad, dtype=np.float64)
    return (np.concatenate([[-np.inf] * 3, limits_rad[:, 0]]), np.concatenate([[np.inf] * 3, limits_rad[:, 1]]))


def forward_kinematics(spec: ChainSpec, joint_angles_rad, T_world_base: np.ndarray | None = None) -> np.ndarray:
    """(n + 1, 4, 4) poses of links 0..n in the world frame."""
    angles = np.asarray(joint_angles_rad, dtype=np.float64).reshape(-1)
    if angles.shape != (spec.n_links,):
        raise ValueError(f"expected {spec.n_links} joint angles, got {angles.shape}")
    out = np.empty((spec.n_links + 1, 4, 4))
    out[0] = np.eye(4) if T_world_base is None else T_world_base
    for k in range(1, spec.n_links + 1):
        out[k] = out[k - 1] @ joint_origin(spec, k) @ rot_y(angles[k - 1])
    return out


def keepout_height_m(spec: ChainSpec) -> float:
    """Height of the foot's socket top: moving links must stay above it (plus a margin)."""
    return (spec.parts.foot_thickness_mm + spec.parts.socket_height_mm) / 1000.0


def link_segment_m(spec: ChainSpec, k: int) -> tuple[float, float]:
    """The centre line of link k's plate in its own frame, as (start, end) along +z, metres.

    The plate is this segment thickened by half the link width (a stadium).
    """
    length = float(printed_lengths_m(spec)[k])
    if k == spec.n_links:  # last link: the tip is at `length`, so the rounded end's centre is inside
        return 0.0, max(length - link_half_width_m(spec), 0.0)
    return 0.0, length


def plate_lowest_point_m(angles_rad, lengths_m, half_width_m: float) -> np.ndarray:
    """Lowest height of any moving link's plate for poses (..., n) -> (...).

    Closed form of the planar chain (joint k turns about +y, so a link at cumulative angle phi runs
    along (sin phi, 0, cos phi)): each plate is the segment between its axes thickened by half the
    width; the last link's segment ends half a width before its tip.
    """
    angles = np.asarray(angles_rad, dtype=np.float64)
    lengths = np.asarray(lengths_m, dtype=np.float64)
    segment = lengths[1:].copy()
    segment[-1] = max(segment[-1] - half_width_m, 0.0)
    dz = np.cos(np.cumsum(angles, axis=-1)) * lengths[1:]
    axes = lengths[0] + np.concatenate([np.zeros(dz.shape[:-1] + (1,)), np.cumsum(dz, axis=-1)[..., :-1]], axis=-1)
    ends = axes + np.cos(np.cumsum(angles, axis=-1)) * segment
    return np.minimum(axes, ends).min(axis=-1) - half_width_m


def lowest_point_m(spec: ChainSpec, joint_angles_rad) -> float:
    """Lowest height reached by any moving link's plate at these joint angles."""
    return float(plate_lowest_point_m(joint_angles_rad, printed_lengths_m(spec), link_half_width_m(spec)))


def joint_limits_rad(spec: ChainSpec) -> np.ndarray:
    """(n, 2) limits. Links share no layer, so only joint 1 needs a limit: link 1 must clear the foot.

    Deeper joints can turn all the way round; whether the whole chain clears the table at a given
    pose depends on every angle, which motion planning checks with `lowest_point_m`.
    """
    limits = np.tile([-math.pi, math.pi], (spec.n_links, 1))
    _, reach = link_segment_m(spec, 1)
    axis_height = float(printed_lengths_m(spec)[0])
    floor = keepout_height_m(spec) + KEEPOUT_MARGIN_M + link_half_width_m(spec)
    if reach > 0 and axis_height - reach < floor:
        # The distal end dips to axis_height + reach * cos(angle); keep it above the floor.
        limit = math.acos(max(-1.0, min(1.0, (floor - axis_height) / reach)))
        limits[0] = (-limit, limit)
    return limits


def is_clear_of_foot(spec: ChainSpec, joint_angles_rad) -> bool:
    return lowest_point_m(spec, joint_angles_rad) >= keepout_height_m(spec) + KEEPOUT_MARGIN_M


def sample_pose(spec: ChainSpec, rng: np.random.Generator, max_tries: int = 1000) -> np.ndarray:
    """Uniform joint angles within the limits whose links all clear the foot (rejection sampling)."""
    limits = joint_limits_rad(spec)
    for _ in range(max_tries):
        angles = rng.uniform(limits[:, 0], limits[:, 1])
        if is_clear_of_foot(spec, angles):
            return angles
    return np.zeros(spec.n_links)  # standing straight up always clears the foot
