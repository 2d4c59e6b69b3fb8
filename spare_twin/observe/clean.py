"""Readings that are no surface, removed before anything is fused: flying pixels and floaters.

An active depth sensor reads, at a depth edge, depths between the foreground and the background
along the pixel's own ray (a mixed or "flying" pixel: docs/sensor_effects.md). Fused from a sweep,
they string a thin link's silhouette out behind it and ring every box and cylinder on the table with
a halo of points in the air; a centimetre's halo is enough to join a chain to the clutter beside it
into one thing "reaching 3 paper units from its base" (seed 30006 of the sim-to-real bench, a 1-link
chain among three cylinders: 2.68 paper units even with the true camera poses; with both tests, the
chain alone, counted and measured within 0.01 paper units). Two tests, each cheap:

1. **between two surfaces** (`between_surfaces`, one depth image at a time): a reading whose small
   neighbourhood holds a depth edge (nearest and farthest readings more than a few noise widths
   apart) and which lies clearly away from both ends of it is on no surface. The edge's own
   foreground and background readings are kept.
2. **seen through** (`seen_through`, across views): a point that other views see clearly past, along
   their own rays (their depth there, the least in a pixel's neighbourhood, is well beyond the point),
   is no surface. A surface point near another view's silhouette, placed a little off by its pose,
   is seen past by a view or two but agrees with the views that see it; so a point goes only where
   more views see past it than agree with it, and at least `min_views` do.

A shadow (no depth where the projector cannot see) casts no vote either way: fewer points, never
wrong ones. Deterministic: fixed view order, no random draws.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage


def depth_tolerance_m(depth_m: np.ndarray, base_m: float, per_m2: float) -> np.ndarray:
    """How far apart two readings of one surface may lie: `base_m` plus `per_m2` z^2 (structured
    light and active stereo both lose precision with the square of the distance)."""
    return base_m + per_m2 * np.square(depth_m)


def between_surfaces(depth_m: np.ndarray, radius_px: int, base_m: float, per_m2: float) -> np.ndarray:
    """bool (H, W): readings that lie between the nearest and the farthest reading of their
    (2 radius + 1)^2 neighbourhood, more than a tolerance (`depth_tolerance_m`) from both, where those
    two are more than three tolerances apart: a depth edge's flying pixels."""
    valid = depth_m > 0
    size = 2 * int(radius_px) + 1
    near = ndimage.minimum_filter(np.where(valid, depth_m, np.inf), size=size, mode="nearest")
    far = ndimage.maximum_filter(np.where(valid, depth_m, 0.0), size=size, mode="nearest")
    tol = depth_tolerance_m(depth_m, base_m, per_m2)
    return valid & (far - near > 3 * tol) & (depth_m - near > tol) & (far - depth_m > tol)


def seen_through(
    points_world: np.ndarray,
    depths: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
    base_m: float,
    per_m2: float,
    min_views: int,
) -> np.ndarray:
    """bool (N,): the points more views see past than agree with, and at least `min_views` see past
    (see the module doc). `depths`: per view (depth (H, W), K at that size, T_world_camera)."""
    past = np.zeros(len(points_world), np.int32)
    agree = np.zeros(len(points_world), np.int32)
    for depth, K, T_world_camera in depths:
        h, w = depth.shape
        T = np.linalg.inv(np.asarray(T_world_camera, np.float64))
        cam = points_world @ T[:3, :3].T + T[:3, 3]
        z = cam[:, 2]
        ahead = z > 1e-3
        u = np.full(len(z), -1, np.int64)
        v = np.full(len(z), -1, np.int64)
        u[ahead] = np.rint(K[0, 0] * cam[ahead, 0] / z[ahead] + K[0, 2]).astype(np.int64)
        v[ahead] = np.rint(K[1, 1] * cam[ahead, 1] / z[ahead] + K[1, 2]).astype(np.int64)
        inside = ahead & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        if not inside.any():
            continue
        idx = np.flatnonzero(inside)
        valid = depth > 0
        # the nearest reading round the pixel: a point is seen past only where the whole neighbourhood is
        nearest = ndimage.minimum_filter(np.where(valid, depth, np.inf), size=3, mode="nearest")
        seen = depth[v[idx], u[idx]]
        least = nearest[v[idx], u[idx]]
        tol = depth_tolerance_m(z[idx], base_m, per_m2)
        past[idx] += (np.isfinite(least) & (least > z[idx] + tol)).astype(np.int32)
        agree[idx] += ((seen > 0) & (np.abs(seen - z[idx]) <= tol)).astype(np.int32)
    return (past >= min_views) & (past > agree)
