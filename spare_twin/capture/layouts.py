"""Listing the frames of a public RGB-D folder layout (7-Scenes, TUM RGB-D, Open3D's recorder) before any
image is read: which colour and depth files make each frame, their poses and timestamps, the intrinsics
and the depth scale. `spare_twin.capture.importers` reads, checks and writes them."""

from __future__ import annotations

import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spare_twin.capture.frames import K_from, read_K_txt
from spare_twin.errors import SpareTwinError
from spare_twin.io import read_json
from spare_twin.validate import check_pose

LAYOUTS = ("7scenes", "tum", "open3d", "bag")
TUM_DEPTH_SCALE = 1.0 / 5000.0
MM_DEPTH_SCALE = 0.001
#: TUM association tolerance (seconds), as in the benchmark's associate.py.
TUM_MAX_DT_S = 0.02


@dataclass(frozen=True)
class FrameFiles:
    """One source frame: its files and, where known, pose and timestamp."""

    name: str
    color: Path
    depth: Path
    T_world_camera: np.ndarray | None = None
    timestamp_s: float | None = None


@dataclass
class Source:
    """A listed source: frames in order plus camera and scale (before any image is read)."""

    frames: list[FrameFiles]
    K: np.ndarray | None
    depth_scale: float
    fps: float | None
    sensor_model: str
    layout: str
    depth_invalid_value: int | None = None
    extra: dict = field(default_factory=dict)


# -- listing ------------------------------------------------------------------------------------


def _frame_number(p: Path, pattern: re.Pattern) -> int | None:
    m = pattern.fullmatch(p.name)
    return int(m.group(1)) if m else None


def _check_pairs(colors: dict, depths: dict, depth_path, colour_path=None) -> None:
    """Every colour frame has its depth frame and every depth frame its colour frame (both {key: path});
    else one line naming the file: `depth_path(key)` for a missing depth frame, and where the layout
    names a depth frame's colour frame, `colour_path(key)` for an extra one."""
    for k in sorted(colors):
        if k not in depths:
            raise SpareTwinError(f"{depth_path(k)}: missing (colour frame {colors[k].name} has no depth)")
    for k in sorted(depths):
        if k not in colors:
            expected = f" {colour_path(k)}" if colour_path else ""
            raise SpareTwinError(f"{depths[k]}: extra depth frame with no matching colour frame{expected}")


def list_7scenes(src: Path) -> Source:
    color_re = re.compile(r"frame-(\d+)\.color\.(?:png|jpg)")
    depth_re = re.compile(r"frame-(\d+)\.depth\.png")
    colors = {n: p for p in src.iterdir() if (n := _frame_number(p, color_re)) is not None}
    depths = {n: p for p in src.iterdir() if (n := _frame_number(p, depth_re)) is not None}
    if not colors and not depths:
        raise SpareTwinError(f"{src}: no frame-NNNNNN.color.png / .depth.png files (not a 7-Scenes layout?)")
    _check_pairs(colors, depths, lambda n: src / re.sub(r"\.color\.(png|jpg)$", ".depth.png", colors[n].name))
    poses = {n: src / f"frame-{n:06d}.pose.txt" for n in colors}
    have = [n for n in sorted(colors) if poses[n].is_file()]
    if have and len(have) != len(colors):
        first_missing = next(n for n in sorted(colors) if not poses[n].is_file())
        raise SpareTwinError(f"{poses[first_missing]}: missing (other frames have poses)")
    frames = [
        FrameFiles(f"frame-{n:06d}", colors[n], depths[n], _pose_file(poses[n]) if have else None)
        for n in sorted(colors)
    ]
    K = None
    for name in ("intrinsics.K.txt", "camera-intrinsics.txt", "intrinsics.txt"):
        if (src / name).is_file():
            K = read_K_txt(src / name)
            break
    # 7-Scenes marks missing depth as 65535; tsdf-fusion data uses 0. Both become 0.
    return Source(
        frames, K, MM_DEPTH_SCALE, None, "unknown (7-Scenes / tsdf-fusion layout)", "7scenes", depth_invalid_value=65535
    )


def _pose_file(path: Path) -> np.ndarray:
    """A 7-Scenes frame-NNNNNN.pose.txt: a rigid 4x4 camera-to-world pose (bottom row 0 0 0 1, under a km)."""
    try:
        T = np.loadtxt(path, dtype=np.float64)
    except (ValueError, OSError) as exc:
        raise SpareTwinError(f"{path}: not a 4x4 pose ({' '.join(str(exc).split())})") from None
    return check_pose(T, str(path))


def _read_tum_list(path: Path) -> list[tuple[float, list[str]]]:
    rows = []
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        try:
            rows.append((float(parts[0]), parts[1:]))
        except (ValueError, IndexError):
            raise SpareTwinError(f"{path}:{lineno}: expected 'timestamp value...'") from None
    if not rows:
        raise SpareTwinError(f"{path}: no entries")
    return rows


def _nearest(t: float, times: np.ndarray) -> int:
    return int(np.argmin(np.abs(times - t)))


def _tum_pose(values: list[str], path: Path, t: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    where = f"{path}: the pose at {t:.6f} s"
    try:
        tx, ty, tz, qx, qy, qz, qw = (float(v) for v in values[:7])
    except ValueError:
        raise SpareTwinError(f"{path}: expected 'timestamp tx ty tz qx qy qz qw'") from None
    q = np.array([qx, qy, qz, qw])
    norm = float(np.linalg.norm(q)) if np.isfinite(q).all() else 0.0
    if not 0.5 < norm < 2.0:  # scipy would normalise anything non-zero; a far-off norm is not a rotation
        raise SpareTwinError(f"{where}: quaternion {qx:g} {qy:g} {qz:g} {qw:g} is not a unit quaternion")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(q / norm).as_matrix()  # scipy: scalar-last, like TUM
    T[:3, 3] = (tx, ty, tz)
    return check_pose(T, where)


def list_tum(src: Path) -> Source:
    rgb_txt, depth_txt = src / "rgb.txt", src / "depth.txt"
    if not rgb_txt.is_file() and not depth_txt.is_file():
        return _list_tum_pairs(src)
    for p in (rgb_txt, depth_txt):
        if not p.is_file():
            raise SpareTwinError(f"{p}: missing (a TUM layout needs rgb.txt and depth.txt)")
    rgb = _read_tum_list(rgb_txt)
    depth = _read_tum_list(depth_txt)
    d_times = np.array([t for t, _ in depth])
    gt = None
    if (src / "groundtruth.txt").is_file():
        gt = _read_tum_list(src / "groundtruth.txt")
        gt_times = np.array([t for t, _ in gt])
    frames, used = [], set()
    for t, (name, *_rest) in rgb:
        j = _nearest(t, d_times)
        if abs(d_times[j] - t) > TUM_MAX_DT_S or j in used:
            continue  # no depth for this colour frame: TUM streams are not synchronised, skip it
        used.add(j)
        pose = None
        if gt is not None:
            k = _nearest(t, gt_times)
            if abs(gt_times[k] - t) <= TUM_MAX_DT_S:
                pose = _tum_pose(gt[k][1], src / "groundtruth.txt", gt_times[k])
        frames.append(FrameFiles(Path(name).stem, src / name, src / depth[j][1][0], pose, t))
    if not frames:
        raise SpareTwinError(f"{rgb_txt}: no colour frame has a depth frame within {TUM_MAX_DT_S} s")
    for f in frames:
        for p in (f.color, f.depth):
            if not p.is_file():
                raise SpareTwinError(f"{p}: missing (listed in {rgb_txt.name if p == f.color else depth_txt.name})")
    if any(f.T_world_camera is None for f in frames) and any(f.T_world_camera is not None for f in frames):
        n = sum(f.T_world_camera is None for f in frames)
        print(
            f"warning: {src / 'groundtruth.txt'}: {n} frames have no pose within {TUM_MAX_DT_S} s; "
            "poses set to unknown",
            file=sys.stderr,
        )
        frames = [FrameFiles(f.name, f.color, f.depth, None, f.timestamp_s) for f in frames]
    return Source(frames, None, TUM_DEPTH_SCALE, None, "Microsoft Kinect v1 (TUM RGB-D)", "tum")


def _list_tum_pairs(src: Path) -> Source:
    depth_re = re.compile(r"(.+)_depth\.png")
    depths = {m.group(1): p for p in src.iterdir() if (m := depth_re.fullmatch(p.name))}
    colors = {p.stem: p for p in src.glob("*.png") if not depth_re.fullmatch(p.name)}
    if not depths:
        raise SpareTwinError(f"{src}: no rgb.txt/depth.txt and no N.png + N_depth.png pairs (not a TUM layout?)")
    _check_pairs(colors, depths, lambda k: src / f"{k}_depth.png", lambda k: src / f"{k}.png")

    def order(k: str):
        return (0, int(k), k) if k.isdigit() else (1, 0, k)

    frames = [FrameFiles(k, colors[k], depths[k]) for k in sorted(colors, key=order)]
    return Source(frames, None, TUM_DEPTH_SCALE, None, "Microsoft Kinect v1 (TUM RGB-D)", "tum")


def list_open3d(src: Path) -> Source:
    cdir, ddir = src / "color", src / "depth"
    for d in (cdir, ddir):
        if not d.is_dir():
            raise SpareTwinError(f"{d}: missing (an Open3D recorder folder has color/ and depth/)")
    colors = {p.stem: p for p in cdir.iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".png")}
    depths = {p.stem: p for p in ddir.iterdir() if p.suffix.lower() == ".png"}
    _check_pairs(colors, depths, lambda k: ddir / f"{k}.png")
    if not colors:
        raise SpareTwinError(f"{cdir}: no frames")
    K, depth_scale, fps, model = None, MM_DEPTH_SCALE, None, "Intel RealSense (Open3D recorder)"
    for name in ("camera_intrinsic.json", "intrinsic.json"):
        p = src / name
        if p.is_file():
            meta = read_json(p)
            try:
                m = np.asarray(meta["intrinsic_matrix"], dtype=np.float64).reshape(3, 3).T  # open3d: column-major
            except (KeyError, TypeError, ValueError) as exc:  # TypeError: not a JSON object, or not numbers
                raise SpareTwinError(f"{p}: no 3x3 intrinsic_matrix ({exc})") from None
            K = K_from(m[0, 0], m[1, 1], m[0, 2], m[1, 2])
            try:
                if meta.get("depth_scale"):
                    depth_scale = 1.0 / float(meta["depth_scale"])  # open3d stores units per metre
                fps = float(meta["fps"]) if meta.get("fps") else None
            except (TypeError, ValueError, ZeroDivisionError, OverflowError) as exc:
                raise SpareTwinError(f"{p}: depth_scale and fps must be numbers ({exc})") from None
            if not (np.isfinite(K).all() and np.isfinite(depth_scale) and depth_scale > 0):
                raise SpareTwinError(f"{p}: intrinsic_matrix and depth_scale must be finite and positive")
            model = str(meta.get("device_name") or model)
            break
    frames = [FrameFiles(k, colors[k], depths[k]) for k in sorted(colors)]
    return Source(frames, K, depth_scale, fps, model, "open3d")


LISTERS = {"7scenes": list_7scenes, "tum": list_tum, "open3d": list_open3d}
