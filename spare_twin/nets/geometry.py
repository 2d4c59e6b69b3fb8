"""Depth views -> world-frame voxel grid, through the cameras' known intrinsics and poses.

This is the geometry-aware networks' front end (the paper's own "future work"): instead of asking a
CNN to infer 3D structure from 8 separate pictures, every depth pixel is back-projected into the world
frame, divided by the object's print_scale (so the grid is in paper units, the unit of E_L), and
splatted trilinearly into a fixed grid around the base. Trilinear splatting keeps sub-voxel position
in the cell weights, which the regression heads use to measure lengths finer than a voxel.
"""

from __future__ import annotations

import torch

from spare_twin.nets.presets import GridConfig


def pixel_rays(K: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """(..., 3, H*W) camera-frame rays with z = 1 (so a point is ray * z-depth), OpenCV pixel centres."""
    v, u = torch.meshgrid(
        torch.arange(height, dtype=K.dtype, device=K.device),
        torch.arange(width, dtype=K.dtype, device=K.device),
        indexing="ij",
    )
    fx, fy = K[..., 0, 0, None], K[..., 1, 1, None]
    cx, cy = K[..., 0, 2, None], K[..., 1, 2, None]
    x = (u.reshape(-1) - cx) / fx
    y = (v.reshape(-1) - cy) / fy
    return torch.stack([x, y, torch.ones_like(x)], dim=-2)


def backproject(
    depth_m: torch.Tensor, K: torch.Tensor, T_world_camera: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """depth (B, V, H, W), K (B, V, 3, 3), T (B, V, 4, 4) -> world points (B, V, H*W, 3), valid (B, V, H*W)."""
    B, V, H, W = depth_m.shape
    rays = pixel_rays(K, H, W)  # (B, V, 3, HW)
    d = depth_m.reshape(B, V, 1, H * W)
    p_cam = rays * d
    R, t = T_world_camera[..., :3, :3], T_world_camera[..., :3, 3:]
    p_world = (R @ p_cam + t).transpose(-1, -2)
    return p_world, d[:, :, 0] > 0


def voxelize(
    depth_m: torch.Tensor,
    K: torch.Tensor,
    T_world_camera: torch.Tensor,
    print_scale: torch.Tensor,
    grid: GridConfig,
    channel_of_view: torch.Tensor | None = None,
    n_channels: int = 1,
) -> torch.Tensor:
    """Fuse depth views into a (B, C, Z, Y, X) occupancy grid in paper units.

    `channel_of_view` (V,) int picks the output channel of each view (temporal input: one channel per
    time bin); by default every view goes into channel 0 (multi-view fusion). Values are
    1 - exp(-points / 2): about 1 where a surface was seen, so near and far views weigh alike.
    """
    B, V, H, W = depth_m.shape
    K = K.expand(B, V, 3, 3) if K.shape[1] == 1 else K
    T_world_camera = T_world_camera.expand(B, V, 4, 4) if T_world_camera.shape[1] == 1 else T_world_camera
    # float32 is plenty: world points are within a metre of the origin.
    p, valid = backproject(depth_m.float(), K.float(), T_world_camera.float())
    valid = valid & (p[..., 2] > grid.table_clearance_m)
    p = p / print_scale.float().reshape(B, 1, 1, 1)
    nx, ny, nz = grid.cells
    lo = torch.tensor([grid.x_range[0], grid.y_range[0], grid.z_range[0]], device=p.device)
    hi = torch.tensor([grid.x_range[1], grid.y_range[1], grid.z_range[1]], device=p.device)
    size = (hi - lo) / torch.tensor([nx, ny, nz], device=p.device, dtype=torch.float32)
    valid = valid & ((p >= lo) & (p < hi)).all(-1)
    # Compress to the points that land in the grid before splatting: in real views most pixels are
    # background or table, and the 8-corner splat is the expensive part.
    b_idx, v_idx, _ = torch.nonzero(valid, as_tuple=True)
    p = p[valid]
    chan = (
        torch.zeros(V, dtype=torch.long, device=p.device)
        if channel_of_view is None
        else channel_of_view.to(p.device).long()
    )
    bc = b_idx * n_channels + chan[v_idx]
    c = (p - lo) / size - 0.5  # continuous voxel coordinates, voxel centres at integers
    base = torch.floor(c)
    frac = c - base
    base = base.long()
    out = torch.zeros(B * n_channels * nz * ny * nx, device=p.device)
    dims = torch.tensor([nx, ny, nz], device=p.device)
    for corner in range(8):
        off = torch.tensor([(corner >> 0) & 1, (corner >> 1) & 1, (corner >> 2) & 1], device=p.device)
        idx = base + off
        w = torch.where(off.bool(), frac, 1 - frac).prod(-1)
        ok = ((idx >= 0) & (idx < dims)).all(-1)
        flat = ((bc * nz + idx[:, 2]) * ny + idx[:, 1]) * nx + idx[:, 0]
        out.index_add_(0, flat[ok], w[ok])
    out = out.reshape(B, n_channels, nz, ny, nx)
    return 1.0 - torch.exp(-out / 2.0)


def voxel_centres_pu(grid: GridConfig, device=None) -> torch.Tensor:
    """(Z*Y*X, 3) centres of the grid's voxels in paper units, x fastest (the order `voxelize` fills)."""
    nx, ny, nz = grid.cells
    axes = [
        torch.linspace(lo + (hi - lo) / (2 * n), hi - (hi - lo) / (2 * n), n, device=device)
        for (lo, hi), n in ((grid.z_range, nz), (grid.y_range, ny), (grid.x_range, nx))
    ]
    z, y, x = torch.meshgrid(*axes, indexing="ij")
    return torch.stack([x, y, z], -1).reshape(-1, 3)


#: Voxels closer to a camera than this (metres, along its axis) are not in its view.
NEAR_M = 0.01


def lift(
    features: torch.Tensor,
    K: torch.Tensor,
    T_world_camera: torch.Tensor,
    print_scale: torch.Tensor,
    grid: GridConfig,
    stride: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Image features sampled at every voxel's projection into every view.

    features (B, V, C, h, w) computed from (H, W) images by convolutions of total `stride` (feature
    pixel j is centred on image pixel stride * j); K (B, V, 3, 3) of the images; T (B, V, 4, 4).
    Returns values (B, V, C, N) (bilinear, zero outside the view) and seen (B, V, 1, N) float, the
    voxels in front of the camera that project into its image (or within half a feature pixel of its
    edge), N = Z*Y*X in `voxel_centres_pu` order.
    """
    B, V, C, h, w = features.shape
    centres_m = voxel_centres_pu(grid, features.device)[None] * print_scale.float().reshape(B, 1, 1)  # (B, N, 3)
    R, t = T_world_camera[..., :3, :3].float(), T_world_camera[..., :3, 3].float()
    # camera-frame points: R^T (p - t), for every view
    p_cam = torch.einsum("bvji,bvnj->bvni", R, centres_m[:, None] - t[:, :, None])
    z = p_cam[..., 2]
    in_front = z > NEAR_M
    z = torch.where(in_front, z, torch.ones_like(z))
    K = K.float()
    u = K[..., 0, 0, None] * p_cam[..., 0] / z + K[..., 0, 2, None]
    v = K[..., 1, 1, None] * p_cam[..., 1] / z + K[..., 1, 2, None]
    # feature-map pixel coordinates, then grid_sample's [-1, 1] (align_corners=False: pixel edges);
    # voxels behind the camera are sent off the image, where the zero padding answers for them
    gx = torch.where(in_front, (2 * (u / stride) + 1) / w - 1, torch.full_like(u, 3.0))
    gy = (2 * (v / stride) + 1) / h - 1
    # seen: wherever the zero-padded bilinear sample can be non-zero (up to half a pixel past the
    # image's edge), so that every view not counted as seeing a voxel adds exactly 0 to its sums
    seen = (gx.abs() < 1 + 1 / w) & (gy.abs() < 1 + 1 / h)
    g = torch.stack([gx, gy], -1).reshape(B * V, 1, -1, 2)
    values = torch.nn.functional.grid_sample(
        features.reshape(B * V, C, h, w), g, mode="bilinear", padding_mode="zeros", align_corners=False
    ).reshape(B, V, C, -1)
    return values, seen.float()[:, :, None]
