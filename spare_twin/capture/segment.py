"""The object on the table: table plane (RANSAC), crop above it, DBSCAN clusters, the object frame.

The object frame has z up (the table normal, oriented towards the cameras), its origin on the table
(z = 0) under the centre of the object's footprint, and x along the footprint's longest axis
(PCA), so a printed chain standing on its base gets the same frame as in the twin simulation
(world z up, table z = 0) up to a rotation about z.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spare_twin.errors import SpareTwinError
from spare_twin.open3d_loader import quiet_open3d


@dataclass(frozen=True)
class SegmentConfig:
    """Object segmentation settings (metres)."""

    plane_distance_m: float = 0.006
    """RANSAC inlier distance of the table plane (sensor noise plus TSDF voxels)."""
    plane_iterations: int = 2000
    min_height_m: float = 0.008
    """points lower than this above the table belong to the table (noise, paper, cables)."""
    max_height_m: float = 0.6
    """the object is shorter than this (the printed chains fit a 200 mm bed)."""
    max_radius_m: float = 0.5
    """and stands within this distance of where the cameras look."""
    cluster_eps_m: float = 0.012
    """DBSCAN neighbourhood: above the voxel size, below the gap between object and clutter."""
    min_cluster_points: int = 50
    max_base_height_m: float = 0.03
    """the object's lowest point must be this close to the table (its base stands on it)."""
    seed: int = 0


@dataclass
class ObjectResult:
    points: np.ndarray
    """(N, 3) world-frame points of the object."""
    colors: np.ndarray
    T_world_object: np.ndarray
    """4x4: object frame (z up, origin on the table) to world."""
    table_plane: np.ndarray
    """(a, b, c, d) with a x + b y + c z + d = 0, unit normal pointing up (towards the cameras)."""
    height_m: float
    footprint_m: tuple[float, float]

    def summary(self) -> dict:
        return {
            "points": int(len(self.points)),
            "height_m": round(self.height_m, 4),
            "footprint_m": [round(v, 4) for v in self.footprint_m],
            "T_world_object": self.T_world_object.tolist(),
            "table_plane": self.table_plane.tolist(),
        }


def find_object(
    points: np.ndarray,
    colors: np.ndarray | None,
    camera_centers: np.ndarray,
    cfg: SegmentConfig = SegmentConfig(),
    source: str = "fused cloud",
    view_target: np.ndarray | None = None,
) -> ObjectResult:
    """Segment the object standing on the table; raises a one-line SpareTwinError naming `source`.

    `camera_centers` (M, 3): orient the table normal towards them. `view_target`: a point the cameras
    look at (default: the cloud's median), to pick the object among clusters.
    """
    o3d = quiet_open3d()

    points = np.asarray(points, np.float64)
    colors = np.full_like(points, 0.5) if colors is None else np.asarray(colors, np.float64)
    if len(points) < 100:
        raise SpareTwinError(f"{source}: no object found (only {len(points)} points)")
    o3d.utility.random.seed(cfg.seed)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    plane, inliers = pc.segment_plane(cfg.plane_distance_m, 3, cfg.plane_iterations)
    plane = np.asarray(plane, np.float64)
    plane /= np.linalg.norm(plane[:3])
    if np.mean(camera_centers @ plane[:3] + plane[3]) < 0:
        plane = -plane  # normal up = towards the cameras
    n = plane[:3]
    height = points @ n + plane[3]
    target = np.median(points, axis=0) if view_target is None else np.asarray(view_target, np.float64)
    target = target - (target @ n + plane[3]) * n  # onto the table
    lateral = (points - target) - np.outer((points - target) @ n, n)
    keep = (
        (height > cfg.min_height_m) & (height < cfg.max_height_m) & (np.linalg.norm(lateral, axis=1) < cfg.max_radius_m)
    )
    if keep.sum() < cfg.min_cluster_points:
        raise SpareTwinError(f"{source}: no object found above the table plane ({int(keep.sum())} points above it)")
    above = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[keep]))
    labels = np.asarray(above.cluster_dbscan(cfg.cluster_eps_m, cfg.min_cluster_points, print_progress=False))
    idx = np.flatnonzero(keep)
    best, best_score = None, -1.0
    for lab in range(labels.max() + 1 if labels.size else 0):
        members = idx[labels == lab]
        if height[members].min() > cfg.max_base_height_m:
            continue  # floating: not standing on the table (a hand, a lamp, another shelf)
        # many points near where the cameras look
        dist = np.linalg.norm(lateral[members].mean(axis=0))
        score = len(members) / (1.0 + dist / 0.1)
        if score > best_score:
            best, best_score = members, score
    if best is None:
        raise SpareTwinError(f"{source}: no object found standing on the table plane")
    obj = points[best]
    # object frame: z = n; x = principal axis of the footprint; origin = footprint centre on the table
    foot = obj - np.outer(obj @ n + plane[3], n)
    centre = foot.mean(axis=0)
    cov = np.cov((foot - centre).T)
    w, v = np.linalg.eigh(cov)
    x = v[:, -1] - (v[:, -1] @ n) * n
    x /= np.linalg.norm(x)
    y = np.cross(n, x)
    R = np.stack([x, y, n], axis=1)
    # centre of the footprint's bounding box in that frame (robust to uneven point density)
    local = (foot - centre) @ R
    lo, hi = local.min(axis=0), local.max(axis=0)
    centre = centre + R @ ((lo + hi) / 2 * np.array([1, 1, 0]))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, centre
    return ObjectResult(
        obj, colors[best], T, plane, float(height[best].max()), (float(hi[0] - lo[0]), float(hi[1] - lo[1]))
    )
