"""Depth from one camera resampled into another camera's pixel grid (a RealSense's depth sensor into
its colour camera), after librealsense's `align`: each depth pixel's footprint, not its centre alone.

Each depth pixel is a small square on its surface: its two corners are carried into the other camera
and every pixel whose centre lies between them takes the depth (along the other camera's axis), the
nearest surface winning where several land. So a depth image of lower resolution leaves no holes in
a finer grid, and a surface hidden from the other camera is not painted over the one in front. Both
cameras are pinholes: lens distortion is left out, as it is everywhere downstream (a recording's
camera is its K). Two differences from librealsense, both measured on a synthetic D435-like bag
(tests/test_bag.py's geometry): it keeps the depth camera's z, 4.5 mm off along the colour camera's
axis there (median; here 0.23-0.29 mm), and it also fills the next row and column, which widens every
near surface by a pixel.
"""

from __future__ import annotations

import numpy as np

#: Widest footprint, in target pixels per axis, that one depth pixel may cover; a wider one is a
#: surface seen edge-on (or a depth far too close), cut to this to bound the work.
MAX_FOOTPRINT_PX = 4


def align_depth(
    depth_u16: np.ndarray,
    K_depth: np.ndarray,
    K_target: np.ndarray,
    T_target_depth: np.ndarray,
    target_size: tuple[int, int],
    depth_scale_m: float,
) -> np.ndarray:
    """`depth_u16` (sensor units, 0 = no reading) seen from the depth camera, as uint16 depth along the
    target camera's axis in the target's (width, height) grid. `T_target_depth` (4x4, metres) carries
    points from the depth camera's frame into the target's."""
    width, height = target_size
    out = np.full(height * width, np.iinfo(np.uint16).max, np.uint32)
    v, u = np.nonzero(depth_u16)
    if len(u):
        z_m = depth_u16[v, u].astype(np.float64) * depth_scale_m
        corners = [_project(u + d, v + d, z_m, K_depth, K_target, T_target_depth) for d in (-0.5, 0.5)]
        (u0, v0, z0), (u1, v1, z1) = corners
        z_target = np.rint(0.5 * (z0 + z1) / depth_scale_m)
        ahead = (z0 > 0) & (z1 > 0) & (z_target > 0) & (z_target < np.iinfo(np.uint16).max)
        # the target pixels whose centres lie in the square
        (u0, u1), (v0, v1) = (np.sort(np.stack([a[ahead], b[ahead]]), axis=0) for a, b in ((u0, u1), (v0, v1)))
        u0, v0 = np.ceil(u0).astype(np.int64), np.ceil(v0).astype(np.int64)
        u1, v1 = np.floor(u1).astype(np.int64), np.floor(v1).astype(np.int64)
        z_target = z_target[ahead]
        inside = (u1 >= 0) & (v1 >= 0) & (u0 < width) & (v0 < height)
        u0, v0, u1, v1, z_target = (a[inside] for a in (u0, v0, u1, v1, z_target))
        u0, v0 = np.maximum(u0, 0), np.maximum(v0, 0)
        u1, v1 = np.minimum(u1, width - 1), np.minimum(v1, height - 1)
        u1, v1 = np.minimum(u1, u0 + MAX_FOOTPRINT_PX - 1), np.minimum(v1, v0 + MAX_FOOTPRINT_PX - 1)
        z_target = z_target.astype(np.uint32)
        for dv in range(MAX_FOOTPRINT_PX):
            for du in range(MAX_FOOTPRINT_PX):
                hit = (u0 + du <= u1) & (v0 + dv <= v1)
                np.minimum.at(out, (v0[hit] + dv) * width + u0[hit] + du, z_target[hit])
    out[out == np.iinfo(np.uint16).max] = 0
    return out.astype(np.uint16).reshape(height, width)


def _project(u, v, z_m, K_from, K_to, T_to_from):
    """Pixels (u, v) at depth z in one camera -> (u, v, z) in the other."""
    x = (u - K_from[0, 2]) / K_from[0, 0] * z_m
    y = (v - K_from[1, 2]) / K_from[1, 1] * z_m
    p = T_to_from[:3, :3] @ np.stack([x, y, z_m]) + T_to_from[:3, 3:4]
    with np.errstate(divide="ignore", invalid="ignore"):
        return K_to[0, 0] * p[0] / p[2] + K_to[0, 2], K_to[1, 1] * p[1] / p[2] + K_to[1, 2], p[2]
