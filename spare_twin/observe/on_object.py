"""A registered sweep's views brought into register on what stands on the table.

Registration (`capture.registration`) matches whole frames, and a table-top frame is mostly table: the
table pins each view's height and tilt, while its turn about the table's normal and its slide along
the table rest on the few hundred points of the object (and of any clutter). Where those slip by a
degree or a few millimetres between views, the fused chain comes out blurred: its 6.4 mm layers run
into each other and the layer measurement finds no chain (a 2-link SR300 sweep fused 14.9 mm RMS off
any chain; with the true poses, 0.3 mm).

`register_on_object` moves each view only in those three directions, in the table frame: every
view's points above the table are matched to the nearest points of the other views (point-to-plane,
each point's normal from its own depth image, a Huber loss), the three motions of every view are
solved at once from the same matches, their mean is taken out (the views as a whole stay where they
were), and the rounds repeat with shrinking match distances. Clutter helps: it stands still too.

`spare_twin.measure.chain.measure_views` measures every sweep it registered itself this way. Only surfaces
that face the same way are matched: without that test a plate's front face was matched to its back
face seen from the other side of the sweep, views already in register drifted 2.5 mm apart, and 3 of
36 hidden-pose development captures lost their count. With it, on the 48 hidden-pose development
captures: counts 45 -> 46 right, E_L better by a fifth or more on 19 and worse by a quarter or more
on 10 (median 0.0018 -> 0.0014).

A tracked camera's poses (`tracked_into_register`, read by `observe.views`) are off in all six
directions, each view on its own: every view is first levelled on the common table
(`level_on_table`: its own table readings' plane taken out by a tilt and a lift), then brought into
register on the object as above. On the bench's development captures with tracked poses (seeds
30006-30017, every effect on), counts 1 of 6 -> 6 of 6 with the flying-pixel removal
(`observe.clean`); 30008 counts only once levelled.

Deterministic: fixed reading order, exact nearest neighbours (cKDTree), sums in a fixed order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from spare_twin.capture.registration import normal_equations
from spare_twin.capture.se3 import se3_exp
from spare_twin.object.kinematics import base_pose
from spare_twin.observe.points import (
    PointsConfig,
    PosedView,
    pixel_normals,
    read_view,
    rigid,
    views_table_frame,
    where_objects_stand,
)
from spare_twin.threads import cores, side_by_side


@dataclass(frozen=True)
class OnObjectConfig:
    """How views are brought into register on the object (lengths in metres)."""

    rounds: int = 10
    """Rounds of matching and solving (most views stop moving after 4-6)."""
    match_distances_m: tuple[float, ...] = (0.015, 0.010, 0.006)
    """Match distances, coarse to fine, each for an equal share of the rounds."""
    max_points_per_view: int = 3000
    """Points above the table kept per view (a fixed stride through them)."""
    min_points: int = 30
    """A view with fewer points above the table, or fewer matches, is not moved."""
    min_normal_cos: float = 0.7
    """Only surfaces facing the same way are matched (within 45 deg): a plate's back face, seen from
    the other side of the sweep, lies a plate's thickness behind its front face."""
    huber_m: float = 0.002
    """Residuals beyond this weigh less (a point matched across a 6.4 mm layer gap, a flying pixel)."""


def _object_points(v: PosedView, T_table_world: np.ndarray, points_cfg: PointsConfig, cfg: OnObjectConfig):
    """(points, normals) of a view above the table near where the cameras look, table frame."""
    depth, K, world, _ = read_view(v, points_cfg, fine=True)
    local = rigid(T_table_world, world)
    near = where_objects_stand(local, points_cfg)
    normals = pixel_normals(depth, K, near) @ (T_table_world[:3, :3] @ np.asarray(v.T_world_camera)[:3, :3]).T
    surface = np.abs(normals).sum(axis=1) > 0  # a surface around it
    idx = np.flatnonzero(near)[surface]
    normals = normals[surface]
    step = max(1, -(-len(idx) // cfg.max_points_per_view))
    return local[idx[::step]], normals[::step]


def register_on_object(
    views: list[PosedView], points_cfg: PointsConfig = PointsConfig(), cfg: OnObjectConfig = OnObjectConfig()
) -> list[PosedView]:
    """The views with their turns about the table normal and slides along the table refined on what
    stands on the table (see the module doc); the views unchanged when there is no table or fewer than
    two views show enough of the object."""
    T_world_table, _ = views_table_frame(views, points_cfg)
    if T_world_table is None or len(views) < 2:
        return views
    T_table_world = np.linalg.inv(T_world_table)
    seen = side_by_side(lambda v: _object_points(v, T_table_world, points_cfg, cfg), views)
    movable = np.array([len(p) >= cfg.min_points for p, _ in seen])
    if movable.sum() < 2:
        return views
    owner = np.concatenate([np.full(len(p), i) for i, (p, _) in enumerate(seen)])
    M = [np.eye(4) for _ in views]  # each view's correction, table frame
    for r in range(cfg.rounds):
        dist = cfg.match_distances_m[r * len(cfg.match_distances_m) // cfg.rounds]
        points = [rigid(Mi, p) for Mi, (p, _) in zip(M, seen)]
        normals = [n @ Mi[:3, :3].T for Mi, (_, n) in zip(M, seen)]
        all_points, all_normals = np.concatenate(points), np.concatenate(normals)
        tree = cKDTree(all_points)
        steps = np.zeros((len(views), 3))
        for i, p in enumerate(points):
            if not movable[i]:
                continue
            d, j = tree.query(p, k=8, distance_upper_bound=dist, workers=cores())
            jj = np.minimum(j, len(owner) - 1)
            facing = np.sum(normals[i][:, None, :] * all_normals[jj], axis=2) > cfg.min_normal_cos
            other = (d < dist) & (owner[jj] != i) & facing
            has = other.any(axis=1)
            if has.sum() < cfg.min_points:
                continue
            p = p[has]
            j = j[has, np.argmax(other[has], axis=1)]  # the nearest point of another view
            q, n = all_points[j], all_normals[j]
            res = np.sum((p - q) * n, axis=1)
            J = np.stack([p[:, 0] * n[:, 1] - p[:, 1] * n[:, 0], n[:, 0], n[:, 1]], axis=1)
            w = np.sqrt(np.minimum(1.0, cfg.huber_m / np.maximum(np.abs(res), 1e-12)))
            H, g = normal_equations(J * w[:, None], res * w)
            steps[i] = -np.linalg.solve(H + 1e-6 * len(p) * np.eye(3), g)
        steps[movable] -= np.mean(steps[movable], axis=0)  # the views as a whole stay put
        M = [base_pose(steps[i, 1], steps[i, 2], steps[i, 0]) @ M[i] for i in range(len(views))]  # turn, slide
    return [
        PosedView(v.depth_m, v.K, T_world_table @ Mi @ T_table_world @ np.asarray(v.T_world_camera, np.float64), v.rgb)
        for v, Mi in zip(views, M)
    ]


def level_on_table(
    views: list[PosedView], points_cfg: PointsConfig = PointsConfig(), bands_m: tuple[float, ...] = (0.015, 0.006)
) -> list[PosedView]:
    """The views each tilted and lifted so that its own table lies on the views' common table plane.

    A tracker's poses are each a few tenths of a degree and a few millimetres off, independently: every
    view's table then lies a little tilted and off height, and what stands on it is blurred up and
    down. Each view's readings within `bands_m` of the common plane (near where the cameras look)
    give a plane z = a x + b y + c in the table frame; the view is turned about the table's x and y
    and moved along z to take it out, with the band narrowing each round. Views that see fewer than
    100 table readings are left as they are. A registered sweep needs none of this: registration
    matched whole frames, table and all."""
    T_world_table, _ = views_table_frame(views, points_cfg)
    if T_world_table is None:
        return views
    T_table_world = np.linalg.inv(T_world_table)
    out = []
    for v in views:
        _, _, world, _ = read_view(v, points_cfg, fine=False)
        local = rigid(T_table_world, world)
        local = local[np.linalg.norm(local[:, :2], axis=1) < points_cfg.max_radius_m]
        M = np.eye(4)  # the view's correction, table frame
        for band in bands_m:
            p = rigid(M, local)
            on = p[np.abs(p[:, 2]) < band]
            if len(on) < 100:
                break
            A = np.stack([on[:, 0], on[:, 1], np.ones(len(on))], axis=1)
            H, g = normal_equations(A, on[:, 2])
            a, b, c = np.linalg.solve(H + 1e-9 * np.eye(3), g)
            # z' = z - (a x + b y + c): a small turn about x by -b and about y by a, a lift by -c
            M = se3_exp(np.array([-b, a, 0.0, 0.0, 0.0, -c])) @ M
        T = T_world_table @ M @ T_table_world @ np.asarray(v.T_world_camera, np.float64)
        out.append(PosedView(v.depth_m, v.K, T, v.rgb))
    return out


#: `tracked_into_register`'s rounds: a tracker's poses start a few millimetres off, closer than a
#: registration's slips, so fewer rounds and points do (on the six development captures with tracked
#: poses: the same counts, E_L 0.0146 -> 0.0125 pu mean, about 1 s less). On the rig's eight views
#: 6.3 mm apart (tests/test_robust_effects.py): 2.8 mm after the full rounds, 3.4 after these, 3.9
#: after 6 rounds of 1,500 points.
TRACKED = OnObjectConfig(rounds=8, max_points_per_view=2000)


def tracked_into_register(
    views: list[PosedView], points_cfg: PointsConfig = PointsConfig(), cfg: OnObjectConfig = TRACKED
) -> list[PosedView]:
    """A tracked camera's views brought into register, starting from the tracker's poses: each levelled
    on the common table (`level_on_table`), then turned and slid on what stands on it
    (`register_on_object`). Tracker poses a few tenths of a degree and a few millimetres off, each
    on its own, blur a chain's 6.4 mm layers into one another and its foot into the table (bench
    seed 30008, 3 links: no chain as tracked, the count and lengths within 0.015 pu after)."""
    return register_on_object(level_on_table(views, points_cfg), points_cfg, cfg)
