"""Points splatted into a camera: z-buffered discs over the analytic table the twin stands on, so
that a fused (or back-projected) object cloud looks like the twin's own renders at the network's
resolution (see `spare_twin.observe.canonical`)."""

from __future__ import annotations

import math

import numpy as np

from spare_twin.open3d_loader import quiet_open3d

#: The twin's table (spare_twin.sim.twin.Twin): a 1 m square top at z = 0 centred on the base.
TABLE_HALF_SIZE_M = 0.5
#: Grey (BT.601 luma in [0, 1]) of that table under the twin's default Lighting, and of the empty
#: background (TinyRenderer clears to white), as measured on renders (tests/test_canonical.py checks both).
TABLE_GREY = 120 / 255
BACKGROUND_GREY = 1.0


def point_spacing_m(points: np.ndarray) -> float:
    """Median nearest-neighbour distance (the cloud's sampling step)."""
    o3d = quiet_open3d()

    if len(points) < 2:
        return 0.004
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    return float(np.median(np.asarray(pc.compute_nearest_neighbor_distance())))


def table_view(K: np.ndarray, T_world_camera: np.ndarray, height: int, width: int) -> np.ndarray:
    """float32 (H, W) z-depth of the table top (z = 0, |x|, |y| <= TABLE_HALF_SIZE_M), 0 elsewhere."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)  # z = 1
    R, t = T_world_camera[:3, :3], T_world_camera[:3, 3]
    dz = rays @ R[2]  # world z change per unit of camera z
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -t[2] / dz  # camera z-depth where the ray meets z = 0
    hit = (dz < 0) & (s > 0)
    xy = t[:2] + s[..., None] * (rays @ R[:2].T)
    hit &= (np.abs(xy) <= TABLE_HALF_SIZE_M).all(-1)
    return np.where(hit, s, 0.0).astype(np.float32)


def splat(
    points: np.ndarray,
    grey: np.ndarray,
    K: np.ndarray,
    T_world_camera: np.ndarray,
    height: int,
    width: int,
    spacing_m: float,
    *,
    radius_rel: float,
    max_px: int,
    fill_min_neighbours: int,
) -> tuple[np.ndarray, np.ndarray]:
    """z-buffered disc splats: (depth float32 (H, W), 0 = none; grey float32 (H, W)). Disc radius
    `radius_rel` x `spacing_m` (at most `max_px` pixels); then `fill_small_holes` with
    `fill_min_neighbours` (the settings are CanonicalConfig's)."""
    T_cw = np.linalg.inv(T_world_camera)
    pc = points @ T_cw[:3, :3].T + T_cw[:3, 3]
    front = pc[:, 2] > 0.02
    pc, g = pc[front], grey[front]
    z = pc[:, 2]
    u = K[0, 0] * pc[:, 0] / z + K[0, 2]
    v = K[1, 1] * pc[:, 1] / z + K[1, 2]
    # a disc whose world radius is a fraction of the spacing, seen at depth z; at least the own pixel
    r_px = np.maximum(radius_rel * spacing_m * K[0, 0] / z, 0.5)
    R = int(min(max_px, math.ceil(r_px.max()))) if len(z) else 0
    ui, vi = np.rint(u).astype(np.int64), np.rint(v).astype(np.int64)
    idx, zs, gs = [], [], []
    for dy in range(-R, R + 1):
        for dx in range(-R, R + 1):
            sel = (dx * dx + dy * dy <= r_px * r_px) | ((dx == 0) & (dy == 0))
            x, y = ui[sel] + dx, vi[sel] + dy
            ok = (x >= 0) & (x < width) & (y >= 0) & (y < height)
            idx.append((y * width + x)[ok])
            zs.append(z[sel][ok])
            gs.append(g[sel][ok])
    idx, zs, gs = np.concatenate(idx), np.concatenate(zs), np.concatenate(gs)
    zbuf = np.full(height * width, np.inf)
    np.minimum.at(zbuf, idx, zs)
    # grey: mean over the samples on the visible surface (within a splat's depth of the nearest)
    front = zs <= zbuf[idx] + max(2.0 * spacing_m, 0.004)
    n = np.bincount(idx[front], minlength=height * width)
    gsum = np.bincount(idx[front], weights=gs[front], minlength=height * width)
    depth = np.where(np.isfinite(zbuf), zbuf, 0.0).reshape(height, width)
    gimg = np.where(n > 0, gsum / np.maximum(n, 1), 0.0).reshape(height, width)
    depth, gimg = fill_small_holes(depth, gimg, fill_min_neighbours)
    return depth.astype(np.float32), gimg.astype(np.float32)


def fill_small_holes(depth: np.ndarray, grey: np.ndarray, min_neighbours: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixels without a reading but with >= min_neighbours of their 8 neighbours read get their mean
    (gaps between splats, not the outline: an outline pixel has at most 5 neighbours inside)."""
    import cv2

    valid = (depth > 0).astype(np.float64)
    k = np.ones((3, 3))
    cnt = cv2.filter2D(valid, -1, k, borderType=cv2.BORDER_CONSTANT)
    dsum = cv2.filter2D(depth * valid, -1, k, borderType=cv2.BORDER_CONSTANT)
    gsum = cv2.filter2D(grey * valid, -1, k, borderType=cv2.BORDER_CONSTANT)
    fill = (valid == 0) & (cnt >= min_neighbours)
    depth, grey = depth.copy(), grey.copy()
    depth[fill] = dsum[fill] / cnt[fill]
    grey[fill] = gsum[fill] / cnt[fill]
    return depth, grey
