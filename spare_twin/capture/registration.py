"""Camera poses from RGB-D frames: chained ICP, a few loop closures, a deterministic pose graph.

For a sequence of frames from one moving camera (or several cameras viewing one scene):

1. each frame becomes a cloud with normals straight from its depth image: blocks of pixels about
   `voxel_m` wide at the frame's median depth, each averaged into one point, its normal from the
   block and its 3x3 grid neighbours on the same surface;
2. pairwise edges, each refined by multi-scale point-to-plane ICP (Gauss-Newton in numpy; normal-space
   sampling keeps every point of the object and thins the table at the coarse scales) from a guess:
   - every neighbouring pair, guessed from the reference poses when given, else from the previous
     pair's motion (a hand-held sweep is smooth), else from no motion;
   - loop pairs `loop_gaps_frames` apart, and up to `loop_closures` pairs further apart (widest gap
     first, spread over the sequence): the closing of a sweep that comes round, a path that turns
     back. A loop pair is tried only when the chained poses say that the two views overlap (at least
     `min_overlap` of each lands on the other's surfaces) and look the same way (optical axes within
     `loop_max_angle_deg`, or 1.25 neighbour steps for a sparse capture): a 360 degree sweep spends no
     time on pairs facing opposite ways, and a table seen from two sides does not pull the turn.
   When a neighbour's guess does not converge (fitness below `retry_fitness`) or `global_init="always"`,
   a global guess from FPFH features (open3d) + RANSAC (numpy, seeded per pair) is refined too and the
   better kept;
3. a pose graph over all edges, solved by Gauss-Newton on the poses; a loop edge off the solution by
   more than `loop_reject_deg` or `loop_reject_m` is dropped, worst first, and the graph solved again.

Why loop closures rather than neighbours only: chaining neighbouring ICP results drifts (about 5 deg
over 40 frames on the APC shelf sweep; 2-6 deg by the time a 360 degree hand-held sweep comes round);
edges two frames apart and a handful across the seam spread that drift out. Why so few: on the test
captures more and wider edges (the 125 of gaps 2..40 before) cost 20-40x the time and ended no closer to
the truth (figures in docs/capture.md).

Determinism: the same frames give byte-identical poses in every process on one machine (checked
across processes, RANSAC fallback included). open3d's point-to-plane ICP and pose-graph optimisation
do not (reductions across threads in a varying order: ~1e-15 in one ICP, amplified to 1e-8..3e-7 in the
poses), nor does its RANSAC (threads draw from the generator in a varying order). So all three are
done here in numpy and scipy: every sum in a fixed order (numpy's own reductions, no BLAS products
over points, whose threading may reorder them), nearest neighbours from cKDTree (exact), the pose
graph solved by SuperLU (single-threaded), RANSAC seeded by (seed, pair). What it costs: the same
ICP on the same points takes 21 ms of CPU per edge in numpy against 14 ms in open3d (1.5x; about
0.4 s of a 30-frame capture's 63 edges); the pose graph costs ~0.1 s. The fewer, cheaper edges more
than pay for it: a 30-frame 640x480 hand-held capture took 60-220 s before, 2-4 s now (docs/capture.md).
open3d is left computing FPFH features (exact run to run), imported only when a guess fails.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

import numpy as np

from spare_twin.capture.checks import fraction, is_number, positive, whole
from spare_twin.capture.frames import quiet_open3d, rotation_error_deg
from spare_twin.errors import SpareTwinError

#: Source points per ICP at each scale, coarse to fine (the finest takes every point of a 640x480 frame
#: at 4 mm): with a stride sample of half the points the turn about the vertical was 1.3-1.5x further
#: off, because it rests on the few points of the object.
_ICP_POINTS = (800, 1600, 8000)
#: ICP stops at a scale when an update turns and moves less than this (rad and m): coarse scales, finest.
_ICP_STOP = (1e-3, 1e-4)
#: A block's neighbourhood whose middle principal axis is not this many times its smallest is no plane
#: (an edge, a thin rod seen end-on): it gives no point.
_PLANAR_RATIO = 4.0


@dataclass(frozen=True)
class RegistrationConfig:
    """Registration settings (lengths in metres). Defaults suit table-top scenes 0.2..2 m away."""

    voxel_m: float = 0.004
    """spacing of the cloud points used for ICP (pixel blocks this wide at the median depth)."""
    max_depth_m: float = 2.0
    """depth beyond this is ignored (far readings are noisy and rarely on the object)."""
    icp_distances_m: tuple[float, ...] = (0.03, 0.015, 0.008)
    """coarse-to-fine ICP correspondence distances; the last also gives each edge's fitness."""
    icp_iterations: int = 10
    """at most this many Gauss-Newton steps per scale (most stop after 3-8; more bought nothing)."""
    loop_gaps_frames: tuple[int, ...] = (2,)
    """loop edges between frames this many positions apart, besides neighbours (when they overlap)."""
    loop_closures: int = 6
    """at most this many further loop edges, between the farthest-apart frames that overlap."""
    min_overlap: float = 0.3
    """a loop pair is tried only when the chained poses put this fraction of each view on the other's surfaces,"""
    loop_max_angle_deg: float = 40.0
    """... and their optical axes less than this apart (or 1.25 median neighbour steps, when more): a table
    seen from two sides overlaps well, but the object on it is seen from its two sides and ICP, matching
    the table, gets the turn wrong by degrees."""
    min_fitness: float = 0.2
    """an edge whose ICP fitness (overlapping fraction) is below this is dropped."""
    global_init: str = "auto"
    """"auto": FPFH + RANSAC when a neighbour's guess fails; "always": on every edge; "never"."""
    retry_fitness: float = 0.3
    """with global_init="auto", a neighbour refined from its guess to below this fitness also tries RANSAC."""
    fpfh_voxel_m: float = 0.02
    ransac_iterations: int = 100000
    ransac_confidence: float = 0.999
    loop_reject_deg: float = 3.0
    loop_reject_m: float = 0.03
    """a loop edge off the solved pose graph by more than either is dropped (a wrong match)."""
    reference_weight: float = 3.0
    """with reference poses, each neighbouring pair's reference motion joins the pose graph as an edge
    this many times as certain as the pair's ICP edge. References come from a tracker, a calibrated
    rig or the simulator and are usually better than one ICP edge on a thin object: with the true
    poses as references, 1.3 deg of mean pairwise error with ICP alone, 0.25 deg with 3 (0.6 deg
    before). 0: ICP alone, the references only start it."""
    seed: int = 0
    """seed of the RANSAC fallback (each pair draws from (seed, source, target))."""
    max_motion_jump_deg: float = 8.0
    """without reference poses, a neighbouring pair whose motion turns more than this from the next
    pair's is refined again from the next pair's motion (`_smooth_start`); 0: never."""
    max_repair_fitness_loss: float = 0.05
    """... and the new result is kept when it agrees with the next pair's motion and its fitness is at
    most this much below the first result's."""

    def __post_init__(self):
        for name in ("voxel_m", "max_depth_m", "fpfh_voxel_m", "loop_reject_deg", "loop_reject_m"):
            positive(name, getattr(self, name))
        if not is_number(self.reference_weight) or self.reference_weight < 0:
            raise SpareTwinError(f"reference_weight {self.reference_weight}: must be a number of at least 0")
        positive("loop_max_angle_deg", self.loop_max_angle_deg, 180.0)
        if not self.icp_distances_m:
            raise SpareTwinError("icp_distances_m: must name at least one ICP distance")
        for d in self.icp_distances_m:
            positive("icp_distances_m", d)
        if not is_number(self.max_motion_jump_deg) or not 0 <= self.max_motion_jump_deg <= 180:
            raise SpareTwinError(f"max_motion_jump_deg {self.max_motion_jump_deg}: must be a number in 0..180")
        for name in ("min_fitness", "retry_fitness", "ransac_confidence", "min_overlap", "max_repair_fitness_loss"):
            fraction(name, getattr(self, name))
        whole("icp_iterations", self.icp_iterations, 1)
        whole("loop_closures", self.loop_closures, 0)
        whole("ransac_iterations", self.ransac_iterations, 1)
        whole("seed", self.seed, 0)
        if self.global_init not in ("auto", "always", "never"):
            raise SpareTwinError(f"global_init {self.global_init!r}: must be auto, always or never")
        for g in self.loop_gaps_frames:
            if not isinstance(g, int) or isinstance(g, bool) or g < 2:
                raise SpareTwinError(
                    f"loop_gaps_frames {g}: each gap must be a whole number >= 2 (1 = neighbours, always there)"
                )


@dataclass
class Edge:
    """One pairwise result: T_target_source maps source-frame points into the target frame."""

    source: int
    target: int
    T_target_source: np.ndarray
    fitness: float
    rmse_m: float
    init: str
    """"guess", "ransac" or "smoothed" (`_smooth_start`): where the kept result started."""
    information: np.ndarray | None = None
    """(6, 6) information per matched point, source frame (rotation vector, translation): the edge's
    weight in the pose graph, times its fitness."""


@dataclass
class RegistrationResult:
    poses: np.ndarray
    """(N, 4, 4) camera-to-world; world = the first frame's camera (or the reference world)."""
    edges: list[Edge] = field(default_factory=list)
    """the edges the pose graph kept."""
    seconds: dict = field(default_factory=dict)
    """wall seconds per step: clouds, edges, pose_graph (their sum: the registration's time)."""
    pruned: int = 0
    """loop edges the pose graph dropped as inconsistent."""

    def summary(self) -> dict:
        return {
            "edges": len(self.edges),
            "loop_edges": sum(abs(e.source - e.target) != 1 for e in self.edges),
            "edges_pruned": self.pruned,
            "edges_from_ransac": sum(e.init == "ransac" for e in self.edges),
            "mean_fitness": float(np.mean([e.fitness for e in self.edges])) if self.edges else None,
            "seconds": {k: round(v, 3) for k, v in self.seconds.items()},
        }


# ---------------------------------------------------------------------------------------------------------------
# rigid-motion helpers, written out so that every sum over points has a fixed order (no BLAS)


def _apply(T: np.ndarray, P: np.ndarray) -> np.ndarray:
    """T (4x4) applied to points P (N, 3)."""
    R = T[:3, :3]
    return P[:, 0:1] * R[:, 0] + P[:, 1:2] * R[:, 1] + P[:, 2:3] * R[:, 2] + T[:3, 3]


def _skew(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _step(xi: np.ndarray) -> np.ndarray:
    """The 4x4 motion of an update xi = (rotation vector w, translation v): p -> R(w) p + v."""
    w = xi[:3]
    th = float(np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]))
    W = _skew(w)
    D = np.eye(4)
    if th < 1e-12:
        D[:3, :3] += W
    else:
        D[:3, :3] += (np.sin(th) / th) * W + ((1.0 - np.cos(th)) / (th * th)) * (W @ W)
    D[:3, 3] = xi[3:]
    return D


def _rotvec(R: np.ndarray) -> np.ndarray:
    c = np.clip((R[0, 0] + R[1, 1] + R[2, 2] - 1.0) / 2.0, -1.0, 1.0)
    th = float(np.arccos(c))
    a = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-6:
        return a / 2.0
    if th > np.pi - 1e-4:  # near 180 degrees: the axis from the symmetric part
        k = int(np.argmax(np.diag(R)))
        v = (R[:, k] + R[k, :]) / 2.0
        v[k] = np.sqrt(max((R[k, k] + 1.0) / 2.0, 0.0))
        v /= np.linalg.norm(v)
        return th * v * (1.0 if float(np.dot(v, a)) >= 0 else -1.0)
    return a * (th / (2.0 * np.sin(th)))


def _inv(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -(T[:3, :3].T @ T[:3, 3])
    return out


def normal_equations(J: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """J^T J (k x k) and J^T r of point rows J (N, k), summed in a fixed order (numpy's pairwise sum per
    entry): a BLAS product over the points may split them across threads and add the parts in any order."""
    k = J.shape[1]
    H = np.empty((k, k))
    g = np.empty(k)
    for i in range(k):
        g[i] = np.sum(J[:, i] * r)
        for j in range(i, k):
            H[i, j] = H[j, i] = np.sum(J[:, i] * J[:, j])
    return H, g


def _solve6(H: np.ndarray, g: np.ndarray) -> np.ndarray:
    """-H^-1 g, lightly damped so that a direction the points do not constrain (a plane's slide) stays put."""
    lam = 1e-9 * max(float(np.trace(H)), 1e-30)
    return -np.linalg.solve(H + lam * np.eye(6), g)


def _point_information(q: np.ndarray) -> np.ndarray:
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
    H[:3, 3:] = _skew(c)
    H[3:, :3] = -_skew(c)
    H[3:, 3:] = np.eye(3)
    return H


# ---------------------------------------------------------------------------------------------------------------
# clouds


@dataclass
class _Cloud:
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


def _block_reduce(a: np.ndarray, b: int, how) -> np.ndarray:
    """how (np.sum, np.max, np.min) over b x b pixel blocks of an (H, W) array cropped to whole blocks."""
    gh, gw = a.shape[0] // b, a.shape[1] // b
    return how(how(a[: gh * b, : gw * b].reshape(gh * b, gw, b), axis=2).reshape(gh, b, gw), axis=1)


def _smallest_eigh3(c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smallest and middle eigenvalues, and the smallest's unit eigenvector, of symmetric 3x3 matrices
    given as (N, 6) upper triangles (xx, xy, xz, yy, yz, zz): closed form, 10x faster than batched eigh."""
    xx, xy, xz, yy, yz, zz = (c[:, i] for i in range(6))
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
    rows = np.arange(len(c))
    return lmin, lmid, cands[rows, best] / np.maximum(norms[rows, best], 1e-300)[:, None]


def _cloud(frame, cfg: RegistrationConfig) -> _Cloud:
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
        return _Cloud(np.zeros((0, 3)), np.zeros((0, 3)), K, np.zeros((1, 1)), 1)
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
    P = np.stack([_block_reduce(z * u[None, :], b, np.sum) / n, _block_reduce(z * v[:, None], b, np.sum) / n, Z], -1)

    # covariance of each block's 3x3 neighbourhood, neighbours on the same surface only
    pad = np.pad(P, ((1, 1), (1, 1), (0, 0)))
    okp = np.pad(ok, 1)
    s1 = np.zeros((gh, gw, 3))
    s2 = np.zeros((gh, gw, 6))
    k = np.zeros((gh, gw))
    iu = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    for dy in range(3):
        for dx in range(3):
            Q = pad[dy : dy + gh, dx : dx + gw]
            m = okp[dy : dy + gh, dx : dx + gw] & ok & (np.abs(Q[..., 2] - Z) <= 3 * cfg.voxel_m)
            D = np.where(m[..., None], Q - P, 0.0)  # centred on the block: better conditioned
            s1 += D
            for c, (i, j) in enumerate(iu):
                s2[..., c] += D[..., i] * D[..., j]
            k += m
    keep = ok & (k >= 4)
    kk = k[keep][:, None]
    mean = s1[keep] / kk
    cov = s2[keep] / kk - np.stack([mean[:, i] * mean[:, j] for i, j in iu], axis=1)
    lmin, lmid, nrm = _smallest_eigh3(cov)
    pts = P[keep]
    nrm[(nrm * pts).sum(axis=1) > 0] *= -1.0  # the camera sees the front of every surface
    planar = lmid > _PLANAR_RATIO * np.maximum(lmin, 0.0)
    return _Cloud(pts[planar], nrm[planar], K, np.where(ok, Z, 0.0), b)


def _overlap(src: _Cloud, tgt: _Cloud, T_t_s: np.ndarray, tol_m: float, n: int = 400) -> float:
    """Fraction of (a sample of) src that T_t_s puts where tgt saw a surface (within tol_m in depth).

    A view turned far away still projects into the image; what it sees there is another surface, or the
    back of this one, and does not match tgt's depth: an estimate of ICP's fitness before running it."""
    P = _apply(T_t_s, src.points[src.spread(n)])
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


# ---------------------------------------------------------------------------------------------------------------
# pairwise


def _kabsch(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(K, 4, 4) rigid motions taking point sets A (K, m, 3) onto B (K, m, 3), least squares (no scale)."""
    ca, cb = A.mean(axis=1), B.mean(axis=1)
    a, b = A - ca[:, None], B - cb[:, None]
    H = (a[:, :, :, None] * b[:, :, None, :]).sum(axis=1)
    U, _, Vt = np.linalg.svd(H)
    V = np.swapaxes(Vt, 1, 2)
    D = np.ones((len(A), 3))
    D[:, 2] = np.sign(np.linalg.det(V @ np.swapaxes(U, 1, 2)))
    R = (V * D[:, None, :]) @ np.swapaxes(U, 1, 2)
    T = np.zeros((len(A), 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = cb - (R * ca[:, None, :]).sum(axis=2)
    T[:, 3, 3] = 1.0
    return T


def _ransac_rigid(A: np.ndarray, B: np.ndarray, cfg: RegistrationConfig, rng: np.random.Generator) -> np.ndarray:
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
        T = _kabsch(a[ok], b[ok])
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
    inl = ((_apply(best_T, A) - B) ** 2).sum(axis=1) < d2
    return _kabsch(A[inl][None], B[inl][None])[0]


class _Registrar:
    def __init__(self, clouds: list[_Cloud], cfg: RegistrationConfig):
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
        return _ransac_rigid(A, B, self.cfg, np.random.default_rng([self.cfg.seed, s, t]))

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
                P = _apply(T, S)
                dist, idx = tgt.tree.query(P, k=1, distance_upper_bound=d)
                m = dist < d
                if m.sum() < 6:
                    return None
                p, j = P[m], idx[m]
                nq = tgt.normals[j]
                r = np.sum((p - tgt.points[j]) * nq, axis=1)
                H, g = normal_equations(np.concatenate([np.cross(p, nq), nq], axis=1), r)
                xi = _solve6(H, g)
                T = _step(xi) @ T
                if np.abs(xi).max() < stop:
                    break
        # fitness, rmse and information at the final pose, on the finest scale's sample
        P = _apply(T, S)
        dist, idx = tgt.tree.query(P, k=1, distance_upper_bound=d)
        m = dist < d
        if m.sum() < 6:
            return None
        j = idx[m]
        r = np.sum((P[m] - tgt.points[j]) * tgt.normals[j], axis=1)
        return T, float(m.mean()), float(np.sqrt(np.mean(r * r))), _point_information(S[m])

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


def _smooth_start(R: _Registrar, edges: list[Edge], cfg: RegistrationConfig) -> list[np.ndarray]:
    """The chained poses after the neighbouring pairs' edges (`edges`, pair a at index a, replaced in
    place) are made to follow a smooth path from the end backwards. The first pair has no motion to
    start from; from none, on a sparse sweep (11-28 deg between frames), ICP settles with the table
    matched and the object turned 10-40 deg, and each next pair, started from that motion, follows it
    until one escapes. Its fitness cannot tell (the table is most of the overlap: 0.93 wrong against
    0.90 right), the path's smoothness can: a hand-held camera's motion changes by a few degrees
    from one pair to the next (at most 4.1 deg on 120 simulated sweeps). So a pair whose motion turns
    more than `max_motion_jump_deg` from the next pair's, where that one follows on smoothly from its
    own next, is refined again from the next pair's motion, and the result kept when it agrees with
    it and fits about as well."""
    motions = [e.T_target_source for e in edges]
    if cfg.max_motion_jump_deg > 0:

        def smooth(a: int) -> bool:
            return _turn_deg(motions[a], motions[a + 1]) <= cfg.max_motion_jump_deg

        for a in range(len(edges) - 3, -1, -1):
            # only a pair that follows on smoothly from its own next one is trusted to restart another
            if smooth(a) or not smooth(a + 1):
                continue
            res = R.icp(edges[a].source, edges[a].target, motions[a + 1])
            if (
                res is not None
                and _turn_deg(res[0], motions[a + 1]) <= cfg.max_motion_jump_deg
                and res[1] >= max(cfg.min_fitness, edges[a].fitness - cfg.max_repair_fitness_loss)
            ):
                edges[a] = Edge(edges[a].source, edges[a].target, res[0], res[1], res[2], "smoothed", res[3])
                motions[a] = res[0]
    chain = [np.eye(4)]
    for M in motions:
        chain.append(chain[-1] @ M)
    return chain


def _turn_deg(A: np.ndarray, B: np.ndarray) -> float:
    """Rotation (degrees) between the rotations of two rigid motions."""
    return rotation_error_deg(A[:3, :3].T @ B[:3, :3])


# ---------------------------------------------------------------------------------------------------------------
# loop pairs and pose graph


def _axis_angle_deg(A: np.ndarray, B: np.ndarray) -> float:
    """Angle between two cameras' optical axes (degrees)."""
    return float(np.degrees(np.arccos(np.clip(np.dot(A[:3, 2], B[:3, 2]), -1.0, 1.0))))


def _loop_pairs(clouds: list[_Cloud], chain: list[np.ndarray], cfg: RegistrationConfig) -> list[tuple[int, int]]:
    """(source, target) loop pairs: the listed gaps, then the widest-apart pairs (other gaps of 3 or more),
    spread out; each only when the chained poses say that the two views overlap and look the same way."""
    n = len(clouds)
    steps = [_axis_angle_deg(chain[a], chain[a + 1]) for a in range(len(chain) - 1)]
    # a sparse capture whose neighbours are already further apart than the limit closes its loop too
    max_angle = max(cfg.loop_max_angle_deg, 1.25 * float(np.median(steps)) if steps else 0.0)
    tol = cfg.icp_distances_m[0]
    seen: dict[tuple[int, int], bool] = {}

    def overlaps(s: int, t: int) -> bool:
        if (s, t) not in seen:
            T = _inv(chain[t]) @ chain[s]
            seen[(s, t)] = _axis_angle_deg(chain[s], chain[t]) <= max_angle and (
                min(_overlap(clouds[s], clouds[t], T, tol), _overlap(clouds[t], clouds[s], _inv(T), tol))
                >= cfg.min_overlap
            )
        return seen[(s, t)]

    pairs = [(a + g, a) for g in cfg.loop_gaps_frames for a in range(n - g) if overlaps(a + g, a)]
    picked: list[tuple[int, int]] = []
    spacing = max(1, n // (4 * max(cfg.loop_closures, 1)))
    for g in range(n - 1, 2, -1):
        if g in cfg.loop_gaps_frames:
            continue
        for a in range(n - g):
            if len(picked) >= cfg.loop_closures:
                return pairs + picked
            s, t = a + g, a
            near = any(abs(s - ps) <= spacing and abs(t - pt) <= spacing for ps, pt in picked)
            if not near and overlaps(s, t):
                picked.append((s, t))
    return pairs + picked


def _edge_residual(poses: np.ndarray, e: Edge) -> np.ndarray:
    """(rotation vector, translation) of Z^-1 T_t^-1 T_s: the edge's disagreement, in the source frame."""
    E = _inv(e.T_target_source) @ _inv(poses[e.target]) @ poses[e.source]
    return np.concatenate([_rotvec(E[:3, :3]), E[:3, 3]])


def _solve_graph(poses: np.ndarray, edges: list[Edge], iterations: int = 20) -> np.ndarray:
    """Gauss-Newton over the poses (node 0 fixed) minimising sum of r_e^T W_e r_e.

    Poses are updated on the left (T_i <- D(xi_i) T_i, world frame); to first order the residual of edge
    s -> t then changes by Ad(T_s^-1) (xi_s - xi_t). W_e is the edge's information per point times its
    fitness. The sparse system is solved by SuperLU (single-threaded: the same sums on every run)."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import spsolve

    n = len(poses)
    poses = poses.copy()
    if n < 2 or not edges:
        return poses
    # a node without edges (a reference-pose run whose pair failed) stays where it is
    prior = 1e-8 * float(np.mean([np.trace(e.information) for e in edges]))
    for _ in range(iterations):
        blocks: dict[tuple[int, int], np.ndarray] = {}
        b = np.zeros(6 * n)
        for e in edges:
            Rt, t = poses[e.source][:3, :3].T, poses[e.source][:3, 3]
            A = np.zeros((6, 6))
            A[:3, :3] = Rt
            A[3:, 3:] = Rt
            A[3:, :3] = -Rt @ _skew(t)
            AtW = A.T @ (e.information * e.fitness)
            M = AtW @ A
            g = AtW @ _edge_residual(poses, e)
            s, q = e.source, e.target
            for key, sign in (((s, s), 1.0), ((q, q), 1.0), ((s, q), -1.0), ((q, s), -1.0)):
                blocks[key] = blocks.get(key, 0.0) + sign * M
            b[6 * s : 6 * s + 6] += g
            b[6 * q : 6 * q + 6] -= g
        rows, cols, vals = [], [], []
        for (i, j), M in sorted(blocks.items()):
            if i == 0 or j == 0:  # node 0 is fixed
                continue
            ii, jj = np.meshgrid(np.arange(6 * i - 6, 6 * i), np.arange(6 * j - 6, 6 * j), indexing="ij")
            rows.append(ii.ravel())
            cols.append(jj.ravel())
            vals.append(np.ravel(M))
        m = 6 * (n - 1)
        rows.append(np.arange(m))
        cols.append(np.arange(m))
        vals.append(np.full(m, prior))
        H = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(m, m))
        dx = -np.asarray(spsolve(H, b[6:])).reshape(-1, 6)
        for i in range(1, n):
            poses[i] = _step(dx[i - 1]) @ poses[i]
        if np.abs(dx).max() < 1e-9:
            break
    return poses


def _optimise(poses: np.ndarray, edges: list[Edge], cfg: RegistrationConfig) -> tuple[np.ndarray, list[Edge], int]:
    """Solve; drop the loop edge that disagrees most with the solution when beyond the limits; repeat."""
    kept = list(edges)
    pruned = 0
    while True:
        sol = _solve_graph(poses, kept)
        worst, worst_k = 1.0, -1
        for k, e in enumerate(kept):
            if abs(e.source - e.target) == 1:
                continue
            r = _edge_residual(sol, e)
            off = max(
                np.degrees(np.linalg.norm(r[:3])) / cfg.loop_reject_deg, np.linalg.norm(r[3:]) / cfg.loop_reject_m
            )
            if off > worst:
                worst, worst_k = off, k
        if worst_k < 0:
            return sol, kept, pruned
        del kept[worst_k]
        pruned += 1


# ---------------------------------------------------------------------------------------------------------------


def register_frames(
    frames, cfg: RegistrationConfig = RegistrationConfig(), init_poses: np.ndarray | None = None, progress: bool = True
) -> RegistrationResult:
    """Camera-to-world poses of `frames` (spare_twin.capture.frames.RGBDFrame list).

    `init_poses` (N, 4, 4): reference or approximate poses used as initial guesses; the result is then
    expressed in their world (anchored at frame 0). Without them, world = frame 0's camera.
    The same frames and settings give byte-identical poses on every run.
    """
    from tqdm import tqdm

    n = len(frames)
    if n == 0:
        raise SpareTwinError("registration: no frames")
    t0 = time.perf_counter()
    clouds = [_cloud(f, cfg) for f in frames]
    for i, c in enumerate(clouds):
        if len(c.points) < 100:
            raise SpareTwinError(f"registration: frame {i} has only {len(c.points)} points within {cfg.max_depth_m} m")
    seconds = {"clouds": time.perf_counter() - t0}
    if n == 1:
        poses = np.eye(4)[None] if init_poses is None else np.asarray(init_poses, np.float64)[:1].copy()
        return RegistrationResult(poses, [], seconds)
    R = _Registrar(clouds, cfg)
    bar = tqdm(total=n - 1, desc="register", unit="edge", file=sys.stderr, disable=not progress)
    t1 = time.perf_counter()

    # neighbours first: they give the chain that guesses (and selects) every loop edge
    if init_poses is not None:
        init_poses = np.asarray(init_poses, np.float64)
        if init_poses.shape != (n, 4, 4):
            raise SpareTwinError(f"registration: init poses have shape {init_poses.shape}, expected ({n}, 4, 4)")
        chain = [_inv(init_poses[0]) @ P for P in init_poses]
    edges: list[Edge] = []
    motion = np.eye(4)
    for a in range(n - 1):
        if init_poses is not None:
            guesses = [_inv(chain[a]) @ chain[a + 1]]
        else:  # the previous pair's motion, then none
            guesses = [motion, np.eye(4)] if a else [np.eye(4)]
        e = R.edge(a + 1, a, guesses, neighbours=True)
        bar.update(1)
        if e is None:
            if init_poses is None:
                raise SpareTwinError(
                    f"registration: frames {a} and {a + 1} do not overlap (ICP fitness below "
                    f"{cfg.min_fitness}); record more slowly or lower voxel_m"
                )
            continue
        edges.append(e)
        motion = e.T_target_source
    if init_poses is None:  # the chain of the neighbours' motions, their start smoothed
        chain = _smooth_start(R, edges, cfg)
    loops = _loop_pairs(clouds, chain, cfg)
    bar.total += len(loops)
    bar.refresh()
    for s, t in loops:
        e = R.edge(s, t, [_inv(chain[t]) @ chain[s]], neighbours=False)
        bar.update(1)
        if e is not None:
            edges.append(e)
    bar.close()
    seconds["edges"] = time.perf_counter() - t1

    t2 = time.perf_counter()
    graph = list(edges)
    if init_poses is not None and cfg.reference_weight > 0:  # the references' own motions, as edges
        for e in [e for e in edges if abs(e.source - e.target) == 1]:
            ref = _inv(chain[e.target]) @ chain[e.source]
            # weight: information x fitness, as the ICP edge's, times reference_weight
            graph.append(
                Edge(e.source, e.target, ref, 1.0, 0.0, "reference", e.information * e.fitness * cfg.reference_weight)
            )
    poses, kept, pruned = _optimise(np.array(chain), graph, cfg)
    kept = [e for e in kept if e.init != "reference"]  # the result lists what registration measured
    poses = np.array([_inv(poses[0]) @ P for P in poses])
    poses[0] = np.eye(4)  # exactly
    if init_poses is not None:
        poses = np.array([init_poses[0] @ P for P in poses])
    seconds["pose_graph"] = time.perf_counter() - t2
    return RegistrationResult(poses, kept, seconds, pruned)


def relative_pose_errors(poses: np.ndarray, reference: np.ndarray, gap: int) -> np.ndarray:
    """(M, 2): rotation error (deg) and translation error (mm) of every relative pose `gap` frames apart."""
    out = []
    for a in range(len(poses) - gap):
        est = np.linalg.inv(poses[a]) @ poses[a + gap]
        ref = np.linalg.inv(reference[a]) @ reference[a + gap]
        E = np.linalg.inv(ref) @ est
        out.append((rotation_error_deg(E[:3, :3]), 1000.0 * float(np.linalg.norm(E[:3, 3]))))
    return np.array(out).reshape(-1, 2)
