"""Articulated registration: the URDF twin's base pose and joint angles that best explain a point cloud.

The cloud is in the object frame the capture tools produce (metres, z up, table at z = 0). The twin
stands on the table, so its base pose has three degrees of freedom (x, y, yaw); together with the n
joint angles these are found by

1. a global search: for each yaw on a grid, the chain is posed link by link, each joint angle picked
   from a grid by how well that link's surface lands on the cloud (the chain is a tree, so this greedy
   pass is exact when the cloud is complete and a good start when it is not);
2. a robust least-squares refinement of all parameters on two-sided point distances (every observed
   point near the twin's surface, and the twin's surface near observed points).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from spare_twin import SpareTwinError
from spare_twin.kinematics import forward_kinematics, joint_limits_rad, joint_origin, keepout_height_m, rot_y
from spare_twin.objects import ObjectFolder

#: Distances beyond this count as "not explained" (metres): robust to clutter and fusion noise.
TRUNCATE_M = 0.01
#: How far below the foot's keep-out height a surface sample may fall during the search (sampling slack).
KEEPOUT_TOLERANCE_M = 0.002


@dataclass(frozen=True)
class FitConfig:
    """Search and refinement settings for `fit_articulated`."""

    points_per_link: int = 400
    """Surface samples per link of the twin."""
    max_cloud_points: int = 3000
    yaw_steps: int = 24
    angle_step_deg: float = 5.0
    search_points_per_link: int = 120
    """Surface samples per link during the global search (a subset, for speed)."""
    refine_hypotheses: int = 2
    """How many of the best global-search poses to refine."""
    seed: int = 0


@dataclass(frozen=True)
class ArticulatedFit:
    T_world_base: np.ndarray
    """4x4 pose of the twin's base (link 0) in the cloud's frame."""
    joint_angles_rad: np.ndarray
    """(n,) joint angles."""
    rmse_m: float
    """Root mean square distance from the cloud to the posed twin's surface (truncated)."""
    inlier_fraction: float
    """Share of cloud points within 5 mm of the posed twin."""


def twin_link_meshes(obj: ObjectFolder) -> list:
    """Each link's printed parts as one trimesh in that link's frame (metres), read through the URDF:
    its visual STL files placed by their visual origins."""
    import trimesh

    from spare_twin.urdf import load_urdf

    links = {l.name: l for l in load_urdf(obj.urdf_path).robot.links}
    out = []
    for k in range(obj.spec.n_links + 1):
        meshes = []
        for visual in links[f"link{k}"].visuals:
            mesh = trimesh.load(obj.root / visual.geometry.mesh.filename, file_type="stl")
            mesh.apply_scale(1e-3)
            mesh.apply_transform(visual.origin)
            meshes.append(mesh)
        out.append(trimesh.util.concatenate(meshes))
    return out


def twin_surface_points(obj: ObjectFolder, per_link: int, seed: int = 0) -> list[np.ndarray]:
    """Surface samples of every link's printed parts, in that link's frame (metres)."""
    import trimesh

    rng = np.random.default_rng(seed)
    out = []
    for mesh in twin_link_meshes(obj):
        pts, _ = trimesh.sample.sample_surface(mesh, per_link, seed=int(rng.integers(2**31)))
        out.append(np.asarray(pts, dtype=np.float64))
    return out


def base_pose(x: float, y: float, yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:2, 3] = x, y
    return T


def _posed(spec, link_points, params) -> np.ndarray:
    poses = forward_kinematics(spec, params[3:], base_pose(*params[:3]))
    return np.vstack([pts @ T[:3, :3].T + T[:3, 3] for pts, T in zip(link_points, poses)])


def _truncated(d: np.ndarray) -> np.ndarray:
    return np.minimum(d, TRUNCATE_M)


def fit_articulated(obj: ObjectFolder, points_world: np.ndarray, config: FitConfig = FitConfig()) -> ArticulatedFit:
    spec = obj.spec
    points = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) < 50:
        raise SpareTwinError(f"articulated registration needs an object cloud, got {len(points)} points")
    rng = np.random.default_rng(config.seed)
    if len(points) > config.max_cloud_points:
        points = points[rng.choice(len(points), config.max_cloud_points, replace=False)]
    cloud = cKDTree(points)
    link_points = twin_surface_points(obj, config.points_per_link, config.seed)
    limits = joint_limits_rad(spec)

    # The foot is centred on the post: the low points give the base position.
    low = points[points[:, 2] < keepout_height_m(spec)]
    x0, y0 = np.median(low if len(low) >= 20 else points, axis=0)[:2]

    keepout = keepout_height_m(spec)
    hypotheses = []
    for yaw in _yaw_candidates(points, spec, config.yaw_steps):
        params = np.array([x0, y0, yaw, *np.zeros(spec.n_links)])
        T_parent = base_pose(x0, y0, yaw)
        unexplained = _unexplained(points, link_points[0] @ T_parent[:3, :3].T + T_parent[:3, 3])
        for k in range(1, spec.n_links + 1):
            grid = np.arange(limits[k - 1, 0], limits[k - 1, 1] + 1e-9, np.radians(config.angle_step_deg))
            world = _link_at_angles(link_points[k][: config.search_points_per_link], T_parent @ joint_origin(spec, k), grid)
            if len(unexplained) == 0:
                break
            # Score against the points the links placed so far do not explain, so a link cannot
            # fold back onto its parent's points.
            d = cKDTree(unexplained).query(world.reshape(-1, 3))[0].reshape(len(grid), -1)
            cost = np.mean(_truncated(d) ** 2, axis=1)
            # The printed object cannot put a link through its foot: such angles are not candidates.
            cost[world[:, :, 2].min(axis=1) < keepout - KEEPOUT_TOLERANCE_M] = np.inf
            best = int(np.argmin(cost))
            params[2 + k] = grid[best]
            T_parent = T_parent @ joint_origin(spec, k) @ rot_y(grid[best])
            unexplained = _unexplained(unexplained, link_points[k] @ T_parent[:3, :3].T + T_parent[:3, 3])
        hypotheses.append((_two_sided_cost(spec, link_points, cloud, points, params), params.copy()))
    hypotheses.sort(key=lambda h: h[0])

    best = None
    for _, start in hypotheses[: config.refine_hypotheses]:
        lower = np.concatenate([[-np.inf, -np.inf, -np.inf], limits[:, 0]])
        upper = np.concatenate([[np.inf, np.inf, np.inf], limits[:, 1]])
        res = least_squares(
            lambda p: _residuals(spec, link_points, cloud, points, p),
            np.clip(start, lower + 1e-9, upper - 1e-9),
            bounds=(lower, upper),
            loss="soft_l1",
            f_scale=0.003,
            diff_step=1e-3,
            max_nfev=25,
        )
        cost = _two_sided_cost(spec, link_points, cloud, points, res.x)
        if best is None or cost < best[0]:
            best = (cost, res.x)
    params = best[1]
    d = cKDTree(_posed(spec, link_points, params)).query(points)[0]
    return ArticulatedFit(
        T_world_base=base_pose(*params[:3]),
        joint_angles_rad=np.array(params[3:]),
        rmse_m=float(np.sqrt(np.mean(_truncated(d) ** 2))),
        inlier_fraction=float(np.mean(d < 0.005)),
    )


#: A cloud point within this distance of a placed link's surface counts as explained by it.
EXPLAINED_M = 0.004


def _unexplained(points: np.ndarray, link_surface: np.ndarray) -> np.ndarray:
    return points[cKDTree(link_surface).query(points)[0] > EXPLAINED_M]


def _link_at_angles(p: np.ndarray, T_joint: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Link points (in the link frame) posed at every joint angle at once: (angles, points, 3)."""
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    rotated = np.stack(
        [c * p[:, 0] + s * p[:, 2], np.broadcast_to(p[:, 1], (len(angles), len(p))), -s * p[:, 0] + c * p[:, 2]], axis=-1
    )
    return rotated @ T_joint[:3, :3].T + T_joint[:3, 3]


def _yaw_candidates(points: np.ndarray, spec, steps: int) -> np.ndarray:
    """A yaw grid, plus the two yaws that put the chain's plane of motion along the cloud's
    main horizontal direction (the moving links lie in one vertical plane of the base frame)."""
    grid = np.linspace(-np.pi, np.pi, steps, endpoint=False)
    upper = points[points[:, 2] > keepout_height_m(spec)]
    if len(upper) < 20:
        return grid
    xy = upper[:, :2] - upper[:, :2].mean(axis=0)
    direction = np.linalg.svd(xy, full_matrices=False)[2][0]
    yaw = float(np.arctan2(direction[1], direction[0]))
    return np.concatenate([[yaw, yaw + np.pi], grid])


def _residuals(spec, link_points, cloud, points, params) -> np.ndarray:
    model = _posed(spec, link_points, params)
    cloud_to_model = cKDTree(model).query(points)[0]
    model_to_cloud = cloud.query(model)[0]
    return np.concatenate([_truncated(cloud_to_model), 0.5 * _truncated(model_to_cloud)])


def _two_sided_cost(spec, link_points, cloud, points, params) -> float:
    return float(np.mean(_residuals(spec, link_points, cloud, points, params) ** 2))
