"""Articulated registration: the URDF twin's base pose and joint angles that best explain a point cloud.

The cloud is in the object frame the capture tools produce (metres, z up, table at z = 0). The twin
stands on the table, so its base pose has three degrees of freedom (x, y, yaw); together with the n
joint angles these are found by

1. a global search: for each yaw on a grid, the chain is posed link by link, each joint angle picked
   from a grid by how well that link's surface lands on the cloud (the chain is a tree, so this greedy
   pass is exact when the cloud is complete and a good start when it is not);
2. a robust least-squares refinement of all parameters on two-sided point distances (every observed
   point near the twin's surface, and the twin's surface near observed points);
3. the choice between the refined poses and their mirror images. A planar chain turned half round
   with every joint angle negated covers the same outline; only the side its 6.4 mm layers stack
   towards differs, and a fused cloud smears that (its cost can even favour the mirror). Given the
   depth images themselves, each candidate is rendered through their cameras and the one whose depth
   agrees best is kept (render and compare); without them the lowest cloud cost wins.
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
    """How many of the best global-search poses to refine (each also as its mirror image)."""
    depth_scale: float = 0.5
    """With depth views: they are rendered and compared at this fraction of their resolution."""
    depth_coarse_deg: float = 10.0
    depth_fine_deg: float = 1.0
    """With depth views: the joint-angle search on depth agreement, whole range then +-coarse."""
    seed: int = 0


@dataclass(frozen=True)
class DepthView:
    """One observed depth image, for choosing between candidate fits by rendering them."""

    depth_m: np.ndarray
    """float32 (H, W) z-depth in metres, 0 = no reading."""
    K: np.ndarray
    """3x3 intrinsics."""
    T_cloud_camera: np.ndarray
    """4x4 camera pose in the cloud's frame (OpenCV camera axes)."""


#: Depth disagreements beyond this count as this much (metres): a hole or a stray reading is one bad pixel.
DEPTH_TRUNCATE_M = 0.02
#: Observed points this high above the table belong to the object (metres; the segmenter's cut).
OBJECT_HEIGHT_M = 0.008


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
    depth_error_m: float | None = None
    """Mean truncated depth disagreement of the rendered fit with the depth views (None without views)."""
    candidates: tuple = ()
    """(cloud cost, depth error or None, params) of every refined candidate, best first."""


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


def fit_articulated(obj: ObjectFolder, points_world: np.ndarray, config: FitConfig = FitConfig(),
                    views: list[DepthView] | None = None) -> ArticulatedFit:
    """Fit the twin to `points_world` (see the module doc); `views` (depth images of the same scene,
    posed in the cloud's frame) decide between a fit and its mirror image."""
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

    lower = np.concatenate([[-np.inf, -np.inf, -np.inf], limits[:, 0]])
    upper = np.concatenate([[np.inf, np.inf, np.inf], limits[:, 1]])
    starts = [start for _, start in hypotheses[: config.refine_hypotheses]]
    starts += [mirrored(start) for start in starts]
    candidates = []
    for start in starts:
        res = least_squares(
            lambda p: _residuals(spec, link_points, cloud, points, p),
            np.clip(start, lower + 1e-9, upper - 1e-9),
            bounds=(lower, upper),
            loss="soft_l1",
            f_scale=0.003,
            diff_step=1e-3,
            max_nfev=25,
        )
        candidates.append([_two_sided_cost(spec, link_points, cloud, points, res.x), None, res.x])
    if views:
        with DepthScorer(obj, views, config.depth_scale) as scorer:
            for c in candidates:
                c[1] = scorer(c[2])
            candidates.sort(key=lambda c: c[1])
            # the cloud search can fold a short end link back onto its smeared parent: settle the
            # joint angles on the depth images themselves
            params, _ = scorer.refine_joints(candidates[0][2], limits, config.depth_coarse_deg, config.depth_fine_deg)
            candidates[0][2], candidates[0][1] = scorer.polish(params, limits)
    else:
        candidates.sort(key=lambda c: c[0])
    params = candidates[0][2]
    d = cKDTree(_posed(spec, link_points, params)).query(points)[0]
    return ArticulatedFit(
        T_world_base=base_pose(*params[:3]),
        joint_angles_rad=np.array(params[3:]),
        rmse_m=float(np.sqrt(np.mean(_truncated(d) ** 2))),
        inlier_fraction=float(np.mean(d < 0.005)),
        depth_error_m=candidates[0][1],
        candidates=tuple((float(c[0]), c[1], np.array(c[2])) for c in candidates),
    )


def mirrored(params: np.ndarray) -> np.ndarray:
    """The chain's mirror pose: base turned half round, every joint angle negated (the same outline)."""
    out = np.array(params, dtype=np.float64)
    out[2] = (out[2] + 2 * np.pi) % (2 * np.pi) - np.pi
    out[3:] = -out[3:]
    return out


class DepthScorer:
    """Renders posed twins through depth views and scores their agreement with the observed depth:
    the mean truncated |rendered - observed| over pixels where the rendered twin or an observed point
    above the table is (both read). Views are scored at `scale` of their resolution (nearest
    neighbour) so that a joint-angle search stays quick."""

    def __init__(self, obj: ObjectFolder, views: list[DepthView], scale: float = 0.5):
        import cv2

        from spare_twin.sim.twin import Twin

        self.views = []
        for v in views:
            h, w = v.depth_m.shape
            hs, ws = max(8, round(h * scale)), max(8, round(w * scale))
            depth = cv2.resize(v.depth_m, (ws, hs), interpolation=cv2.INTER_NEAREST)
            K = np.asarray(v.K, np.float64).copy()
            K[0] *= ws / w
            K[1] *= hs / h
            K[0, 2] += 0.5 * ws / w - 0.5  # pixel centres stay pixel centres
            K[1, 2] += 0.5 * hs / h - 0.5
            small = DepthView(depth, K, v.T_cloud_camera)
            self.views.append((small, _object_pixels(small)))
        self.twin = Twin()
        self.twin.load(obj)

    def __call__(self, params: np.ndarray) -> float:
        self.twin.set_joints(params[3:])
        T_base_cloud = np.linalg.inv(base_pose(*params[:3]))
        errors = []
        for v, observed in self.views:
            h, w = v.depth_m.shape
            frame = self.twin.render(T_base_cloud @ v.T_cloud_camera, v.K, w, h, 0.02, 3.0, segmentation=True)
            both = (observed | (frame.segmentation > 0)) & (v.depth_m > 0) & (frame.depth_m > 0)
            errors.append(np.minimum(np.abs(frame.depth_m[both] - v.depth_m[both]), DEPTH_TRUNCATE_M))
        e = np.concatenate(errors)
        return float(e.mean()) if len(e) else float("inf")

    def refine_joints(self, params: np.ndarray, limits: np.ndarray, coarse_deg: float, fine_deg: float) -> tuple[np.ndarray, float]:
        """Coordinate search, base outwards: each joint angle over its whole range at `coarse_deg`,
        then +-coarse_deg around the best at `fine_deg`, the others held."""
        params = np.array(params, dtype=np.float64)
        best = self(params)
        for k in range(len(limits)):
            lo, hi = limits[k]
            for step, span in ((coarse_deg, None), (fine_deg, coarse_deg)):
                if span is None:
                    grid = np.arange(lo, hi + 1e-9, np.radians(step))
                else:
                    c = params[3 + k]
                    grid = np.clip(c + np.radians(np.arange(-span, span + 1e-9, step)), lo, hi)
                for a in grid:
                    trial = params.copy()
                    trial[3 + k] = a
                    e = self(trial)
                    if e < best:
                        best, params = e, trial
        return params, best

    def polish(self, params: np.ndarray, limits: np.ndarray, rounds: int = 2) -> tuple[np.ndarray, float]:
        """Small coordinate steps on every parameter (base x, y in 1 mm, yaw and joints in 0.5 deg,
        +-3 steps), `rounds` times: the joints and the base settle together."""
        params = np.array(params, dtype=np.float64)
        best = self(params)
        steps = [0.001, 0.001] + [np.radians(0.5)] * (len(params) - 2)
        lower = np.concatenate([[-np.inf] * 3, limits[:, 0]])
        upper = np.concatenate([[np.inf] * 3, limits[:, 1]])
        for _ in range(rounds):
            for i, step in enumerate(steps):
                for j in (-3, -2, -1, 1, 2, 3):
                    trial = params.copy()
                    trial[i] = np.clip(params[i] + j * step, lower[i], upper[i])
                    e = self(trial)
                    if e < best:
                        best, params = e, trial
        return params, best

    def close(self) -> None:
        self.twin.close()

    def __enter__(self) -> "DepthScorer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _object_pixels(v: DepthView) -> np.ndarray:
    """Pixels whose observed point lies above the table (z > OBJECT_HEIGHT_M in the cloud's frame)."""
    h, w = v.depth_m.shape
    vv, uu = np.nonzero(v.depth_m > 0)
    z = v.depth_m[vv, uu].astype(np.float64)
    rays = np.stack([(uu - v.K[0, 2]) / v.K[0, 0] * z, (vv - v.K[1, 2]) / v.K[1, 1] * z, z], axis=1)
    height = rays @ v.T_cloud_camera[2, :3] + v.T_cloud_camera[2, 3]
    mask = np.zeros((h, w), dtype=bool)
    mask[vv, uu] = height > OBJECT_HEIGHT_M
    return mask


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
