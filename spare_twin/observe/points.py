"""The object's points in the table frame, from posed depth views of any source.

This is the one observation every network input is made from. A training-rig render (8 fixed cameras
at one time step), a hand-held render and an imported real capture all reach it as a list of posed
depth views (`PosedView`); nothing here asks where they came from:

1. back-project every view (a pixel stride that keeps about `points_per_view` points a view) into
   the recording's world and merge them on a voxel grid (`voxel_m`), so a 640 x 480 sweep and the
   rig's 96 x 128 views give clouds of the same density;
2. the table: the dominant plane (seeded RANSAC over the merged cloud, refined by least squares),
   its normal turned towards the cameras; the table frame has z up along that normal and z = 0 on
   the table;
3. the object: points between `min_height_m` and `max_height_m` above the table, less those that
   other views see past (`observe.clean.seen_through`: flying pixels and floaters, which otherwise
   join a chain to the clutter beside it), split into objects: points closer than `cluster_link_m`
   belong to one (single linkage on exact distances: no grid, whose cells the world's axes would
   place); the one that stands on the table (lowest point within `max_base_height_m`) nearest the
   point the cameras look at is the object; everything else (clutter, walls, the table's edge)
   is dropped.

A view's own flying pixels (readings between two surfaces at a depth edge) are dropped once, where
views are made (`without_flying_pixels`, called by `observe.views`).

Everything is numpy with a seeded generator, so the same views give the same points, bit for bit.
open3d's plane RANSAC and DBSCAN are not used here because their threaded loops do not promise
that (see docs/capture.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from spare_twin.observe.clean import between_surfaces, seen_through
from spare_twin.threads import side_by_side

#: `PointsConfig.cluster_link_m`: a cell of the grid this replaced always joined points this close
#: and sometimes twice as far; clutter stands 3 cm from the chain and more (`sim.effects`).
CLUSTER_LINK_M = 0.012


@dataclass(frozen=True)
class PosedView:
    """One depth view with its pose: what every source is reduced to."""

    depth_m: np.ndarray
    """float32 (H, W) z-depth in metres, 0 = no reading."""
    K: np.ndarray
    """(3, 3) intrinsics at H x W."""
    T_world_camera: np.ndarray
    """(4, 4) camera-to-world (OpenCV axes)."""
    rgb: np.ndarray | None = None
    """uint8 (H, W, 3) colour, when the source has it."""


@dataclass(frozen=True)
class PointsConfig:
    """How the object is cut out of the views (metres)."""

    points_per_view: int = 20000
    """Pixels back-projected per view (a stride is chosen to keep about this many)."""
    max_depth_m: float = 1.5
    """Readings beyond this are dropped (far, noisy, never the object on a table top)."""
    voxel_m: float = 0.003
    """Merge grid: one point per occupied voxel (their mean)."""
    fine_voxel_m: float = 0.002
    """The measurement's merge grid (`ObjectPoints.fine_points_m`): the same readings merged finer.
    Measured on 3 mm points (until release 0.6.19), the lengths were further off (E_L over the
    development captures' right counts 18 % higher, the rig's clean views' 59 %): a 3 mm voxel
    averages a plate's rim and rounded end into its face. The profile image keeps the 3 mm points:
    the profile network was trained on them, and on 2 mm points counted 69 of 96 development
    captures right, not 74 (docs/observe.md)."""
    plane_distance_m: float = 0.006
    """Table inliers: within this of the plane (sensor noise at arm's length)."""
    plane_iterations: int = 200
    plane_sample: int = 5000
    """RANSAC scores planes on at most this many points (a seeded subset)."""
    min_height_m: float = 0.008
    """Lower points are the table (noise, registration blur, the 5 mm foot plate)."""
    max_height_m: float = 0.5
    """The printed chains fit a 200 mm bed; nothing on the table that is taller is one."""
    max_radius_m: float = 0.3
    """Only points within this of where the cameras look (a chain reaches 14 cm from its base)."""
    cluster_link_m: float = CLUSTER_LINK_M
    """Points closer than this are one object; clutter farther from the chain is apart."""
    min_cluster_points: int = 30
    max_base_height_m: float = 0.03
    """The object's lowest point must be this close to the table: it stands on it."""
    seed: int = 0
    depth_tolerance_m: float = 0.006
    """Two readings of one surface lie within this plus `depth_tolerance_per_m2` z^2 of each other
    (noise, a tracker's pose error); beyond, one is past the other (`observe.clean`)."""
    depth_tolerance_per_m2: float = 0.006
    remove_flying: bool = True
    """Drop readings between two surfaces at a depth edge, and points other views see past
    (`observe.clean`), before anything is fused."""
    min_seen_through_views: int = 2
    """A point goes when at least this many views (and more than agree with it) see past it."""


@dataclass(frozen=True)
class ObjectPoints:
    """The observation: the object's points in the table frame, or why there are none."""

    points_m: np.ndarray
    """float64 (N, 3) table frame: z up, table at z = 0, origin below where the cameras look."""
    colors: np.ndarray | None
    """float32 (N, 3) RGB in [0, 1], when the views had colour."""
    T_world_table: np.ndarray
    """(4, 4) table frame to the views' world."""
    scene_points: int
    """Merged points before the table and the clutter were removed."""
    reason: str | None = None
    """Why no object was found (then `points_m` is empty)."""
    view_dirs: np.ndarray | None = None
    """float64 (N, 3) table frame: per point, the mean unit direction towards the cameras that saw
    it (which side of a surface it lies on; short where views from both sides merged)."""
    normals: np.ndarray | None = None
    """float64 (N, 3) table frame: per point, the mean surface normal of its readings, each taken in
    its own depth image (so registration error between views does not blur it), facing the camera;
    zero where no reading had a surface around it."""
    fine_points_m: np.ndarray | None = None
    """float64 (M, 3) table frame: the object's readings merged on the finer `fine_voxel_m` grid, for
    the layer measurement (None: measure `points_m`): those within a coarse voxel of `points_m`, so
    what the clutter split and the flying-pixel check took from the object goes with it."""
    fine_view_dirs: np.ndarray | None = None
    """float64 (M, 3) table frame: `view_dirs` of `fine_points_m`."""

    @property
    def off_aim_m(self) -> float:
        """How far the object stands from where the cameras look: its points' median, horizontally."""
        return median_off_aim_m(self.points_m)


def median_off_aim_m(points_table_m: np.ndarray) -> float:
    """Horizontal distance (metres) of the median of points in the table frame from its origin, below
    where the cameras look."""
    return float(np.linalg.norm(np.median(points_table_m[:, :2], axis=0)))


def backproject(depth_m: np.ndarray, K: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) float64 camera-frame points (OpenCV axes, metres) of the pixels with depth (and `mask`)."""
    valid = depth_m > 0 if mask is None else mask & (depth_m > 0)
    v, u = np.nonzero(valid)
    z = depth_m[v, u].astype(np.float64)
    return np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=1)


def rigid(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """T (4x4) applied to points p (N, 3), written out column by column: a BLAS product of (N, 3) by
    (3, 3) took 50-80 ms for a 640 x 480 view's 300,000 readings on the shared 2-core machine, this
    13 ms (and its sums have a fixed order)."""
    R = T[:3, :3]
    return p[:, 0:1] * R[:, 0] + p[:, 1:2] * R[:, 1] + p[:, 2:3] * R[:, 2] + T[:3, 3]


def depth_normals(depth_m: np.ndarray, K: np.ndarray, max_step_m: float = 0.01, origin=(0, 0)) -> np.ndarray:
    """float64 (H, W, 3) camera-frame unit normals facing the camera, from central differences of the
    back-projected depth image; zero at the border, where a neighbour has no reading, or across a
    depth step (an occluding edge is no surface). `origin`: the (row, column) that `depth_m[0, 0]`
    has in the image K belongs to, when `depth_m` is cut from it."""
    h, w = depth_m.shape
    v, u = np.mgrid[origin[0] : origin[0] + h, origin[1] : origin[1] + w]
    z = depth_m.astype(np.float64)
    P = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=-1)
    normals = np.zeros((h, w, 3))
    if h < 3 or w < 3:
        return normals
    du = P[1:-1, 2:] - P[1:-1, :-2]
    dv = P[2:, 1:-1] - P[:-2, 1:-1]
    n = np.cross(du, dv)
    ok = (
        (z[1:-1, 2:] > 0)
        & (z[1:-1, :-2] > 0)
        & (z[2:, 1:-1] > 0)
        & (z[:-2, 1:-1] > 0)
        & (np.abs(du[..., 2]) < 2 * max_step_m)
        & (np.abs(dv[..., 2]) < 2 * max_step_m)
    )
    norm = np.linalg.norm(n, axis=-1)
    ok &= norm > 0
    n = np.where(ok[..., None], n / np.maximum(norm, 1e-12)[..., None], 0.0)
    n *= np.where((n * P[1:-1, 1:-1]).sum(-1, keepdims=True) > 0, -1.0, 1.0)  # towards the camera
    normals[1:-1, 1:-1] = n
    return normals


def pixel_normals(depth_m: np.ndarray, K: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """`depth_normals(depth_m, K)[depth_m > 0][keep]` ((N, 3); `keep` masks the readings in row-major
    order), computed only over the box round the kept pixels (and the one pixel around it the
    differences need): the object fills a small part of a hand-held view, and the whole image's
    normals cost 50 ms a 640 x 480 view."""
    pick = np.zeros(depth_m.shape, bool)
    pick[depth_m > 0] = keep
    rows, cols = np.flatnonzero(pick.any(axis=1)), np.flatnonzero(pick.any(axis=0))
    if not len(rows):
        return np.zeros((0, 3))
    r0, r1 = max(rows[0] - 1, 0), rows[-1] + 2
    c0, c1 = max(cols[0] - 1, 0), cols[-1] + 2
    return depth_normals(depth_m[r0:r1, c0:c1], K, origin=(r0, c0))[pick[r0:r1, c0:c1]]


def _stride(v: PosedView, cfg: PointsConfig, fine: bool) -> int:
    """Pixel stride of a view: about `points_per_view` pixels; `fine`: no coarser than a voxel at
    the view's median depth (a 12 mm link seen from 1.3 m is 5 pixels wide: a coarse stride keeps
    one or two of them)."""
    h, w = v.depth_m.shape
    stride = max(1, int(round(np.sqrt(h * w / cfg.points_per_view))))
    if fine:
        valid = v.depth_m[(v.depth_m > 0) & (v.depth_m < cfg.max_depth_m)]
        if len(valid):
            stride = min(stride, max(1, int(cfg.voxel_m * float(v.K[0, 0]) / float(np.median(valid)))))
    return stride


def strided_depth(v: PosedView, cfg: PointsConfig, fine: bool) -> tuple[np.ndarray, np.ndarray, int]:
    """(depth, K, stride) of a view read at its stride (`_stride`): 0 = no reading or beyond `max_depth_m`."""
    stride = _stride(v, cfg, fine)
    depth = v.depth_m[::stride, ::stride]
    depth = np.where(depth < cfg.max_depth_m, depth, 0.0)
    K = np.asarray(v.K, np.float64).copy()
    K[:2] /= stride  # pixel i of the strided grid is pixel stride * i: centres stay on integers
    return depth, K, stride


def without_flying_pixels(v: PosedView, cfg: PointsConfig = PointsConfig()) -> PosedView:
    """The view with its readings between two surfaces at a depth edge dropped (`clean.between_surfaces`
    over 2 pixels either side, the flying pixels' band at 640 wide); the view itself where
    `remove_flying` is off. Once per view, where views are made (`observe.views`)."""
    if not cfg.remove_flying:
        return v
    flying = between_surfaces(v.depth_m, 2, cfg.depth_tolerance_m, cfg.depth_tolerance_per_m2)
    return PosedView(np.where(flying, np.float32(0), v.depth_m).astype(np.float32), v.K, v.T_world_camera, v.rgb)


def read_view(v: PosedView, cfg: PointsConfig, fine: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(depth, K, world points, stride) of a view read at its stride (`strided_depth`): the strided
    depth, its intrinsics, its readings in the world (row-major)."""
    depth, K, stride = strided_depth(v, cfg, fine)
    return depth, K, rigid(np.asarray(v.T_world_camera, np.float64), backproject(depth, K)), stride


def read_views(
    views: list[PosedView], cfg: PointsConfig, keep=None, surfaces: bool = True
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """(points, colours, view directions, normals) of every reading of the views in the world, not
    merged: the unit direction from each to its camera and its normal (`depth_normals`; both None
    unless `surfaces`). `keep`: a function of (N, 3) world points giving the mask of those to keep;
    with it, every view is read at the fine stride (`_stride`), since only the region kept costs memory."""

    def one_view(v: PosedView) -> tuple:
        depth, K, world, stride = read_view(v, cfg, fine=keep is not None)
        mask = np.ones(len(world), bool) if keep is None else keep(world)
        world = world[mask]
        normals = to_camera = colors = None
        if surfaces:
            normals = pixel_normals(depth, K, mask) @ np.asarray(v.T_world_camera, np.float64)[:3, :3].T
            to_camera = np.asarray(v.T_world_camera, np.float64)[:3, 3] - world
            to_camera /= np.maximum(np.linalg.norm(to_camera, axis=1, keepdims=True), 1e-9)
        if v.rgb is not None:
            colors = v.rgb[::stride, ::stride][depth > 0][mask].astype(np.float32) / 255.0
        return world, normals, to_camera, colors

    read = side_by_side(one_view, views)
    pts = [r[0] for r in read]
    nrms, dirs = [r[1] for r in read if surfaces], [r[2] for r in read if surfaces]
    cols = [r[3] for r in read if r[3] is not None]
    points = np.concatenate(pts) if pts else np.zeros((0, 3))
    directions = (np.concatenate(dirs) if dirs else np.zeros((0, 3))) if surfaces else None
    normals = (np.concatenate(nrms) if nrms else np.zeros((0, 3))) if surfaces else None
    colors = np.concatenate(cols) if len(cols) == len(views) and cols else None
    return points, colors, directions, normals


def merged_cloud(
    views: list[PosedView], cfg: PointsConfig, keep=None, surfaces: bool = True
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """(points, colours, view directions, normals): the views' readings (`read_views`) merged, one
    point (the mean) per `voxel_m` voxel, in a fixed order."""
    return merged(read_views(views, cfg, keep, surfaces), cfg.voxel_m)


def merged(readings: tuple, voxel_m: float) -> tuple:
    """`read_views`' (points, colours, view directions, normals) merged on a `voxel_m` grid."""
    points, colors, directions, normals = readings
    if len(points) == 0:
        return points, colors, directions, normals
    points, colors, directions, normals = voxel_means(points, voxel_m, colors, directions, normals)
    return points, None if colors is None else colors.astype(np.float32), directions, normals


def voxel_means(points: np.ndarray, voxel_m: float, *values: np.ndarray | None) -> tuple:
    """(points, *values) with one row per occupied `voxel_m` voxel of the (N, 3) `points`: the mean
    of its rows, in a fixed order (the voxels' keys, sorted); a None in `values` stays None."""
    cells = np.floor(points / voxel_m).astype(np.int64)
    cells -= cells.min(0)
    span = cells.max(0) + 1
    keys = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]  # one int64 per voxel: a 1-D unique
    _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)

    def mean(rows: np.ndarray | None) -> np.ndarray | None:
        if rows is None:
            return None
        return np.stack([np.bincount(inverse, rows[:, k]) for k in range(rows.shape[1])], 1) / counts[:, None]

    return (mean(points), *(mean(v) for v in values))


def table_plane(points: np.ndarray, camera_centers: np.ndarray, cfg: PointsConfig) -> np.ndarray:
    """(a, b, c, d), unit normal towards the cameras: the plane with the most inliers (seeded RANSAC),
    refined by a least-squares fit to its inliers."""
    rng = np.random.default_rng(cfg.seed)
    sample = points if len(points) <= cfg.plane_sample else points[rng.choice(len(points), cfg.plane_sample, False)]
    tri = sample[rng.integers(0, len(sample), (cfg.plane_iterations, 3))]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(normals, axis=1)
    ok = norm > 1e-9
    normals = normals[ok] / norm[ok, None]
    offsets = -np.einsum("ij,ij->i", normals, tri[ok, 0])
    inliers = np.abs(sample @ normals.T + offsets) < cfg.plane_distance_m
    best = int(inliers.sum(0).argmax())
    on = sample[inliers[:, best]]
    centre = on.mean(0)
    normal = np.linalg.svd(on - centre, full_matrices=False)[2][-1]
    plane = np.append(normal, -normal @ centre)
    if np.mean(camera_centers @ plane[:3] + plane[3]) < 0:
        plane = -plane
    return plane


def view_target(views: list[PosedView], plane: np.ndarray) -> np.ndarray:
    """The point on the table nearest to every camera's optical axis (least squares): where the
    cameras look, i.e. where the object is."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for v in views:
        c, d = v.T_world_camera[:3, 3], v.T_world_camera[:3, 2]
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ c
    n = plane[:3]
    A += 1e-3 * np.outer(n, n)  # one camera: the axis meets the table there
    target = np.linalg.solve(A, b + 1e-3 * n * -plane[3])
    return target - (target @ n + plane[3]) * n


def table_frame(plane: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """4x4 table frame to world: z = the plane's normal, x = world x projected onto the table."""
    z = plane[:3]
    x = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = x - (x @ z) * z
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    T[:3, 3] = origin
    return T


def where_objects_stand(local: np.ndarray, cfg: PointsConfig) -> np.ndarray:
    """Mask of table-frame points where something standing on the table can be: between
    `min_height_m` and `max_height_m` above it, within `max_radius_m` of where the cameras look."""
    radius = np.linalg.norm(local[:, :2], axis=1)
    return (local[:, 2] > cfg.min_height_m) & (local[:, 2] < cfg.max_height_m) & (radius < cfg.max_radius_m)


def views_table_frame(views: list[PosedView], cfg: PointsConfig) -> tuple[np.ndarray | None, int]:
    """(T_world_table, points merged): the table frame of the views (`table_plane` of their coarse
    merged cloud, the origin where they look); None when they hold fewer than 100 points."""
    points = merged_cloud(views, cfg, surfaces=False)[0]
    if len(points) < 100:
        return None, len(points)
    plane = table_plane(points, np.stack([v.T_world_camera[:3, 3] for v in views]), cfg)
    return table_frame(plane, view_target(views, plane)), len(points)


def _empty(T: np.ndarray, scene: int, reason: str) -> ObjectPoints:
    return ObjectPoints(np.zeros((0, 3)), None, T, scene, reason)


def object_candidates(views: list[PosedView], cfg: PointsConfig = PointsConfig()) -> list[ObjectPoints]:
    """Everything standing on the table in the views' world (see the module doc), each in the table
    frame, best first (more points, nearer where the cameras look); one entry with a `reason` when
    nothing stands there. Which of them is a chain is for `observe.chain` to say."""
    T_world_table, n_points = views_table_frame(views, cfg)
    if T_world_table is None:
        return [_empty(np.eye(4), n_points, f"the depth views hold only {n_points} points")]
    T_table_world = np.linalg.inv(T_world_table)

    def near_target(world: np.ndarray) -> np.ndarray:  # what the object can be: above the table, near the target
        local = rigid(T_table_world, world)
        return (local[:, 2] > -cfg.min_height_m) & (np.linalg.norm(local[:, :2], axis=1) < cfg.max_radius_m)

    # the table and the scene from a coarse read; the object from a read as fine as the voxels
    readings = read_views(views, cfg, keep=near_target)
    points, colors, directions, normals = merged(readings, cfg.voxel_m)
    read_points, _, read_directions, _ = readings
    fine_points, _, fine_directions, _ = merged((read_points, None, read_directions, None), cfg.fine_voxel_m)
    local = rigid(T_table_world, points)
    above = where_objects_stand(local, cfg)
    if cfg.remove_flying and above.any():  # floaters seen through by other views join nothing
        depths = [(*strided_depth(v, cfg, fine=True)[:2], v.T_world_camera) for v in views]
        tol = (cfg.depth_tolerance_m, cfg.depth_tolerance_per_m2)
        above[above] = ~seen_through(points[above], depths, *tol, cfg.min_seen_through_views)
    nothing = [_empty(T_world_table, len(points), "nothing stands on the table where the cameras look")]
    if above.sum() < cfg.min_cluster_points:
        return nothing
    idx = np.flatnonzero(above)
    point_label = _single_linkage(local[idx], cfg.cluster_link_m)
    R = T_world_table[:3, :3]  # world to table frame: R^T d, as rows d @ R
    scored = []
    sizes = np.bincount(point_label)
    for lab in np.flatnonzero(sizes >= cfg.min_cluster_points):
        members = idx[point_label == lab]
        if local[members, 2].min() > cfg.max_base_height_m:
            continue  # floating: not standing on the table
        scored.append((-len(members) / (1.0 + median_off_aim_m(local[members]) / 0.1), lab, members))
    if not scored:
        return nothing
    # each fine point goes with the object it lies within a coarse voxel of (one query for all:
    # objects are more than `cluster_link_m` apart, so no fine point is that near two)
    fine_local = rigid(T_table_world, fine_points)
    reach, nearest = cKDTree(local[idx]).query(fine_local, distance_upper_bound=cfg.voxel_m)
    on = reach <= cfg.voxel_m
    fine_label = np.full(len(fine_local), -1)
    fine_label[on] = point_label[nearest[on]]
    candidates = []
    for _, lab, members in sorted(scored, key=lambda x: (x[0], x[1])):
        fine = fine_label == lab
        candidates.append(
            ObjectPoints(
                local[members],
                None if colors is None else colors[members],
                T_world_table,
                len(points),
                reason=None,
                view_dirs=directions[members] @ R,
                normals=normals[members] @ R,
                fine_points_m=fine_local[fine],
                fine_view_dirs=fine_directions[fine] @ R,
            )
        )
    return candidates


def _single_linkage(points: np.ndarray, link_m: float) -> np.ndarray:
    """Each point's object label: points closer than `link_m` share one (exact neighbours, so the
    split is the same in any world frame). A grid's cells joined chain and clutter up to twice a
    cell apart depending on where the world's axes put the cell boundaries: a 6-link sweep read 6
    links in its first camera's frame and 1 link of a chain merged with the box beside it in its
    tracker's."""
    pairs = cKDTree(points).query_pairs(link_m, output_type="ndarray")
    n = len(points)
    graph = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def object_points(views: list[PosedView], cfg: PointsConfig = PointsConfig()) -> ObjectPoints:
    """The most prominent thing standing on the table (`object_candidates`' first)."""
    return object_candidates(views, cfg)[0]
