"""Render and compare: posed twins scored against observed depth images, and the refinements built on
that score.

A fused cloud smears what a single depth image shows sharply (the 6.4 mm layers, a short end link),
so the last word on a fit goes to the depth images themselves: the twin is rendered through each
view's camera and its depth compared pixel by pixel. Three refinements use that score:

- `DepthScorer.refine_joints`: each joint over its whole range, base outwards (escapes a folding
  the cloud search settled in);
- `DepthScorer.polish`: a pattern search on every parameter with shrinking steps; besides single
  coordinates it makes the coupled moves single steps cannot (neighbouring joints turned against
  each other, so one link turns while the rest of the chain keeps its direction);
- `DepthScorer.align_views`: the camera poses themselves. They come from registering whole frames,
  which the table dominates; 2-5 mm off, they cap the joint-angle accuracy at about 9 degrees on
  2 cm links (1.3 degrees with the true poses). Each view is re-aligned by point-to-plane ICP onto
  what it should see: the posed twin rendered through it, and the table plane around it
  (model-based tracking).

Rendering is ray casting (open3d's Embree `RaycastingScene`) rather than pybullet's rasteriser: a
search scores hundreds of poses through twenty views, and only a few per cent of the pixels can
count (those that observed a point above the table, or can see the twin). Per pose, the rays cast
are those of the observed object pixels and of the image rectangles of boxes that hold the posed
links (`slab_boxes`); all views' rays go in one call against the posed link meshes, and the table
(pybullet's 1 m slab round the base) is the plane z = 0, met analytically. The depth is z-depth
(rays are scaled to unit camera z, so the hit distance is the depth), at exactly the pixel centres
the intrinsics give; the score equals the one pybullet's render gives to within 0.001 mm, ten to
twenty times faster. Open3D's ICP runs on one thread (`align_views`), so that its sums, and the fit, are
the same on every run.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from spare_twin.capture.frames import rotation_error_deg
from spare_twin.object.folder import ObjectFolder
from spare_twin.object.kinematics import base_pose, forward_kinematics, param_bounds
from spare_twin.object.urdf import load_urdf
from spare_twin.observe.points import backproject
from spare_twin.open3d_loader import quiet_open3d

#: Depth disagreements beyond this count as this much (metres): a hole or a stray reading is one bad pixel.
DEPTH_TRUNCATE_M = 0.02
#: Observed points this high above the table belong to the object (metres; the segmenter's cut).
OBJECT_HEIGHT_M = 0.008
#: Rendering range of the twin (metres): nothing nearer or further is seen.
NEAR_M, FAR_M = 0.02, 3.0
#: View alignment: ICP voxel and coarse-to-fine correspondence distances (metres).
ALIGN_VOXEL_M = 0.002
ALIGN_DISTANCES_M = (0.01, 0.004)
#: ... ICP iterations at each distance, and the voxel of the observed table (it fixes only height,
#: roll and pitch: a coarser sampling holds as well and costs a quarter).
ALIGN_ITERATIONS = 20
ALIGN_TABLE_VOXEL_M = 0.006
#: ... and the radius round the base within which the table takes part (metres; the object's
#: points take part out to its reach).
ALIGN_TABLE_RADIUS_M = 0.12
#: A view whose ICP overlaps less than this, or moves further than these, keeps its pose.
ALIGN_MIN_FITNESS = 0.3
ALIGN_MAX_SHIFT_M, ALIGN_MAX_TURN_DEG = 0.02, 5.0
#: Table points further than this beyond the chain's reach from its base do not take part (metres).
TABLE_MARGIN_M = 0.02


@dataclass(frozen=True)
class DepthView:
    """One observed depth image, posed in the frame of the cloud being fitted."""

    depth_m: np.ndarray
    """float32 (H, W) z-depth in metres, 0 = no reading."""
    K: np.ndarray
    """3x3 intrinsics."""
    T_cloud_camera: np.ndarray
    """4x4 camera pose in the cloud's frame (OpenCV camera axes)."""


def twin_link_meshes(obj: ObjectFolder) -> list:
    """Each link's printed parts as one trimesh in that link's frame (metres), read through the URDF:
    its visual STL files placed by their visual origins."""
    import trimesh

    links = {link.name: link for link in load_urdf(obj.urdf_path).robot.links}
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


def transformed(points: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(..., 3) points moved by the 4x4 rigid transform T. Written as an einsum, not `points @ R.T`:
    a tall, thin product goes to BLAS, whose threads on a small, busy machine cost ten times the
    arithmetic."""
    T = np.asarray(T, np.float64)
    return np.einsum("...j,kj->...k", points, T[:3, :3]) + T[:3, 3]


class ScoredPixels:
    """The pixels of a set of views that a score reads (every `stride`-th, with an observed depth), as
    rays in the cloud's frame with what was observed along them, all views in one flat layout."""

    def __init__(self, views: list[DepthView], stride: int):
        self.stride = stride
        self.shapes, self.offsets, index, object_mask = [], [], [], []
        origins, directions, observed_m, observed_object = [], [], [], []
        cells = rays = 0
        for view in views:
            observed = view.depth_m[::stride, ::stride]
            valid = observed > 0
            rows, cols = np.nonzero(valid)
            T = np.asarray(view.T_cloud_camera, np.float64)
            d = pixel_directions(np.asarray(view.K, np.float64), T, rows * stride, cols * stride)
            z = observed[valid].astype(np.float64)
            above = (T[2, 3] + z * d[:, 2]) > OBJECT_HEIGHT_M
            grid = np.full(observed.shape, -1, np.int64)
            grid[rows, cols] = rays + np.arange(len(rows))
            mask = np.zeros(observed.shape, bool)
            mask[rows[above], cols[above]] = True
            self.shapes.append(observed.shape)
            self.offsets.append(cells)
            index.append(grid.ravel())
            object_mask.append(mask.ravel())
            origins.append(np.broadcast_to(T[:3, 3], d.shape))
            directions.append(d)
            observed_m.append(z)
            observed_object.append(above)
            cells += observed.size
            rays += len(rows)
        self.index = np.concatenate(index)
        self.object_mask = np.concatenate(object_mask)
        self.origins = np.vstack(origins)
        self.directions = np.vstack(directions)
        self.observed_m = np.concatenate(observed_m)
        self.observed_object = np.concatenate(observed_object)
        with np.errstate(divide="ignore", invalid="ignore"):
            self.table_m = np.where(self.directions[:, 2] < 0, -self.origins[:, 2] / self.directions[:, 2], np.inf)
            self.table_xy = (
                self.origins[:, :2]
                + np.where(np.isfinite(self.table_m), self.table_m, 0.0)[:, None] * (self.directions[:, :2])
            )
        self.rays = np.hstack([self.origins, self.directions]).astype(np.float32)
        """(N, 6) float32 origins and directions, as the ray caster takes them."""
        self.K = np.stack([np.asarray(v.K, np.float64) for v in views])
        self.T_camera_cloud = np.stack([np.linalg.inv(np.asarray(v.T_cloud_camera, np.float64)) for v in views])

    def selected(self, boxes: np.ndarray) -> np.ndarray:
        """Indices of the rays that see an observed object point or may see the twin: those inside the
        image rectangles of `boxes` ((B, 8, 3) corners in the cloud's frame that hold the twin)."""
        mask = self.object_mask.copy()
        rects = image_rectangles(boxes, self.K, self.T_camera_cloud, self.stride, self.shapes)
        for view, r0, r1, c0, c1 in rects:
            h, w = self.shapes[view]
            mask[self.offsets[view] : self.offsets[view] + h * w].reshape(h, w)[r0:r1, c0:c1] = True
        idx = self.index[mask]
        return idx[idx >= 0]


def pixel_directions(K: np.ndarray, T_cloud_camera: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """(N, 3) ray directions of pixels (row, col) in the cloud's frame, scaled to unit camera z (a hit
    at distance t lies at z-depth t), through exactly the pixel centres K puts them at."""
    d = np.stack([(cols - K[0, 2]) / K[0, 0], (rows - K[1, 2]) / K[1, 1], np.ones(len(rows))], axis=1)
    return np.einsum("...j,kj->...k", d, np.asarray(T_cloud_camera, np.float64)[:3, :3])


def image_rectangles(boxes: np.ndarray, K: np.ndarray, T_camera_cloud: np.ndarray, stride: int, shapes) -> list:
    """(view, row0, row1, col0, col1) slices of each view's `stride`-decimated image (of shapes[view])
    that cover each box's projection ((L, 8, 3) box corners; (V, 3, 3) K, (V, 4, 4) poses), a pixel
    wider all round; the whole image for a box reaching behind the camera."""
    p = np.einsum("vij,lcj->vlci", T_camera_cloud[:, :3, :3], boxes) + T_camera_cloud[:, None, None, :3, 3]
    z = p[..., 2]
    behind = (z <= NEAR_M).any(axis=2)
    z = np.where(z > NEAR_M, z, 1.0)
    fx, fy, cx, cy = (K[:, i, j][:, None, None] for i, j in ((0, 0), (1, 1), (0, 2), (1, 2)))
    u = (fx * p[..., 0] / z + cx) / stride
    v = (fy * p[..., 1] / z + cy) / stride
    hw = np.array(shapes)[:, None, :]
    c0 = np.maximum(np.floor(u.min(axis=2)).astype(np.int64) - 1, 0)
    c1 = np.minimum(np.ceil(u.max(axis=2)).astype(np.int64) + 2, hw[..., 1])
    r0 = np.maximum(np.floor(v.min(axis=2)).astype(np.int64) - 1, 0)
    r1 = np.minimum(np.ceil(v.max(axis=2)).astype(np.int64) + 2, hw[..., 0])
    c0, r0 = np.where(behind, 0, c0), np.where(behind, 0, r0)
    c1, r1 = np.where(behind, hw[..., 1], c1), np.where(behind, hw[..., 0], r1)
    views, links = np.nonzero((c0 < c1) & (r0 < r1))
    return [(int(a), int(r0[a, b]), int(r1[a, b]), int(c0[a, b]), int(c1[a, b])) for a, b in zip(views, links)]


#: The twin's table: a slab this wide each way round the base (`spare_twin.sim.twin.Twin`'s, 1 m square).
TABLE_HALF_M = 0.5


class TwinCaster:
    """The twin's link meshes, posed by base parameters and joint angles, hit by rays (z-depth).

    The meshes are the printed parts' (`twin_link_meshes`), decimated to DECIMATE of their triangles:
    their 64-segment circles are finer than any depth image resolves (the score moves by less than a
    micrometre), and a pose's ray-casting structure is built in proportion to the triangles."""

    def __init__(self, obj: ObjectFolder):
        self.spec = obj.spec
        meshes = [decimated(m, DECIMATE) for m in twin_link_meshes(obj)]
        self.link_vertices = [v for v, _ in meshes]
        offsets = np.cumsum([0] + [len(v) for v in self.link_vertices[:-1]])
        self.faces = np.vstack([f + o for (_, f), o in zip(meshes, offsets)]).astype(np.uint32)
        self.box_link, corners = [], []
        for k, (vertices, faces) in enumerate(meshes):
            for box in slab_boxes(vertices, faces):
                self.box_link.append(k)
                corners.append(box)
        self.box_link = np.array(self.box_link)
        self.box_corners = np.stack(corners)

    def link_poses(self, params: np.ndarray) -> np.ndarray:
        return forward_kinematics(self.spec, params[3:], base_pose(*params[:3]))

    def boxes(self, poses: np.ndarray) -> np.ndarray:
        """(B, 8, 3) boxes that together hold the twin (`slab_boxes` of every link), posed."""
        P = poses[self.box_link]
        return np.einsum("bij,bcj->bci", P[:, :3, :3], self.box_corners) + P[:, None, :3, 3]

    def cast(self, poses: np.ndarray, rays: np.ndarray) -> np.ndarray:
        """(N,) distance along each of `rays` ((N, 6) float32 origins, directions) to the twin with
        links at `poses`; inf where a ray misses it."""
        o3d = quiet_open3d()

        if len(rays) == 0:
            return np.zeros(0)
        vertices = np.vstack([transformed(v, T) for v, T in zip(self.link_vertices, poses)])
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(self.faces))
        return (
            scene.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays, np.float32)))["t_hit"].numpy().astype(np.float64)
        )


#: The share of a link mesh's triangles the ray caster keeps.
DECIMATE = 0.5


def decimated(mesh, share: float) -> tuple[np.ndarray, np.ndarray]:
    """(vertices float64, faces int64) of a trimesh simplified to `share` of its triangles by quadric
    decimation (open3d; deterministic)."""
    o3d = quiet_open3d()

    m = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.asarray(mesh.vertices, np.float64)),
        o3d.utility.Vector3iVector(np.asarray(mesh.faces, np.int32)),
    )
    m = m.simplify_quadric_decimation(max(4, int(len(mesh.faces) * share)))
    return np.asarray(m.vertices, np.float64), np.asarray(m.triangles, np.int64)


#: A link's mesh is covered by boxes this long along the link (metres): a link seen at a slant fills
#: less of one box's image rectangle than of its whole bounding box's, so fewer rays are cast.
SLAB_M = 0.02


def slab_boxes(vertices: np.ndarray, faces: np.ndarray, slab_m: float = SLAB_M) -> list[np.ndarray]:
    """(8, 3) corners of boxes, one per `slab_m` of the link's length (its z axis), that together hold
    every triangle: a slab's box spans the x, y range of every triangle that reaches into it."""
    corners = np.array(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij")).reshape(3, -1).T
    tri = vertices[faces]
    tz_lo, tz_hi = tri[..., 2].min(axis=1), tri[..., 2].max(axis=1)
    z_lo, z_hi = float(tz_lo.min()), float(tz_hi.max())
    edges = np.linspace(z_lo, z_hi, max(1, int(np.ceil((z_hi - z_lo) / slab_m))) + 1)
    out = []
    for z0, z1 in zip(edges[:-1], edges[1:]):
        inside = (tz_hi >= z0) & (tz_lo <= z1)
        if not inside.any():
            continue
        xy = tri[inside][..., :2].reshape(-1, 2)
        lo, hi = np.array([*xy.min(axis=0), z0]), np.array([*xy.max(axis=0), z1])
        out.append(np.where(corners, hi, lo))
    return out


def on_table(points_xy: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Whether table-plane points (x, y) lie on the twin's table slab round the base at params."""
    c, s = np.cos(params[2]), np.sin(params[2])
    d = points_xy - params[:2]
    return (np.abs(c * d[:, 0] + s * d[:, 1]) <= TABLE_HALF_M) & (np.abs(-s * d[:, 0] + c * d[:, 1]) <= TABLE_HALF_M)


class DepthScorer:
    """Renders posed twins (params = base x, y, yaw, then the joint angles) through depth views and
    scores their agreement with the observed depth: the mean truncated |rendered - observed| over
    pixels where the rendered twin or an observed point above the table is (both read), as
    pybullet's twin (links, and a 1 m table slab round the base) renders it. Views are scored on every
    `stride`-th pixel so that searches stay quick (decimated, not resampled: exactly the pixels a
    decimated image keeps). Only the pixels that can count are cast: those that observed an object
    point, and those inside the image rectangles of the posed links' bounding boxes."""

    def __init__(self, obj: ObjectFolder, views: list[DepthView], stride: int = 2):
        self.obj = obj
        self.stride = stride
        self.caster = TwinCaster(obj)
        self.set_views(views)

    def set_views(self, views: list[DepthView]) -> None:
        self.views = list(views)
        self._pixels: ScoredPixels | None = None
        # each view's observed points in its camera frame: re-aligning a view moves them, never changes them
        cached = {id(depth): points for depth, points in getattr(self, "_camera_points", [])}
        self._camera_points = [(v.depth_m, cached.get(id(v.depth_m))) for v in self.views]

    def observed_points(self, i: int) -> np.ndarray:
        """(N, 3) view i's observed points (full resolution) in the cloud's frame, at its current pose."""
        depth, points = self._camera_points[i]
        if points is None:
            points = backproject(depth, self.views[i].K)
            self._camera_points[i] = (depth, points)
        return _to_cloud(points, self.views[i].T_cloud_camera)

    def set_stride(self, stride: int) -> None:
        """Score on every `stride`-th pixel from now on."""
        if stride != self.stride:
            self.stride, self._pixels = stride, None

    def reach_m(self) -> float:
        """How far from its base the chain (and the table round it worth aligning on) can reach."""
        return float(np.sum(self.obj.spec.link_lengths_pu)) * self.obj.spec.print_scale + TABLE_MARGIN_M

    def residuals(self, params: np.ndarray) -> np.ndarray:
        """The truncated |rendered - observed| depth of every pixel the score reads (metres)."""
        params = np.asarray(params, np.float64)
        if self._pixels is None:
            self._pixels = ScoredPixels(self.views, self.stride)
        px = self._pixels
        poses = self.caster.link_poses(params)
        i = px.selected(self.caster.boxes(poses))
        table = px.table_m[i]
        table = np.where(np.isfinite(table) & on_table(px.table_xy[i], params), table, np.inf)
        twin = self.caster.cast(poses, px.rays[i])
        on_twin = twin < table
        rendered = np.where(on_twin, twin, table)
        both = (px.observed_object[i] | on_twin) & (rendered >= NEAR_M) & (rendered <= FAR_M)
        return np.minimum(np.abs(rendered[both] - px.observed_m[i][both]), DEPTH_TRUNCATE_M)

    def __call__(self, params: np.ndarray) -> float:
        e = self.residuals(params)
        return float(e.mean()) if len(e) else float("inf")

    def twin_points(self, params: np.ndarray, view: DepthView) -> np.ndarray:
        """(N, 3) the posed twin's surface as `view` sees it at full resolution, in the cloud's frame."""
        params = np.asarray(params, np.float64)
        poses = self.caster.link_poses(params)
        T_camera_cloud = np.linalg.inv(view.T_cloud_camera)
        mask = np.zeros(view.depth_m.shape, bool)
        K = np.asarray(view.K, np.float64)[None]
        for _, r0, r1, c0, c1 in image_rectangles(self.caster.boxes(poses), K, T_camera_cloud[None], 1, [mask.shape]):
            mask[r0:r1, c0:c1] = True
        rows, cols = np.nonzero(mask)
        origin = np.asarray(view.T_cloud_camera, np.float64)[:3, 3]
        directions = pixel_directions(np.asarray(view.K, np.float64), view.T_cloud_camera, rows, cols)
        twin = self.caster.cast(poses, np.hstack([np.broadcast_to(origin, directions.shape), directions]))
        with np.errstate(divide="ignore", invalid="ignore"):
            table = np.where(directions[:, 2] < 0, -origin[2] / directions[:, 2], np.inf)
        hit = (twin < table) & (twin >= NEAR_M) & (twin <= FAR_M)
        return origin + twin[hit, None] * directions[hit]

    def refine_joints(
        self, params: np.ndarray, limits: np.ndarray, coarse_deg: float, fine_deg: float
    ) -> tuple[np.ndarray, float]:
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
                    grid = np.clip(params[3 + k] + np.radians(np.arange(-span, span + 1e-9, step)), lo, hi)
                for a in grid:
                    trial = params.copy()
                    trial[3 + k] = a
                    e = self(trial)
                    if e < best:
                        best, params = e, trial
        return params, best

    def polish(
        self, params: np.ndarray, limits: np.ndarray, steps_deg=(2.0, 1.0, 0.5, 0.25)
    ) -> tuple[np.ndarray, float]:
        """Pattern search: at each step size (degrees for yaw and joints, as many millimetres for
        the base position) try +-step on every parameter, on every neighbouring joint pair in
        opposite directions and on every three neighbouring joints as (+1, -2, +1) (a middle link
        turns while its neighbours keep their directions), taking each improvement, until none is
        left; then the next size. A move that improved is tried again first (a valley is often
        followed for several steps the same way)."""
        params = np.array(params, dtype=np.float64)
        n = len(params) - 3
        lower, upper = param_bounds(limits)
        best = self(params)
        for step_deg in steps_deg:
            scale = np.array([step_deg / 1000.0, step_deg / 1000.0] + [np.radians(step_deg)] * (n + 1))
            moves = list(np.eye(n + 3))
            for k in range(n - 1):
                pair = np.zeros(n + 3)
                pair[3 + k], pair[4 + k] = 1.0, -1.0
                moves.append(pair)
            for k in range(n - 2):
                triple = np.zeros(n + 3)
                triple[3 + k : 6 + k] = 1.0, -2.0, 1.0
                moves.append(triple)
            improved = True
            while improved:
                improved = False
                for move in moves:
                    for sign in (1.0, -1.0):
                        while True:  # an improving move is tried again at once: valleys run on
                            trial = np.clip(params + sign * move * scale, lower, upper)
                            e = self(trial)
                            if not e < best:
                                break
                            best, params, improved = e, trial, True
        return params, best

    def align_views(self, params: np.ndarray) -> tuple[float, float]:
        """Re-align every view's camera onto the twin posed by `params` and the table plane (see the
        module doc); returns the mean correction (millimetres, degrees)."""
        o3d = quiet_open3d()

        reach_m = self.reach_m()
        threads = o3d.utility.get_max_threads()
        # one thread: ICP's sums (and the voxel grids' point order) come out the same on every run
        o3d.utility.set_max_threads(1)
        try:
            aligned, shifts = self._align(params, reach_m)
        finally:
            o3d.utility.set_max_threads(threads)
        self.set_views(aligned)
        return tuple(float(x) for x in np.mean(shifts, axis=0))

    def _align(self, params: np.ndarray, reach_m: float) -> tuple[list[DepthView], list[tuple[float, float]]]:
        o3d = quiet_open3d()

        reg = o3d.pipelines.registration
        table = _table_patch(params[:2], min(reach_m, ALIGN_TABLE_RADIUS_M))
        aligned, shifts = [], []
        for i, v in enumerate(self.views):
            twin_points = self.twin_points(params, v)
            target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(twin_points)).voxel_down_sample(
                ALIGN_VOXEL_M * 0.75
            )
            target.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=ALIGN_VOXEL_M * 2.5, max_nn=30))
            target.orient_normals_towards_camera_location(v.T_cloud_camera[:3, 3])
            target += table
            source = _observed_near(self.observed_points(i), params[:2], reach_m)
            T, fitness = np.eye(4), 0.0
            for d in ALIGN_DISTANCES_M:
                r = reg.registration_icp(
                    source,
                    target,
                    d,
                    T,
                    reg.TransformationEstimationPointToPlane(),
                    reg.ICPConvergenceCriteria(1e-7, 1e-7, ALIGN_ITERATIONS),
                )
                T, fitness = np.asarray(r.transformation), float(r.fitness)
            shift_m, turn_deg = float(np.linalg.norm(T[:3, 3])), rotation_error_deg(T[:3, :3])
            if fitness < ALIGN_MIN_FITNESS or shift_m > ALIGN_MAX_SHIFT_M or turn_deg > ALIGN_MAX_TURN_DEG:
                T, shift_m, turn_deg = np.eye(4), 0.0, 0.0
            aligned.append(replace(v, T_cloud_camera=T @ v.T_cloud_camera))
            shifts.append((shift_m * 1000.0, turn_deg))
        return aligned, shifts

    def object_points(self, centre_xy: np.ndarray, radius_m: float, max_points: int, seed: int = 0) -> np.ndarray:
        """(N, 3) observed points above the table within `radius_m` of `centre_xy`, from every view
        at full resolution and its current pose (at most `max_points`, a seeded subset)."""
        clouds = [self.observed_points(i) for i in range(len(self.views))]
        points = np.vstack(clouds) if clouds else np.zeros((0, 3))
        points = points[
            (points[:, 2] > OBJECT_HEIGHT_M) & (np.linalg.norm(points[:, :2] - centre_xy, axis=1) < radius_m)
        ]
        if len(points) > max_points:
            points = points[np.random.default_rng(seed).choice(len(points), max_points, replace=False)]
        return points

    def close(self) -> None:
        """Nothing to release (kept so that callers may use the scorer as a context manager)."""

    def __enter__(self) -> DepthScorer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _to_cloud(points_camera: np.ndarray, T_cloud_camera: np.ndarray) -> np.ndarray:
    return transformed(points_camera, T_cloud_camera)


def _observed_near(observed: np.ndarray, centre_xy: np.ndarray, radius_m: float):
    """Observed points within `radius_m` of `centre_xy` as an open3d cloud: the object's at
    ALIGN_VOXEL_M, the table's (within ALIGN_TABLE_RADIUS_M) at the coarser ALIGN_TABLE_VOXEL_M."""
    o3d = quiet_open3d()

    distance = np.linalg.norm(observed[:, :2] - centre_xy, axis=1)
    above = observed[:, 2] > OBJECT_HEIGHT_M
    keep = np.where(above, distance < radius_m, distance < min(radius_m, ALIGN_TABLE_RADIUS_M))
    observed, above = observed[keep], above[keep]
    source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(observed[above])).voxel_down_sample(ALIGN_VOXEL_M)
    source += o3d.geometry.PointCloud(o3d.utility.Vector3dVector(observed[~above])).voxel_down_sample(
        ALIGN_TABLE_VOXEL_M
    )
    return source


def _table_patch(centre_xy: np.ndarray, radius_m: float, spacing_m: float = 0.003):
    """The table top (z = 0) round `centre_xy` as an open3d cloud with upward normals."""
    o3d = quiet_open3d()

    g = np.arange(-radius_m, radius_m + 1e-9, spacing_m)
    x, y = np.meshgrid(g, g)
    keep = np.hypot(x, y) <= radius_m
    points = np.stack([x[keep] + centre_xy[0], y[keep] + centre_xy[1], np.zeros(keep.sum())], axis=1)
    patch = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    patch.normals = o3d.utility.Vector3dVector(np.tile([0.0, 0.0, 1.0], (len(points), 1)))
    return patch
