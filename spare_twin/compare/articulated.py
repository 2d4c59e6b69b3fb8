"""Articulated registration: the URDF twin's base pose and joint angles that best explain a point cloud.

The cloud is in the object frame the capture tools produce (metres, z up, table at z = 0). The twin
stands on the table, so its base pose has three degrees of freedom (x, y, yaw); together with the n
joint angles these are found by

1. a global search: for each yaw on a grid, the chain is posed link by link, each joint angle taken
   from a grid by how well that link's surface lands on the points the links before it leave
   unexplained; a beam of partial chains is kept (a greedy pass lets a short link settle on a later
   link's points and strands the rest of the chain);
2. a robust least-squares refinement of the best few on two-sided point distances (every observed
   point near the twin's surface, and the twin's surface near observed points), each also from its
   mirror image: a planar chain turned half round with every joint angle negated covers the same
   outline; only the side its 6.4 mm layers stack towards differs, and a fused cloud smears that;
3. with the depth images themselves (`views`), render and compare (`spare_twin.compare.depth_fit`): the
   candidate whose rendered depth agrees best is kept, its joints re-searched and polished on depth
   agreement, the cameras re-aligned onto the posed twin between polishes, and the chain fitted to
   the aligned frames' own points. Without views the lowest cloud cost wins.

Speed (a 30-frame 640 x 480 capture, 20 depth views): the searches read the depth images at about
160 columns and only the last polish at 320 (`FitConfig.depth_width_px`); the depth score casts
rays only where the chain can be seen (`depth_fit`); nearest-neighbour queries stop at the distance
their costs truncate at. A 5-link fit that took 9 CPU-minutes (pybullet renders at 320 columns
throughout) takes about 20 CPU-seconds, its joint angles within half a degree of the earlier ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from spare_twin.compare.depth_fit import DepthScorer, DepthView, transformed, twin_link_meshes
from spare_twin.errors import SpareTwinError
from spare_twin.object.folder import ObjectFolder
from spare_twin.object.kinematics import (
    base_pose,
    forward_kinematics,
    joint_limits_rad,
    joint_origin,
    keepout_height_m,
    param_bounds,
    rot_y,
)

#: Distances beyond this count as "not explained" (metres): robust to clutter and fusion noise.
TRUNCATE_M = 0.01
#: How far below the foot's keep-out height a surface sample may fall during the search (sampling slack).
KEEPOUT_TOLERANCE_M = 0.002


@dataclass(frozen=True)
class FitConfig:
    """Search and refinement settings for `fit_articulated`."""

    points_per_link: int = 250
    """Surface samples per link of the twin."""
    max_cloud_points: int = 3000
    yaw_steps: int = 24
    angle_step_deg: float = 5.0
    search_points_per_link: int = 60
    """Surface samples per link during the global search (a subset, for speed)."""
    beam_width: int = 12
    branch: int = 4
    """Global search: partial chains kept per base yaw, and angles tried per link for each of them."""
    refine_hypotheses: int = 2
    """How many of the best global-search poses to refine (each also as its mirror image)."""
    depth_width_px: int = 160
    depth_fine_width_px: int = 320
    """With depth views: they are rendered and compared on every n-th pixel, n chosen so that about
    this many columns are read: `depth_width_px` while searching, `depth_fine_width_px` for the last
    polish (a 640-pixel-wide sensor: every 4th, then every 2nd)."""
    depth_coarse_deg: float = 10.0
    depth_fine_deg: float = 2.5
    """With depth views: the joint-angle search on depth agreement, whole range then +-coarse."""
    align_rounds: int = 2
    """With depth views: rounds of camera re-alignment onto the fit, each followed by a polish; then
    a fit to the aligned frames' points and a last polish."""
    polish_deg: tuple[float, ...] = (2.0, 1.0)
    aligned_polish_deg: tuple[float, ...] = (1.0, 0.5)
    fine_polish_deg: tuple[float, ...] = (0.25,)
    """With depth views: the polishes' step sizes (`DepthScorer.polish`): after the joint search, after
    each camera alignment, and the last one at the finer sampling."""
    dense_points_per_link: int = 1500
    max_view_points: int = 8000
    dense_fit_evaluations: int = 30
    """With depth views: twin surface samples per link, observed points and the least-squares
    evaluations for the fit to the frames (its valleys are long and flat: it pulls the chain most
    of the way along them, and the last polish on depth settles it)."""
    seed: int = 0


@dataclass(frozen=True)
class ArticulatedFit:
    T_object_base: np.ndarray
    """4x4 pose of the twin's base (link 0) in the cloud's frame: the object frame (z up, table z = 0)."""
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
    view_corrections: tuple = ()
    """With depth views: the mean camera-pose correction of each alignment round (millimetres, degrees)."""
    view_poses: tuple = ()
    """With depth views: each view's 4x4 camera pose in the cloud's frame, re-aligned onto the fit
    (in the order the views were given)."""

    @property
    def params(self) -> np.ndarray:
        """(n + 3,) base x, y, yaw and the joint angles: the search's parameter vector."""
        T = self.T_object_base
        return np.array([T[0, 3], T[1, 3], np.arctan2(T[1, 0], T[0, 0]), *self.joint_angles_rad])


def twin_surface_points(obj: ObjectFolder, per_link: int, seed: int = 0) -> list[np.ndarray]:
    """Surface samples of every link's printed parts, in that link's frame (metres)."""
    import trimesh

    rng = np.random.default_rng(seed)
    out = []
    for mesh in twin_link_meshes(obj):
        pts, _ = trimesh.sample.sample_surface(mesh, per_link, seed=int(rng.integers(2**31)))
        out.append(np.asarray(pts, dtype=np.float64))
    return out


def _posed(spec, link_points, params) -> np.ndarray:
    poses = forward_kinematics(spec, params[3:], base_pose(*params[:3]))
    return np.vstack([transformed(pts, T) for pts, T in zip(link_points, poses)])


def _near(tree: cKDTree, points: np.ndarray, within_m: float) -> np.ndarray:
    """Distance from each point to its nearest neighbour in `tree`, exact up to `within_m` and inf
    beyond (a little past it): every use truncates or thresholds at `within_m`, and the bounded
    search skips the far branches of the tree."""
    return tree.query(points, distance_upper_bound=within_m * 1.01)[0]


def _truncated(d: np.ndarray) -> np.ndarray:
    return np.minimum(d, TRUNCATE_M)


def fit_articulated(
    obj: ObjectFolder,
    points_object: np.ndarray,
    config: FitConfig = FitConfig(),
    views: list[DepthView] | None = None,
) -> ArticulatedFit:
    """Fit the twin to `points_object` (see the module doc); `views` (`depth_fit.DepthView`: depth
    images of the same scene, posed in the cloud's frame) settle the fit by render and compare."""
    spec = obj.spec
    points = np.asarray(points_object, dtype=np.float64).reshape(-1, 3)
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

    hypotheses = []
    for yaw in _yaw_candidates(points, spec, config.yaw_steps):
        for params in _chain_search(spec, link_points, limits, points, base_pose(x0, y0, yaw), config):
            params[:3] = x0, y0, yaw
            hypotheses.append((_two_sided_cost(spec, link_points, cloud, points, params), params))
    hypotheses.sort(key=lambda h: h[0])

    lower, upper = param_bounds(limits)
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
    view_corrections, view_poses = [], ()
    if views:
        with DepthScorer(obj, views, _stride(views, config.depth_width_px)) as scorer:
            for c in candidates:
                c[1] = scorer(c[2])
            candidates.sort(key=lambda c: c[1])
            # the cloud search can fold a short end link back onto its smeared parent: settle the
            # joint angles on the depth images themselves
            params, _ = scorer.refine_joints(candidates[0][2], limits, config.depth_coarse_deg, config.depth_fine_deg)
            params, error = scorer.polish(params, limits, config.polish_deg)
            for _ in range(config.align_rounds):
                view_corrections.append(scorer.align_views(params))
                params, error = scorer.polish(params, limits, config.aligned_polish_deg)
            # the aligned frames' own points, tens of thousands, pull the chain smoothly along the
            # shallow valleys a pattern search crosses slowly; the polish then settles it on depth,
            # at the finer sampling
            dense = twin_surface_points(obj, config.dense_points_per_link, config.seed)
            points_seen = scorer.object_points(params[:2], scorer.reach_m(), config.max_view_points, config.seed)
            fitted = _fit_to_points(spec, dense, points_seen, params, limits, config.dense_fit_evaluations)
            scorer.set_stride(_stride(views, config.depth_fine_width_px))
            if scorer(fitted) < scorer(params):
                params = fitted
            params, error = scorer.polish(params, limits, config.fine_polish_deg)
            candidates[0][2], candidates[0][1] = params, error
            view_poses = tuple(np.array(v.T_cloud_camera) for v in scorer.views)
    else:
        candidates.sort(key=lambda c: c[0])
    params = candidates[0][2]
    d = _near(cKDTree(_posed(spec, link_points, params)), points, TRUNCATE_M)
    return ArticulatedFit(
        T_object_base=base_pose(*params[:3]),
        joint_angles_rad=np.array(params[3:]),
        rmse_m=float(np.sqrt(np.mean(_truncated(d) ** 2))),
        inlier_fraction=float(np.mean(d < 0.005)),
        depth_error_m=candidates[0][1],
        candidates=tuple((float(c[0]), c[1], np.array(c[2])) for c in candidates),
        view_corrections=tuple(view_corrections),
        view_poses=view_poses,
    )


def _stride(views: list[DepthView], width_px: int) -> int:
    """The pixel step that reads about `width_px` columns of the widest view."""
    return max(1, round(max(v.depth_m.shape[1] for v in views) / width_px))


def mirrored(params: np.ndarray) -> np.ndarray:
    """The chain's mirror pose: base turned half round, every joint angle negated (the same outline)."""
    out = np.array(params, dtype=np.float64)
    out[2] = (out[2] + 2 * np.pi) % (2 * np.pi) - np.pi
    out[3:] = -out[3:]
    return out


#: A cloud point within this distance of a placed link's surface counts as explained by it.
EXPLAINED_M = 0.004


def _unexplained(points: np.ndarray, link_surface: np.ndarray) -> np.ndarray:
    return points[_near(cKDTree(link_surface), points, EXPLAINED_M) > EXPLAINED_M]


def _chain_search(spec, link_points, limits, points, T_object_base, config: FitConfig) -> list[np.ndarray]:
    """Pose the chain link by link from its base, keeping a beam of the `beam_width` partial chains
    with the lowest summed link costs; each extends by the `branch` best local minima of its next
    link's cost over the angle grid. A link is scored against the points the links placed before it
    leave unexplained, so it cannot fold back onto its parent's points; a greedy pass (one branch)
    lets a short link settle on a later link's points and strands the rest of the chain."""
    keepout = keepout_height_m(spec)
    base_points = transformed(link_points[0], T_object_base)
    beam = [(0.0, np.zeros(spec.n_links + 3), T_object_base, _unexplained(points, base_points))]
    for k in range(1, spec.n_links + 1):
        grid = np.arange(limits[k - 1, 0], limits[k - 1, 1] + 1e-9, np.radians(config.angle_step_deg))
        children = []
        for total, params, T_parent, unexplained in beam:
            target = unexplained if len(unexplained) >= 10 else points
            posed = _link_at_angles(
                link_points[k][: config.search_points_per_link], T_parent @ joint_origin(spec, k), grid
            )
            d = _near(cKDTree(target), posed.reshape(-1, 3), TRUNCATE_M).reshape(len(grid), -1)
            cost = np.mean(_truncated(d) ** 2, axis=1)
            # The printed object cannot put a link through its foot: such angles are not candidates.
            cost[posed[:, :, 2].min(axis=1) < keepout - KEEPOUT_TOLERANCE_M] = np.inf
            for i in _local_minima(cost)[: config.branch]:
                child = params.copy()
                child[2 + k] = grid[i]
                T_link = T_parent @ joint_origin(spec, k) @ rot_y(grid[i])
                children.append((total + cost[i], child, T_link, unexplained))
        children.sort(key=lambda c: c[0])
        beam = [
            (total, child, T_link, _unexplained(unexplained, transformed(link_points[k], T_link)))
            for total, child, T_link, unexplained in children[: config.beam_width]
        ]
    return [params for _, params, _, _ in beam]


def _local_minima(cost: np.ndarray) -> np.ndarray:
    """Indices of the finite local minima of a 1-D cost (ends compare with one neighbour), lowest first."""
    padded = np.concatenate([[np.inf], cost, [np.inf]])
    is_min = np.isfinite(cost) & (cost <= padded[:-2]) & (cost <= padded[2:])
    idx = np.nonzero(is_min)[0]
    if len(idx) == 0:  # every angle is ruled out: keep the least bad so the chain stays whole
        return np.array([int(np.argmin(cost))])
    return idx[np.argsort(cost[idx], kind="stable")]


def _link_at_angles(p: np.ndarray, T_joint: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Link points (in the link frame) posed at every joint angle at once: (angles, points, 3)."""
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    rotated = np.stack(
        [c * p[:, 0] + s * p[:, 2], np.broadcast_to(p[:, 1], (len(angles), len(p))), -s * p[:, 0] + c * p[:, 2]],
        axis=-1,
    )
    return transformed(rotated, T_joint)


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
    cloud_to_model = _near(cKDTree(model), points, TRUNCATE_M)
    model_to_cloud = _near(cloud, model, TRUNCATE_M)
    return np.concatenate([_truncated(cloud_to_model), 0.5 * _truncated(model_to_cloud)])


def _fit_to_points(spec, link_points, points, params, limits, max_nfev: int = 100) -> np.ndarray:
    """Robust least squares of the chain onto observed points (each near the posed twin's surface):
    one-sided, since a depth frame sees only the surfaces facing it."""
    if len(points) < 50:
        return np.array(params, dtype=np.float64)
    lower, upper = param_bounds(limits)
    res = least_squares(
        lambda p: _truncated(_near(cKDTree(_posed(spec, link_points, p)), points, TRUNCATE_M)),
        np.clip(params, lower + 1e-9, upper - 1e-9),
        bounds=(lower, upper),
        loss="soft_l1",
        f_scale=0.002,
        diff_step=1e-3,
        max_nfev=max_nfev,
    )
    return res.x


def _two_sided_cost(spec, link_points, cloud, points, params) -> float:
    return float(np.mean(_residuals(spec, link_points, cloud, points, params) ** 2))
