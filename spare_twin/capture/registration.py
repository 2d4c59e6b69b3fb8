"""Camera poses from RGB-D frames: global initialisation, ICP, pose-graph optimisation.

For a sequence of frames from one moving camera (or several cameras viewing one scene):

1. each frame becomes a voxel-downsampled point cloud with normals (and colours);
2. pairwise edges: every neighbouring pair, plus "loop" pairs `loop_gaps_frames` apart. Each edge is
   refined by multi-scale point-to-plane ICP (coloured ICP at the finest scale when `colored_icp`)
   from an initial guess: the current chain of neighbouring edges, or the reference poses when given.
   When that guess does not converge (fitness below `retry_fitness`) or `global_init="always"`, a
   global guess from FPFH features + RANSAC is refined too, and the better of the two kept;
3. open3d's pose-graph optimisation (multiway registration) over all edges, with loop edges marked
   uncertain so that wrong matches are pruned.

Why loop edges every few gaps rather than neighbours only: chaining neighbouring ICP results drifts
(on the APC shelf frames about 5 deg over 40 frames); edges spanning 2..40 frames pin that down to
about 1 deg (figures in docs/capture.md).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

import numpy as np

from spare_twin.capture.checks import fraction, positive, whole
from spare_twin.capture.frames import o3d_intrinsic, rotation_error_deg, to_o3d_rgbd
from spare_twin.errors import SpareTwinError


@dataclass(frozen=True)
class RegistrationConfig:
    """Registration settings (lengths in metres). Defaults suit table-top scenes 0.2..2 m away."""

    voxel_m: float = 0.005
    """voxel size of the clouds used for ICP."""
    max_depth_m: float = 2.0
    """depth beyond this is ignored (far readings are noisy and rarely on the object)."""
    icp_distances_m: tuple[float, ...] = (0.03, 0.015, 0.008)
    """coarse-to-fine ICP correspondence distances; the last also weighs the pose-graph edges."""
    icp_iterations: int = 50
    colored_icp: bool = False
    """coloured ICP at the finest scale (helps on flat, textured scenes; slower)."""
    loop_gaps_frames: tuple[int, ...] = (2, 4, 8, 16, 24, 32, 40)
    """extra edges between frames this many positions apart, besides neighbours."""
    min_fitness: float = 0.2
    """an edge whose ICP fitness (overlapping fraction) is below this is dropped."""
    global_init: str = "auto"
    """"auto": FPFH + RANSAC when the guess fails; "always": on every edge; "never"."""
    retry_fitness: float = 0.3
    """with global_init="auto", an edge refined from its guess to below this fitness also tries RANSAC."""
    fpfh_voxel_m: float = 0.02
    ransac_iterations: int = 100000
    ransac_confidence: float = 0.999
    edge_prune_threshold: float = 0.25
    """pose-graph line-process threshold: uncertain edges less consistent than this are dropped."""
    seed: int = 0
    """seed of open3d's RANSAC."""

    def __post_init__(self):
        for name in ("voxel_m", "max_depth_m", "fpfh_voxel_m"):
            positive(name, getattr(self, name))
        if not self.icp_distances_m:
            raise SpareTwinError("icp_distances_m: must name at least one ICP distance")
        for d in self.icp_distances_m:
            positive("icp_distances_m", d)
        for name in ("min_fitness", "retry_fitness", "ransac_confidence", "edge_prune_threshold"):
            fraction(name, getattr(self, name))
        whole("icp_iterations", self.icp_iterations, 1)
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
    """"guess" or "ransac": where the kept result started."""


@dataclass
class RegistrationResult:
    poses: np.ndarray
    """(N, 4, 4) camera-to-world; world = the first frame's camera (or the reference world)."""
    edges: list[Edge] = field(default_factory=list)
    seconds: dict = field(default_factory=dict)

    def summary(self) -> dict:
        return {
            "edges": len(self.edges),
            "edges_from_ransac": sum(e.init == "ransac" for e in self.edges),
            "mean_fitness": float(np.mean([e.fitness for e in self.edges])) if self.edges else None,
            "seconds": {k: round(v, 3) for k, v in self.seconds.items()},
        }


def _cloud(frame, cfg: RegistrationConfig):
    import open3d as o3d

    h, w = frame.depth_u16.shape
    pc = o3d.geometry.PointCloud.create_from_rgbd_image(
        to_o3d_rgbd(frame, cfg.max_depth_m), o3d_intrinsic(frame.K, w, h)
    )
    pc = pc.voxel_down_sample(cfg.voxel_m)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=cfg.voxel_m * 3, max_nn=30))
    pc.orient_normals_towards_camera_location(np.zeros(3))  # the camera sees the front of every surface
    return pc


def _features(pc, cfg: RegistrationConfig):
    import open3d as o3d

    down = pc.voxel_down_sample(cfg.fpfh_voxel_m)
    down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=cfg.fpfh_voxel_m * 2, max_nn=30))
    fpfh = o3d.pipelines.registration.compute_fpfh_feature(
        down, o3d.geometry.KDTreeSearchParamHybrid(radius=cfg.fpfh_voxel_m * 5, max_nn=100)
    )
    return down, fpfh


class _Registrar:
    def __init__(self, clouds, cfg: RegistrationConfig):
        self.clouds = clouds
        self.cfg = cfg
        self._feat: dict[int, tuple] = {}

    def features(self, i):
        if i not in self._feat:
            self._feat[i] = _features(self.clouds[i], self.cfg)
        return self._feat[i]

    def ransac(self, s: int, t: int) -> np.ndarray:
        import open3d as o3d

        reg = o3d.pipelines.registration
        (sd, sf), (td, tf) = self.features(s), self.features(t)
        d = self.cfg.fpfh_voxel_m * 1.5
        r = reg.registration_ransac_based_on_feature_matching(
            sd,
            td,
            sf,
            tf,
            True,
            d,
            reg.TransformationEstimationPointToPoint(False),
            3,
            [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(d)],
            reg.RANSACConvergenceCriteria(self.cfg.ransac_iterations, self.cfg.ransac_confidence),
        )
        return r.transformation

    def icp(self, s: int, t: int, init: np.ndarray):
        """Multi-scale ICP of cloud s onto cloud t; returns (T_t_s, fitness, rmse) or None."""
        import open3d as o3d

        reg = o3d.pipelines.registration
        src, tgt, T, r = self.clouds[s], self.clouds[t], np.asarray(init, np.float64), None
        crit = reg.ICPConvergenceCriteria(1e-7, 1e-7, self.cfg.icp_iterations)
        for k, d in enumerate(self.cfg.icp_distances_m):
            finest = k == len(self.cfg.icp_distances_m) - 1
            try:
                if finest and self.cfg.colored_icp:
                    r = reg.registration_colored_icp(
                        src, tgt, d, T, reg.TransformationEstimationForColoredICP(lambda_geometric=0.9), crit
                    )
                else:
                    r = reg.registration_icp(src, tgt, d, T, reg.TransformationEstimationPointToPlane(), crit)
            except RuntimeError:  # open3d raises when no correspondence is left within d
                return None
            T = r.transformation
        return T, float(r.fitness), float(r.inlier_rmse)

    def edge(self, s: int, t: int, guess: np.ndarray) -> Edge | None:
        cfg = self.cfg
        cands = []
        if cfg.global_init != "always":
            res = self.icp(s, t, guess)
            if res is not None:
                cands.append((res, "guess"))
        if cfg.global_init == "always" or (
            cfg.global_init == "auto" and (not cands or cands[0][0][1] < cfg.retry_fitness)
        ):
            res = self.icp(s, t, self.ransac(s, t))
            if res is not None:
                cands.append((res, "ransac"))
        if not cands:
            return None
        # more overlap wins; on a tie (within 2 %) the tighter fit
        (T, fit, rmse), how = max(cands, key=lambda c: (round(c[0][1] / 0.02), -c[0][2]))
        if fit < cfg.min_fitness:
            return None
        return Edge(s, t, T, fit, rmse, how)


def register_frames(
    frames, cfg: RegistrationConfig = RegistrationConfig(), init_poses: np.ndarray | None = None, progress: bool = True
) -> RegistrationResult:
    """Camera-to-world poses of `frames` (spare_twin.capture.frames.RGBDFrame list).

    `init_poses` (N, 4, 4): reference or approximate poses used as initial guesses; the result is then
    expressed in their world (anchored at frame 0). Without them, world = frame 0's camera.
    """
    import open3d as o3d
    from tqdm import tqdm

    reg = o3d.pipelines.registration
    n = len(frames)
    if n == 0:
        raise SpareTwinError("registration: no frames")
    o3d.utility.random.seed(cfg.seed)
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
    pairs = [(a + 1, a) for a in range(n - 1)] + [(a + g, a) for g in cfg.loop_gaps_frames for a in range(n - g)]
    bar = tqdm(total=len(pairs), desc="register", unit="edge", file=sys.stderr, disable=not progress)
    t1 = time.perf_counter()

    # neighbours first: they give the chain that guesses every loop edge
    if init_poses is not None:
        init_poses = np.asarray(init_poses, np.float64)
        if init_poses.shape != (n, 4, 4):
            raise SpareTwinError(f"registration: init poses have shape {init_poses.shape}, expected ({n}, 4, 4)")
        chain = [np.linalg.inv(init_poses[0]) @ P for P in init_poses]
    else:
        chain = [np.eye(4)]
    edges: list[Edge] = []
    for a in range(n - 1):
        guess = np.linalg.inv(chain[a]) @ chain[a + 1] if init_poses is not None else np.eye(4)
        e = R.edge(a + 1, a, guess)
        bar.update(1)
        if e is None:
            if init_poses is None:
                raise SpareTwinError(
                    f"registration: frames {a} and {a + 1} do not overlap (ICP fitness below "
                    f"{cfg.min_fitness}); record more slowly or lower voxel_m"
                )
            continue
        edges.append(e)
        if init_poses is None:
            chain.append(chain[a] @ e.T_target_source)
    for s, t in pairs[n - 1 :]:
        e = R.edge(s, t, np.linalg.inv(chain[t]) @ chain[s])
        bar.update(1)
        if e is not None:
            edges.append(e)
    bar.close()
    seconds["edges"] = time.perf_counter() - t1

    t2 = time.perf_counter()
    graph = reg.PoseGraph()
    for P in chain:
        graph.nodes.append(reg.PoseGraphNode(P))
    d = cfg.icp_distances_m[-1]
    for e in edges:
        info = reg.get_information_matrix_from_point_clouds(clouds[e.source], clouds[e.target], d, e.T_target_source)
        graph.edges.append(
            reg.PoseGraphEdge(e.source, e.target, e.T_target_source, info, uncertain=abs(e.source - e.target) != 1)
        )
    reg.global_optimization(
        graph,
        reg.GlobalOptimizationLevenbergMarquardt(),
        reg.GlobalOptimizationConvergenceCriteria(),
        reg.GlobalOptimizationOption(
            max_correspondence_distance=d, edge_prune_threshold=cfg.edge_prune_threshold, reference_node=0
        ),
    )
    poses = np.array([node.pose for node in graph.nodes])
    poses = np.linalg.inv(poses[0]) @ poses  # exactly frame 0 = identity, whatever the optimiser did
    if init_poses is not None:
        poses = init_poses[0] @ poses
    seconds["pose_graph"] = time.perf_counter() - t2
    return RegistrationResult(poses, edges, seconds)


def relative_pose_errors(poses: np.ndarray, reference: np.ndarray, gap: int) -> np.ndarray:
    """(M, 2): rotation error (deg) and translation error (mm) of every relative pose `gap` frames apart."""
    out = []
    for a in range(len(poses) - gap):
        est = np.linalg.inv(poses[a]) @ poses[a + gap]
        ref = np.linalg.inv(reference[a]) @ reference[a + gap]
        E = np.linalg.inv(ref) @ est
        out.append((rotation_error_deg(E[:3, :3]), 1000.0 * float(np.linalg.norm(E[:3, 3]))))
    return np.array(out).reshape(-1, 2)
