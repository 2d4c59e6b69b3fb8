"""TSDF fusion of registered RGB-D frames into one coloured point cloud (and optionally a mesh)."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass

import numpy as np

from spare_twin.capture.checks import is_number, positive, whole
from spare_twin.errors import SpareTwinError
from spare_twin.open3d_loader import quiet_open3d


@dataclass(frozen=True)
class FusionConfig:
    """TSDF settings (metres)."""

    voxel_m: float = 0.004
    """TSDF voxel size: 4 mm resolves the printed links (>= 10 mm wide) at table-top distances."""
    sdf_trunc_m: float = 0.016
    """truncation distance: four voxels, the usual choice against sensor noise of a few mm."""
    max_depth_m: float = 2.0
    min_weight: float = 1.0
    """keep surface voxels observed at least this many times."""
    block_count: int = 20000
    """initial voxel-block capacity (8^3 voxels each, about 10 kB): 20000 blocks cover a table-top scene
    at 4 mm; open3d grows the grid when needed."""

    def __post_init__(self):
        for name in ("voxel_m", "sdf_trunc_m", "max_depth_m"):
            positive(name, getattr(self, name))
        if not is_number(self.min_weight) or self.min_weight < 0:
            raise SpareTwinError(f"min_weight {self.min_weight}: must be a number of at least 0")
        whole("block_count", self.block_count, 1)


@dataclass
class Fused:
    points: np.ndarray
    """(N, 3) float64, world frame."""
    colors: np.ndarray
    """(N, 3) float64 RGB in [0, 1]."""
    mesh: object | None
    """open3d TriangleMesh, when asked for."""
    seconds: float
    frames: int


def fuse_frames(
    frames, poses: np.ndarray, cfg: FusionConfig = FusionConfig(), mesh: bool = False, progress: bool = True
) -> Fused:
    """Integrate every frame at its camera-to-world pose into a voxel-block TSDF grid (open3d tensor API).

    (The tensor VoxelBlockGrid rather than the legacy ScalableTSDFVolume: in the open3d 0.20 wheel the
    legacy volume extracts no surface at all.) The points come sorted by position: open3d's threads
    extract the same values in a different order from run to run, and the same poses must give the
    same cloud byte for byte.
    """
    o3d = quiet_open3d()
    from tqdm import tqdm

    t0 = time.perf_counter()
    dev = o3d.core.Device("CPU:0")
    grid = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"),
        attr_dtypes=(o3d.core.float32,) * 3,
        attr_channels=((1), (1), (3)),
        voxel_size=cfg.voxel_m,
        block_resolution=8,
        block_count=cfg.block_count,
        device=dev,
    )
    trunc_voxels = cfg.sdf_trunc_m / cfg.voxel_m
    for frame, T in tqdm(list(zip(frames, poses)), desc="fuse", unit="frame", file=sys.stderr, disable=not progress):
        depth = o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(frame.depth_u16[..., None])))
        color = o3d.t.geometry.Image(
            o3d.core.Tensor(np.ascontiguousarray(frame.color, np.uint8))
        )  # (uint16, uint8): open3d's native pair
        K = o3d.core.Tensor(np.asarray(frame.K, np.float64))
        extrinsic = o3d.core.Tensor(np.linalg.inv(T))  # world-to-camera
        scale = 1.0 / frame.depth_scale  # open3d: depth units per metre
        coords = grid.compute_unique_block_coordinates(depth, K, extrinsic, scale, cfg.max_depth_m, trunc_voxels)
        grid.integrate(coords, depth, color, K, K, extrinsic, scale, cfg.max_depth_m, trunc_voxels)
    # a surface seen by one frame only is kept (weight 1): sparse captures are the common case here
    pc = grid.extract_point_cloud(weight_threshold=cfg.min_weight)
    pts = pc.point.positions.numpy().astype(np.float64) if "positions" in pc.point else np.zeros((0, 3))
    cols = np.clip(pc.point.colors.numpy().astype(np.float64), 0, 1) if "colors" in pc.point else np.zeros((0, 3))
    if len(pts) and len(cols) == len(pts):  # a fixed order: by position as stored (float32), then colour
        p32 = pts.astype(np.float32)
        order = np.lexsort((cols[:, 2], cols[:, 1], cols[:, 0], p32[:, 2], p32[:, 1], p32[:, 0]))
        pts, cols = pts[order], cols[order]
    m = None
    if mesh and len(pts):
        m = grid.extract_triangle_mesh(weight_threshold=cfg.min_weight).to_legacy()
        m.compute_vertex_normals()
    return Fused(pts, cols, m, time.perf_counter() - t0, len(frames))


def ply_bytes(points: np.ndarray, colors: np.ndarray | None = None) -> bytes:
    """A binary little-endian PLY point cloud (x y z float32, red green blue uchar)."""
    points = np.asarray(points, np.float32)
    n = len(points)
    props = "property float x\nproperty float y\nproperty float z\n"
    dt = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colors is not None:
        props += "property uchar red\nproperty uchar green\nproperty uchar blue\n"
        dt += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    rec = np.empty(n, dtype=dt)
    rec["x"], rec["y"], rec["z"] = points[:, 0], points[:, 1], points[:, 2]
    if colors is not None:
        c = np.clip(np.rint(np.asarray(colors) * 255), 0, 255).astype(np.uint8)
        rec["red"], rec["green"], rec["blue"] = c[:, 0], c[:, 1], c[:, 2]
    header = f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\n{props}end_header\n"
    return header.encode() + rec.tobytes()


def mesh_ply_bytes(mesh) -> bytes:
    """open3d TriangleMesh as PLY bytes (written through a temporary file: open3d writes only to paths)."""
    import os
    import tempfile

    o3d = quiet_open3d()

    fd, tmp = tempfile.mkstemp(suffix=".ply")
    os.close(fd)
    try:
        o3d.io.write_triangle_mesh(tmp, mesh, write_ascii=False)
        with open(tmp, "rb") as f:
            return f.read()
    finally:
        os.unlink(tmp)


def read_ply_points(path) -> tuple[np.ndarray, np.ndarray]:
    """Points and colours (0..1) of a PLY cloud."""
    o3d = quiet_open3d()

    pc = o3d.io.read_point_cloud(str(path))
    if len(pc.points) == 0:
        raise SpareTwinError(f"{path}: no points (missing or not a PLY point cloud)")
    return np.asarray(pc.points), np.asarray(pc.colors) if pc.has_colors() else np.full((len(pc.points), 3), 0.5)
