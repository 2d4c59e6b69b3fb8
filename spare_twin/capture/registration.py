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

The parts, one topic a module: `se3` (rigid-motion maths in a fixed summation order), `icp` (a frame as
ICP sees it, pairwise ICP and the RANSAC guess), `pose_graph` (the graph solve and loop-edge pruning);
this module runs them in order: neighbours, a smoothed start, loop pairs, the graph.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

import numpy as np

from spare_twin.capture.checks import fraction, is_number, positive, whole
from spare_twin.capture.frames import rotation_error_deg
from spare_twin.capture.icp import Cloud, Edge, PairRegistrar, frame_cloud, overlap
from spare_twin.capture.pose_graph import optimise
from spare_twin.capture.se3 import axis_angle_deg, invert, normal_equations, turn_deg
from spare_twin.errors import SpareTwinError
from spare_twin.threads import side_by_side

__all__ = [
    "Edge",
    "RegistrationConfig",
    "RegistrationResult",
    "normal_equations",
    "register_frames",
    "relative_pose_errors",
]


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
    keep_reference_within: tuple[float, float] | None = None
    """(degrees, metres): with reference poses, the references are kept as given, and no pose graph
    solved, where the neighbouring pairs' ICP edges agree with the references' motions within both
    (the median over the pairs; at least half of the pairs matched). A near-exact tracker (a rig, a
    robot arm, motion capture) is only made worse by registration: over a sweep of far, flat views
    ICP's own small errors add up (a clean 40-frame render at Kinect distance fused 0.13 mm off its
    chain as given, 15 mm once registered). None: the references always only start it."""
    seed: int = 0
    """seed of the RANSAC fallback (each pair draws from (seed, source, target))."""
    max_motion_jump_deg: float = 8.0
    """without reference poses, a neighbouring pair whose motion turns more than this from the next
    pair's is refined again from the next pair's motion (`registration._smooth_start`); 0: never."""
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
        if self.keep_reference_within is not None:
            if not isinstance(self.keep_reference_within, (tuple, list)) or len(self.keep_reference_within) != 2:
                raise SpareTwinError("keep_reference_within: must be (degrees, metres) or None")
            positive("keep_reference_within degrees", self.keep_reference_within[0], 180.0)
            positive("keep_reference_within metres", self.keep_reference_within[1])
        if self.global_init not in ("auto", "always", "never"):
            raise SpareTwinError(f"global_init {self.global_init!r}: must be auto, always or never")
        for g in self.loop_gaps_frames:
            if not isinstance(g, int) or isinstance(g, bool) or g < 2:
                raise SpareTwinError(
                    f"loop_gaps_frames {g}: each gap must be a whole number >= 2 (1 = neighbours, always there)"
                )


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
    reference_kept: bool = False
    """the reference poses were kept as given: the frames agree with them (`keep_reference_within`)."""

    def summary(self) -> dict:
        return {
            "edges": len(self.edges),
            "loop_edges": sum(abs(e.source - e.target) != 1 for e in self.edges),
            "edges_pruned": self.pruned,
            "edges_from_ransac": sum(e.init == "ransac" for e in self.edges),
            "mean_fitness": float(np.mean([e.fitness for e in self.edges])) if self.edges else None,
            "seconds": {k: round(v, 3) for k, v in self.seconds.items()},
        }


def _smooth_start(R: PairRegistrar, edges: list[Edge], cfg: RegistrationConfig) -> list[np.ndarray]:
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
            return turn_deg(motions[a], motions[a + 1]) <= cfg.max_motion_jump_deg

        for a in range(len(edges) - 3, -1, -1):
            # only a pair that follows on smoothly from its own next one is trusted to restart another
            if smooth(a) or not smooth(a + 1):
                continue
            res = R.icp(edges[a].source, edges[a].target, motions[a + 1])
            if (
                res is not None
                and turn_deg(res[0], motions[a + 1]) <= cfg.max_motion_jump_deg
                and res[1] >= max(cfg.min_fitness, edges[a].fitness - cfg.max_repair_fitness_loss)
            ):
                edges[a] = Edge(edges[a].source, edges[a].target, res[0], res[1], res[2], "smoothed", res[3])
                motions[a] = res[0]
    chain = [np.eye(4)]
    for M in motions:
        chain.append(chain[-1] @ M)
    return chain


def _loop_pairs(clouds: list[Cloud], chain: list[np.ndarray], cfg: RegistrationConfig) -> list[tuple[int, int]]:
    """(source, target) loop pairs: the listed gaps, then the widest-apart pairs (other gaps of 3 or more),
    spread out; each only when the chained poses say that the two views overlap and look the same way."""
    n = len(clouds)
    steps = [axis_angle_deg(chain[a], chain[a + 1]) for a in range(len(chain) - 1)]
    # a sparse capture whose neighbours are already further apart than the limit closes its loop too
    max_angle = max(cfg.loop_max_angle_deg, 1.25 * float(np.median(steps)) if steps else 0.0)
    tol = cfg.icp_distances_m[0]
    seen: dict[tuple[int, int], bool] = {}

    def overlaps(s: int, t: int) -> bool:
        if (s, t) not in seen:
            T = invert(chain[t]) @ chain[s]
            seen[(s, t)] = axis_angle_deg(chain[s], chain[t]) <= max_angle and (
                min(overlap(clouds[s], clouds[t], T, tol), overlap(clouds[t], clouds[s], invert(T), tol))
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
    clouds = side_by_side(lambda f: frame_cloud(f, cfg), frames)
    for i, c in enumerate(clouds):
        if len(c.points) < 100:
            raise SpareTwinError(f"registration: frame {i} has only {len(c.points)} points within {cfg.max_depth_m} m")
    seconds = {"clouds": time.perf_counter() - t0}
    if n == 1:
        poses = np.eye(4)[None] if init_poses is None else np.asarray(init_poses, np.float64)[:1].copy()
        return RegistrationResult(poses, [], seconds)
    R = PairRegistrar(clouds, cfg)
    bar = tqdm(total=n - 1, desc="register", unit="edge", file=sys.stderr, disable=not progress)
    t1 = time.perf_counter()

    # neighbours first: they give the chain that guesses (and selects) every loop edge
    if init_poses is not None:
        init_poses = np.asarray(init_poses, np.float64)
        if init_poses.shape != (n, 4, 4):
            raise SpareTwinError(f"registration: init poses have shape {init_poses.shape}, expected ({n}, 4, 4)")
        chain = [invert(init_poses[0]) @ P for P in init_poses]
    edges: list[Edge] = []
    if init_poses is not None:  # each pair guessed from the references alone: side by side

        def referenced_edge(a: int) -> Edge | None:
            e = R.edge(a + 1, a, [invert(chain[a]) @ chain[a + 1]], neighbours=True)
            bar.update(1)
            return e

        edges = [e for e in side_by_side(referenced_edge, range(n - 1)) if e is not None]
    else:  # each pair guessed from the previous pair's motion, then none: in turn
        motion = np.eye(4)
        for a in range(n - 1):
            e = R.edge(a + 1, a, [motion, np.eye(4)] if a else [np.eye(4)], neighbours=True)
            bar.update(1)
            if e is None:
                raise SpareTwinError(
                    f"registration: frames {a} and {a + 1} do not overlap (ICP fitness below "
                    f"{cfg.min_fitness}); record more slowly or lower voxel_m"
                )
            edges.append(e)
            motion = e.T_target_source
        chain = _smooth_start(R, edges, cfg)  # the chain of the neighbours' motions, their start smoothed
    loops = _loop_pairs(clouds, chain, cfg)
    bar.total += len(loops)
    bar.refresh()
    for c in clouds:  # built once here, not raced for by the threads below
        _ = c.tree

    def loop_edge(pair: tuple[int, int]) -> Edge | None:
        s, t = pair
        e = R.edge(s, t, [invert(chain[t]) @ chain[s]], neighbours=False)
        bar.update(1)
        return e

    # each loop edge starts from the chain alone, so they are independent: side by side, in their order
    edges += [e for e in side_by_side(loop_edge, loops) if e is not None]
    bar.close()
    seconds["edges"] = time.perf_counter() - t1

    if init_poses is not None and _agrees_with_reference(edges, chain, n, cfg):
        return RegistrationResult(init_poses.copy(), edges, seconds, 0, reference_kept=True)
    t2 = time.perf_counter()
    graph = list(edges)
    if init_poses is not None and cfg.reference_weight > 0:  # the references' own motions, as edges
        for e in [e for e in edges if abs(e.source - e.target) == 1]:
            ref = invert(chain[e.target]) @ chain[e.source]
            # weight: information x fitness, as the ICP edge's, times reference_weight
            graph.append(
                Edge(e.source, e.target, ref, 1.0, 0.0, "reference", e.information * e.fitness * cfg.reference_weight)
            )
    poses, kept, pruned = optimise(np.array(chain), graph, cfg)
    kept = [e for e in kept if e.init != "reference"]  # the result lists what registration measured
    poses = np.array([invert(poses[0]) @ P for P in poses])
    poses[0] = np.eye(4)  # exactly
    if init_poses is not None:
        poses = np.array([init_poses[0] @ P for P in poses])
    seconds["pose_graph"] = time.perf_counter() - t2
    return RegistrationResult(poses, kept, seconds, pruned)


def _agrees_with_reference(edges: list[Edge], chain: list[np.ndarray], n: int, cfg: RegistrationConfig) -> bool:
    """Whether the neighbouring pairs' edges agree with the reference motions `chain` within
    `cfg.keep_reference_within` (median over at least half of the n - 1 pairs)."""
    if cfg.keep_reference_within is None:
        return False
    max_deg, max_m = cfg.keep_reference_within
    off = []
    for e in edges:
        if abs(e.source - e.target) == 1:
            E = invert(invert(chain[e.target]) @ chain[e.source]) @ e.T_target_source
            off.append((rotation_error_deg(E[:3, :3]), float(np.linalg.norm(E[:3, 3]))))
    if len(off) < max(1, (n - 1) / 2):
        return False
    median_deg, median_m = np.median(np.array(off), axis=0)
    return bool(median_deg <= max_deg and median_m <= max_m)


def relative_pose_errors(poses: np.ndarray, reference: np.ndarray, gap: int) -> np.ndarray:
    """(M, 2): rotation error (deg) and translation error (mm) of every relative pose `gap` frames apart."""
    out = []
    for a in range(len(poses) - gap):
        est = np.linalg.inv(poses[a]) @ poses[a + gap]
        ref = np.linalg.inv(reference[a]) @ reference[a + gap]
        E = np.linalg.inv(ref) @ est
        out.append((rotation_error_deg(E[:3, :3]), 1000.0 * float(np.linalg.norm(E[:3, 3]))))
    return np.array(out).reshape(-1, 2)
