"""Pairwise registration: a frame as ICP sees it (`Cloud`), multi-scale point-to-plane ICP, and the
FPFH + RANSAC global guess (`PairRegistrar`). Every sum has a fixed order and RANSAC is seeded per pair,
so the same frames give the same edges on every run (`spare_twin.capture.registration` says why)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from spare_twin.capture.se3 import apply_transform, kabsch, normal_equations, se3_exp, skew, solve_damped
from spare_twin.open3d_loader import quiet_open3d

if TYPE_CHECKING:
    from spare_twin.capture.registration import RegistrationConfig

#: Source points per ICP at each scale, coarse to fine (the finest takes every point of a 640x480 frame
#: at 4 mm): with a stride sample of half the points the turn about the vertical was 1.3-1.5x further
#: off, because it rests on the few points of the object.
_ICP_POINTS = (800, 1600, 8000)
#: ICP stops at a scale when an update turns and moves less than this (rad and m): coarse scales, finest.
_ICP_STOP = (1e-3, 1e-4)
#: A block's neighbourhood whose middle principal axis is not this many times its smallest is no plane
#: (an edge, a thin rod seen end-on): it gives no point.
_PLANAR_RATIO = 4.0


@dataclass
class Edge:
    """One pairwise result: T_target_source maps source-frame points into the target frame."""

    source: int
    target: int
    T_target_source: np.ndarray
    fitness: float
    rmse_m: float
    init: str
    """"guess", "ransac" or "smoothed" (`registration._smooth_start`): where the kept result started."""
    information: np.ndarray | None = None
    """(6, 6) information per matched point, source frame (rotation vector, translation): the edge's
    weight in the pose graph, times its fitness."""


def point_information(q: np.ndarray) -> np.ndarray:
    """Information per point of a rigid motion (rotation vector, translation; source frame) from the
    matched source points q: the mean of J^T J with J = d(R q + t) = [-[q]x, I] (open3d's choice too).

    Point-to-point rather than the ICP's own point-to-plane Hessian: that one says a table pins nothing
    along itself, which holds for every edge alike, and the graph then weighs edges by their few object
    points; on the test captures that ended up to 2x further from the truth (docs/capture.md)."""
    n = float(len(q))
    c = np.array([np.sum(q[:, i]) for i in range(3)]) / n
    Q = np.empty((3, 3))
    for i in range(3):
        for j in range(i, 3):
            Q[i, j] = Q[j, i] = np.sum(q[:, i] * q[:, j]) / n
    H = np.zeros((6, 6))
    H[:3, :3] = np.trace(Q) * np.eye(3) - Q
    H[:3, 3:] = skew(c)
    H[3:, :3] = -skew(c)
    H[3:, 3:] = np.eye(3)
    return H


@dataclass
class Cloud:
    """One frame as ICP sees it (camera frame, metres)."""

    points: np.ndarray
    normals: np.ndarray
    K: np.ndarray
    grid_z_m: np.ndarray
    """(H // block, W // block) mean depth of each pixel block, 0 where it gave no point."""
    block: int
    _tree: object = None

    @property
    def tree(self):
        from scipy.spatial import cKDTree

        if self._tree is None:
            self._tree = cKDTree(self.points)
        return self._tree

    def spread(self, n: int) -> np.ndarray:
        """Indices of at most n points evenly through the cloud (a fixed stride)."""
        return np.arange(0, len(self.points), max(1, -(-len(self.points) // n)))

    def sample(self, n: int) -> np.ndarray:
        """Indices (ascending) of at most n points, spread over normal directions first.

        Normal-space sampling (Rusinkiewicz and Levoy 2001): a table-top scene is mostly table, whose
        points pin height and tilt only; the few points on the object pin the turn about the vertical
        and the slide along the table, so they are all kept and the table thinned. Within one normal
        direction the points are taken in a fixed pseudo-random order (spread over the image)."""
        m = len(self.points)
        if m <= n:
            return np.arange(m)
        q = np.clip(np.floor((self.normals + 1.0) * 2.0), 0, 3).astype(np.int64)  # 4 bins per axis
        bucket = q[:, 0] * 16 + q[:, 1] * 4 + q[:, 2]
        counts = np.bincount(bucket, minlength=64)
        lo, hi = 1, int(counts.max())  # the smallest per-direction quota that gives n points
        while lo < hi:
            mid = (lo + hi) // 2
            if np.minimum(counts, mid).sum() >= n:
                hi = mid
            else:
                lo = mid + 1
        order = np.lexsort((np.random.default_rng(m).permutation(m), bucket))
        rank = np.arange(m) - np.concatenate([[0], np.cumsum(counts)[:-1]])[bucket[order]]
        return np.sort(order[rank < lo])


#: The elementwise operation of each reduction `_block_reduce` takes.
_BLOCK_OPS = {np.sum: np.add, np.max: np.maximum, np.min: np.minimum}


def _block_reduce(a: np.ndarray, b: int, how) -> np.ndarray:
    """how (np.sum, np.max, np.min) over b x b pixel blocks of an (H, W) array cropped to whole blocks.

    Column by column, then row by row, each step one operation on every b-th column (row) of the whole
    image: the same values, added in the same order, as `how` along each block's axes, which runs a
    short loop per block (4-10x slower on a 640 x 480 frame). Except a sum across 8 columns or more:
    numpy adds those in 8 interleaved partial sums, so it is left to numpy, for the same bytes."""
    op = _BLOCK_OPS[how]
    gh, gw = a.shape[0] // b, a.shape[1] // b
    a = a[: gh * b, : gw * b]
    if how is np.sum and b >= 8:
        columns = np.sum(a.reshape(gh * b, gw, b), axis=2)
    else:
        columns = a[:, 0::b]
        for k in range(1, b):
            columns = op(columns, a[:, k::b])
    blocks = columns[0::b]
    for k in range(1, b):
        blocks = op(blocks, columns[k::b])
    return blocks


def _smallest_eigh3(xx, xy, xz, yy, yz, zz) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smallest and middle eigenvalues, and the smallest's unit eigenvector, of symmetric 3x3 matrices
    given by their upper triangles' six (N,) entries: closed form, 10x faster than batched eigh."""
    q = (xx + yy + zz) / 3.0
    p1 = xy * xy + xz * xz + yz * yz
    p = np.sqrt(np.maximum(((xx - q) ** 2 + (yy - q) ** 2 + (zz - q) ** 2 + 2.0 * p1) / 6.0, 1e-300))
    b00, b11, b22 = (xx - q) / p, (yy - q) / p, (zz - q) / p
    b01, b02, b12 = xy / p, xz / p, yz / p
    r = (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02)) / 2.0
    phi = np.arccos(np.clip(r, -1.0, 1.0)) / 3.0
    lmax = q + 2.0 * p * np.cos(phi)
    lmin = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    lmid = 3.0 * q - lmax - lmin
    r0 = np.stack([xx - lmin, xy, xz], axis=1)
    r1 = np.stack([xy, yy - lmin, yz], axis=1)
    r2 = np.stack([xz, yz, zz - lmin], axis=1)
    cands = np.stack([np.cross(r0, r1), np.cross(r0, r2), np.cross(r1, r2)], axis=1)
    norms = np.sqrt((cands * cands).sum(axis=2))
    best = np.argmax(norms, axis=1)
    rows = np.arange(len(xx))
    return lmin, lmid, cands[rows, best] / np.maximum(norms[rows, best], 1e-300)[:, None]


def frame_cloud(frame, cfg: RegistrationConfig) -> Cloud:
    """Block-averaged points and normals of one frame.

    Each block of b x b pixels (b chosen so that a block is about `voxel_m` wide at the frame's median
    depth) with at least half its pixels valid and less than 4 `voxel_m` of depth in it becomes its
    pixels' centroid (the centroid of points on a surface lies on it). The normal is the smallest
    principal axis of the block and its 3x3 grid neighbours that are on the same surface (within 3
    `voxel_m` in depth), turned towards the camera."""
    K = np.asarray(frame.K, np.float64)
    h, w = frame.depth_u16.shape
    raw = frame.depth_u16
    far = int(min(cfg.max_depth_m / frame.depth_scale, 65535))
    sub = raw[::4, ::4]
    sub = sub[(sub > 0) & (sub <= far)]
    if not len(sub):
        return Cloud(np.zeros((0, 3)), np.zeros((0, 3)), K, np.zeros((1, 1)), 1)
    median_m = float(np.sort(sub)[len(sub) // 2]) * frame.depth_scale
    b = max(1, int(round(cfg.voxel_m * K[0, 0] / median_m)))
    gh, gw = h // b, w // b
    raw = raw[: gh * b, : gw * b]
    valid = (raw > 0) & (raw <= far)
    z = np.where(valid, raw * frame.depth_scale, 0.0)
    spread = _block_reduce(z, b, np.max) - _block_reduce(np.where(valid, z, np.inf), b, np.min)
    cnt = _block_reduce(valid.astype(np.float64), b, np.sum)
    ok = (2 * cnt >= b * b) & (spread <= 4 * cfg.voxel_m)
    n = np.maximum(cnt, 1.0)
    u = (np.arange(gw * b, dtype=np.float64) - K[0, 2]) / K[0, 0]
    v = (np.arange(gh * b, dtype=np.float64) - K[1, 2]) / K[1, 1]
    Z = _block_reduce(z, b, np.sum) / n
    X, Y = _block_reduce(z * u[None, :], b, np.sum) / n, _block_reduce(z * v[:, None], b, np.sum) / n

    # covariance of each block's 3x3 neighbourhood, neighbours on the same surface only; each coordinate
    # and each sum an array of its own (whole arrays, not strided slices of one: 3x faster)
    padded = [np.pad(c, 1) for c in (X, Y, Z)]
    okp = np.pad(ok, 1)
    s1 = [np.zeros((gh, gw)) for _ in range(3)]
    s2 = [np.zeros((gh, gw)) for _ in range(6)]
    k = np.zeros((gh, gw))
    iu = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    for dy in range(3):
        for dx in range(3):
            Q = [p[dy : dy + gh, dx : dx + gw] for p in padded]
            m = okp[dy : dy + gh, dx : dx + gw] & ok & (np.abs(Q[2] - Z) <= 3 * cfg.voxel_m)
            D = [np.where(m, q, 0.0) for q in (Q[0] - X, Q[1] - Y, Q[2] - Z)]  # centred on the block
            for c in range(3):
                s1[c] += D[c]
            for c, (i, j) in enumerate(iu):
                s2[c] += D[i] * D[j]
            k += m
    keep = ok & (k >= 4)
    kk = k[keep]
    mean = [s[keep] / kk for s in s1]
    lmin, lmid, nrm = _smallest_eigh3(*(s2[c][keep] / kk - mean[i] * mean[j] for c, (i, j) in enumerate(iu)))
    P = np.stack([X, Y, Z], -1)
    pts = P[keep]
    nrm[(nrm * pts).sum(axis=1) > 0] *= -1.0  # the camera sees the front of every surface
    planar = lmid > _PLANAR_RATIO * np.maximum(lmin, 0.0)
    return Cloud(pts[planar], nrm[planar], K, np.where(ok, Z, 0.0), b)


def overlap(src: Cloud, tgt: Cloud, T_t_s: np.ndarray, tol_m: float, n: int = 400) -> float:
    """Fraction of (a sample of) src that T_t_s puts where tgt saw a surface (within tol_m in depth).

    A view turned far away still projects into the image; what it sees there is another surface, or the
    back of this one, and does not match tgt's depth: an estimate of ICP's fitness before running it."""
    P = apply_transform(T_t_s, src.points[src.spread(n)])
    if not len(P):
        return 0.0
    z = P[:, 2]
    zs = np.where(z > 1e-3, z, 1.0)
    gu = np.floor((tgt.K[0, 0] * P[:, 0] / zs + tgt.K[0, 2] + 0.5) / tgt.block).astype(np.int64)
    gv = np.floor((tgt.K[1, 1] * P[:, 1] / zs + tgt.K[1, 2] + 0.5) / tgt.block).astype(np.int64)
    gh, gw = tgt.grid_z_m.shape
    inside = (z > 1e-3) & (gu >= 0) & (gu < gw) & (gv >= 0) & (gv < gh)
    zt = tgt.grid_z_m[np.where(inside, gv, 0), np.where(inside, gu, 0)]
    return float(np.mean(inside & (zt > 0) & (np.abs(zt - z) <= tol_m)))


def ransac_rigid(A: np.ndarray, B: np.ndarray, cfg: RegistrationConfig, rng: np.random.Generator) -> np.ndarray:
    """The rigid motion with most matches A[i] -> B[i] within 1.5 `fpfh_voxel_m`, from triples that pass
    open3d's checks (edge lengths alike within 10 %, the triple itself within the distance), refined on its
    inliers. Hypotheses in batches of 2000 from `rng`, until `ransac_iterations` or `ransac_confidence`."""
    d2 = (1.5 * cfg.fpfh_voxel_m) ** 2
    m = len(A)
    best, best_T, tried, batch = -1, np.eye(4), 0, 2000
    while tried < cfg.ransac_iterations:
        k = min(batch, cfg.ransac_iterations - tried)
        tried += k
        tri = rng.integers(0, m, size=(k, 3))
        a, b = A[tri], B[tri]
        ok = (tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])
        for i, j in ((0, 1), (1, 2), (0, 2)):
            la = np.sqrt(((a[:, i] - a[:, j]) ** 2).sum(axis=1))
            lb = np.sqrt(((b[:, i] - b[:, j]) ** 2).sum(axis=1))
            ok &= (la > 0.9 * lb) & (lb > 0.9 * la) & (la > 1e-6)
        if not ok.any():
            continue
        T = kabsch(a[ok], b[ok])
        moved = (a[ok][:, :, None, :] * T[:, None, :3, :3]).sum(axis=3) + T[:, None, :3, 3]
        T = T[(((moved - b[ok]) ** 2).sum(axis=2) < d2).all(axis=1)]
        for c0 in range(0, len(T), 500):  # inliers of each hypothesis, 500 at a time (memory)
            Tc = T[c0 : c0 + 500]
            P = (A[None, :, None, :] * Tc[:, None, :3, :3]).sum(axis=3) + Tc[:, None, :3, 3]
            count = (((P - B[None]) ** 2).sum(axis=2) < d2).sum(axis=1)
            i = int(np.argmax(count))  # the first of equals: the same on every run
            if count[i] > best:
                best, best_T = int(count[i]), Tc[i]
        # the confidence stop only after a tenth of the budget: a table plane gives any motion along it
        # many inliers, which would otherwise stop the search at once
        w = best / m
        enough = tried >= cfg.ransac_iterations // 10
        if enough and w > 0 and tried >= np.log(1.0 - cfg.ransac_confidence) / np.log(max(1.0 - w**3, 1e-12)):
            break
    if best < 3:
        return np.eye(4)
    inl = ((apply_transform(best_T, A) - B) ** 2).sum(axis=1) < d2
    return kabsch(A[inl][None], B[inl][None])[0]


class PairRegistrar:
    def __init__(self, clouds: list[Cloud], cfg: RegistrationConfig):
        self.clouds = clouds
        self.cfg = cfg
        self._feat: dict[int, tuple] = {}
        k = len(cfg.icp_distances_m)
        counts = tuple(_ICP_POINTS[max(0, len(_ICP_POINTS) - k + i)] for i in range(k))
        self._samples = [[c.sample(n) for n in counts] for c in clouds]

    def features(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(points (M, 3), FPFH descriptors (M, 33)) of cloud i at `fpfh_voxel_m` (open3d: exact run to run)."""
        if i not in self._feat:
            o3d = quiet_open3d()  # imported only when a guess fails: it takes about a second
            d = self.cfg.fpfh_voxel_m
            down = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(self.clouds[i].points)).voxel_down_sample(d)
            down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=d * 2, max_nn=30))
            down.orient_normals_towards_camera_location(np.zeros(3))
            fpfh = o3d.pipelines.registration.compute_fpfh_feature(
                down, o3d.geometry.KDTreeSearchParamHybrid(radius=d * 5, max_nn=100)
            )
            self._feat[i] = (np.asarray(down.points).copy(), np.asarray(fpfh.data).T.copy())
        return self._feat[i]

    def ransac(self, s: int, t: int) -> np.ndarray:
        """T_t_s from FPFH matches by RANSAC: seeded by (seed, s, t), so the same pair gives the same guess
        whatever ran before (open3d's own RANSAC draws from threads in a varying order: not reproducible)."""
        from scipy.spatial import cKDTree

        (ps, fs), (pt, ft) = self.features(s), self.features(t)
        if len(ps) < 3 or len(pt) < 3:
            return np.eye(4)
        st = cKDTree(ft).query(fs, k=1)[1]
        ts = cKDTree(fs).query(ft, k=1)[1]
        mutual = ts[st] == np.arange(len(fs))
        if mutual.sum() < 10:  # too few mutual matches: every forward match (as open3d does)
            mutual[:] = True
        A, B = ps[mutual], pt[st[mutual]]
        return ransac_rigid(A, B, self.cfg, np.random.default_rng([self.cfg.seed, s, t]))

    def icp(self, s: int, t: int, init: np.ndarray):
        """Multi-scale point-to-plane ICP of cloud s onto cloud t: (T_t_s, fitness, rmse, information) or None.

        Gauss-Newton on p -> R(w) p + v applied on the left; at each scale a fixed sample of the source
        points and nearest target points within that scale's distance."""
        src, tgt = self.clouds[s], self.clouds[t]
        T = np.array(init, np.float64)
        dists = self.cfg.icp_distances_m
        for k, d in enumerate(dists):
            S = src.points[self._samples[s][k]]
            stop = _ICP_STOP[1] if k == len(dists) - 1 else _ICP_STOP[0]
            for _ in range(self.cfg.icp_iterations):
                P = apply_transform(T, S)
                dist, idx = tgt.tree.query(P, k=1, distance_upper_bound=d)
                m = dist < d
                if m.sum() < 6:
                    return None
                p, j = P[m], idx[m]
                nq = tgt.normals[j]
                r = np.sum((p - tgt.points[j]) * nq, axis=1)
                H, g = normal_equations(np.concatenate([np.cross(p, nq), nq], axis=1), r)
                xi = solve_damped(H, g)
                T = se3_exp(xi) @ T
                if np.abs(xi).max() < stop:
                    break
        # fitness, rmse and information at the final pose, on the finest scale's sample
        P = apply_transform(T, S)
        dist, idx = tgt.tree.query(P, k=1, distance_upper_bound=d)
        m = dist < d
        if m.sum() < 6:
            return None
        j = idx[m]
        r = np.sum((P[m] - tgt.points[j]) * tgt.normals[j], axis=1)
        return T, float(m.mean()), float(np.sqrt(np.mean(r * r))), point_information(S[m])

    def edge(self, s: int, t: int, guesses: list[np.ndarray], neighbours: bool) -> Edge | None:
        """The best of ICP from each guess in turn (stopping at the first that fits), then RANSAC if asked.

        With global_init="auto" only neighbours fall back on RANSAC: a loop pair whose chained guess does
        not fit is, far more often than not, a pair that does not overlap after all."""
        cfg = self.cfg
        cands = []
        if cfg.global_init != "always":
            for guess in guesses:
                res = self.icp(s, t, guess)
                if res is not None:
                    cands.append((res, "guess"))
                    if res[1] >= cfg.retry_fitness:
                        break
        if cfg.global_init == "always" or (
            cfg.global_init == "auto" and neighbours and (not cands or max(c[0][1] for c in cands) < cfg.retry_fitness)
        ):
            res = self.icp(s, t, self.ransac(s, t))
            if res is not None:
                cands.append((res, "ransac"))
        if not cands:
            return None
        # more overlap wins; on a tie (within 2 %) the tighter fit
        (T, fit, rmse, info), how = max(cands, key=lambda c: (round(c[0][1] / 0.02), -c[0][2]))
        if fit < cfg.min_fitness:
            return None
        return Edge(s, t, T, fit, rmse, how, info)
