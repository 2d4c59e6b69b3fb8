"""Shared helpers for RGB-D frames: depth sanity checks, intrinsics parsing, resizing with the
intrinsics that follow, back-projection, open3d conversions."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spare_twin.errors import SpareTwinError
from spare_twin.open3d_loader import quiet_open3d

#: Plausible median depth of a real RGB-D frame (metres). Outside it the depth scale is almost
#: certainly wrong (millimetres read as metres gives hundreds of metres; 1/5000 read as 1/1000 gives 5x).
PLAUSIBLE_MEDIAN_DEPTH_M = (0.1, 10.0)
#: Below this fraction of valid pixels a depth image is treated as empty (a dead or covered sensor).
MIN_VALID_DEPTH_FRACTION = 0.01


def check_depth(depth_u16: np.ndarray, depth_scale: float, source: str | Path) -> None:
    """One-line error naming `source` for an empty depth image or an implausible depth scale."""
    if depth_u16.ndim != 2 or depth_u16.dtype != np.uint16:
        raise SpareTwinError(
            f"{source}: depth must be a single-channel 16-bit image, got {depth_u16.dtype} {depth_u16.shape}"
        )
    valid = depth_u16 > 0
    if valid.mean() < MIN_VALID_DEPTH_FRACTION:
        raise SpareTwinError(f"{source}: depth image is empty ({100 * valid.mean():.2f} % valid pixels)")
    median_m = float(np.median(depth_u16[valid])) * depth_scale
    lo, hi = PLAUSIBLE_MEDIAN_DEPTH_M
    if not lo <= median_m <= hi:
        raise SpareTwinError(
            f"{source}: median depth {median_m:.3g} m with depth scale {depth_scale:g} m/unit is outside "
            f"{lo:g}..{hi:g} m; wrong depth_scale?"
        )


def parse_intrinsics_arg(intrinsics: str) -> np.ndarray:
    """`fx,fy,cx,cy` (pixels) to a 3x3 K."""
    try:
        fx, fy, cx, cy = (float(v) for v in intrinsics.split(","))
    except ValueError:
        raise SpareTwinError(f"intrinsics {intrinsics!r}: expected fx,fy,cx,cy in pixels") from None
    if fx <= 0 or fy <= 0:
        raise SpareTwinError(f"intrinsics {intrinsics!r}: focal lengths must be positive")
    return K_from(fx, fy, cx, cy)


def K_from(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def read_K_txt(path: Path) -> np.ndarray:
    """A 3x3 matrix as text (tsdf-fusion `intrinsics.K.txt`, `camera-intrinsics.txt`)."""
    try:
        K = np.loadtxt(path, dtype=np.float64)
    except (ValueError, OSError) as exc:
        raise SpareTwinError(f"{path}: not a 3x3 intrinsics matrix ({exc})") from None
    if K.shape != (3, 3) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise SpareTwinError(f"{path}: not a 3x3 intrinsics matrix with positive focal lengths")
    return K


def read_pose_txt(path: Path) -> np.ndarray:
    """A 4x4 camera-to-world matrix as text; rejects NaN/inf and non-rigid rotations."""
    try:
        T = np.loadtxt(path, dtype=np.float64)
    except (ValueError, OSError) as exc:
        raise SpareTwinError(f"{path}: not a 4x4 pose ({exc})") from None
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise SpareTwinError(f"{path}: not a finite 4x4 pose")
    R = T[:3, :3]
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-3 or abs(np.linalg.det(R) - 1) > 1e-3:
        raise SpareTwinError(f"{path}: rotation part is not a rotation matrix")
    return T


@dataclass(frozen=True)
class RGBDFrame:
    """One frame in memory: colour uint8 (H, W, 3) RGB, depth uint16 (H, W) with `depth_scale` m/unit."""

    color: np.ndarray
    depth_u16: np.ndarray
    depth_scale: float
    K: np.ndarray


def load_frames(rec, cam: str, frames: list[int] | None = None) -> list[RGBDFrame]:
    """Colour and raw depth of `cam` for the given frames (all by default), checked for sanity."""
    c = rec.camera(cam)
    frames = list(range(rec.n_frames)) if frames is None else frames
    out = []
    for f in frames:
        color = rec.color(cam, f)
        depth = rec.depth_raw(cam, f)  # raw uint16: no float round trip
        check_depth(depth, rec.depth_scale, rec.path(cam, "depth", f))
        out.append(RGBDFrame(color, depth, rec.depth_scale, c.K))
    return out


def to_o3d_rgbd(frame: RGBDFrame, max_depth_m: float):
    """Legacy open3d RGBDImage (colour kept as RGB, depth in metres after the frame's own scale)."""
    o3d = quiet_open3d()

    return o3d.geometry.RGBDImage.create_from_color_and_depth(
        o3d.geometry.Image(np.ascontiguousarray(frame.color)),
        o3d.geometry.Image(np.ascontiguousarray(frame.depth_u16)),
        depth_scale=1.0 / frame.depth_scale,
        depth_trunc=max_depth_m,
        convert_rgb_to_intensity=False,
    )


def o3d_intrinsic(K: np.ndarray, width: int, height: int):
    o3d = quiet_open3d()

    return o3d.camera.PinholeCameraIntrinsic(
        int(width), int(height), float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    )


def fit_view(img: np.ndarray, K: np.ndarray, height: int, width: int, nearest: bool) -> tuple[np.ndarray, np.ndarray]:
    """Centre-crop to width:height aspect, resize to (height, width); K follows the crop and scale."""
    import cv2

    h, w = img.shape[:2]
    if w * height > h * width:  # too wide: crop columns
        cw, ch = int(round(h * width / height)), h
    else:
        cw, ch = w, int(round(w * height / width))
    x0, y0 = (w - cw) // 2, (h - ch) // 2
    img = img[y0 : y0 + ch, x0 : x0 + cw]
    # INTER_NEAREST_EXACT samples at pixel centres, as K assumes; INTER_NEAREST is up to a pixel off
    out = cv2.resize(img, (width, height), interpolation=cv2.INTER_NEAREST_EXACT if nearest else cv2.INTER_AREA)
    sx, sy = width / cw, height / ch
    K2 = np.asarray(K, np.float64).copy()
    # pixel-centre convention: u' + 0.5 = (u - x0 + 0.5) * s
    K2[0, 0] *= sx
    K2[1, 1] *= sy
    K2[0, 2] = (K2[0, 2] - x0 + 0.5) * sx - 0.5
    K2[1, 2] = (K2[1, 2] - y0 + 0.5) * sy - 0.5
    return out, K2


def rotation_error_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))
