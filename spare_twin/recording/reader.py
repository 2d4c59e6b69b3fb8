"""Reading a recording: `Recording.open(folder)`, then metadata, per-frame images, poses and ground truth."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spare_twin.config import with_paper_lengths
from spare_twin.errors import SpareTwinError
from spare_twin.io import read_json, read_npy, read_png, write_bytes_atomic
from spare_twin.recording.format import (
    FORMAT,
    MAX_FRAMES,
    REFERENCE_POSES,
    VERSION,
    Camera,
    Registration,
    frame_file_name,
    npz_bytes,
)
from spare_twin.validate import check_poses


@dataclass
class Recording:
    """A recording folder opened for reading. Images are read lazily, one frame at a time."""

    root: Path
    meta: dict
    cameras: list[Camera]
    _poses: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    @classmethod
    def open(cls, root: str | Path) -> Recording:
        root = Path(root)
        meta_path = root / "recording.json"
        if not root.is_dir():
            raise SpareTwinError(f"{root}: not a folder")
        if not meta_path.is_file():
            raise SpareTwinError(f"{root}: not a recording (no recording.json)")
        meta = read_json(meta_path)  # bounded: nesting, integer digits, size
        _check_meta(meta, meta_path)
        cameras = [Camera.from_dict(c, str(meta_path)) for c in meta["cameras"]]
        names = [c.name for c in cameras]
        if len(set(names)) != len(names):
            raise SpareTwinError(f"{meta_path}: cameras: camera names must be unique, got {names}")
        rec = cls(root, meta, cameras)
        if meta.get("registration"):
            reg = Registration.from_dict(meta["registration"], str(meta_path))
            if reg.camera not in names:
                raise SpareTwinError(f"{meta_path}: registration: no camera named {reg.camera!r}")
        for cam in cameras:
            if cam.poses == "per_frame":
                p = root / "cameras" / cam.name / "T_world_camera.npy"
                if not p.is_file():
                    raise SpareTwinError(f"{p}: missing (camera {cam.name} has per-frame poses)")
                rec._poses[cam.name] = _load_poses(p, rec.n_frames)
        return rec

    # -- metadata ------------------------------------------------------------------------
    @property
    def n_frames(self) -> int:
        return int(self.meta["frames"])

    @property
    def fps(self) -> float:
        return float(self.meta["fps"])

    @property
    def depth_scale(self) -> float:
        return float(self.meta["depth_scale"])

    @property
    def source(self) -> dict:
        return dict(self.meta.get("source") or {})

    @property
    def object_config(self) -> dict | None:
        obj = self.meta.get("object")
        return with_paper_lengths(obj, str(self.root / "recording.json")) if isinstance(obj, dict) else obj

    @property
    def rig(self) -> str | None:
        return self.meta.get("rig")

    @property
    def timestamps_s(self) -> np.ndarray:
        ts = self.meta.get("timestamps_s")
        if ts is None:
            return np.arange(self.n_frames, dtype=np.float64) / self.fps
        return np.asarray(ts, dtype=np.float64)

    @property
    def registration(self) -> Registration | None:
        """What `capture register` wrote into recording.json (camera, world, summary, fused cloud, object),
        or None for a recording that was never registered."""
        d = self.meta.get("registration")
        return Registration.from_dict(d, str(self.root / "recording.json")) if d else None

    @property
    def in_sim_world(self) -> bool:
        """True for an unregistered simulation recording whose cameras are all posed: its world frame is
        the simulation's (table z = 0, the object's base at the origin, the chain in the x-z plane)."""
        return (
            self.registration is None
            and self.source.get("kind") == "sim"
            and all(c.poses != "unknown" for c in self.cameras)
        )

    def camera(self, name: str) -> Camera:
        for cam in self.cameras:
            if cam.name == name:
                return cam
        raise SpareTwinError(f"{self.root}: no camera named {name!r}")

    # -- per-frame data ------------------------------------------------------------------
    def path(self, cam: str, kind: str, frame: int) -> Path:
        return self.root / "cameras" / cam / kind / frame_file_name(frame)

    def color(self, cam: str, frame: int) -> np.ndarray:
        """uint8 (H, W, 3) RGB."""
        import cv2

        img = self._checked(cam, "color", frame)
        if img.ndim == 2:
            img = np.repeat(img[..., None], 3, axis=2)
        if img.dtype != np.uint8:
            raise SpareTwinError(f"{self.path(cam, 'color', frame)}: colour must be 8-bit")
        return cv2.cvtColor(img[..., :3], cv2.COLOR_BGR2RGB)

    def depth_m(self, cam: str, frame: int) -> np.ndarray:
        """float32 (H, W) z-depth in metres, 0 where there is no reading."""
        return self.depth_raw(cam, frame).astype(np.float32) * np.float32(self.depth_scale)

    def segmentation(self, cam: str, frame: int) -> np.ndarray | None:
        """uint8 (H, W): 0 background, k = link k - 1; None when the recording has none."""
        if not self.path(cam, "segmentation", frame).is_file():
            return None
        img = self._checked(cam, "segmentation", frame)
        if img.dtype != np.uint8 or img.ndim != 2:
            raise SpareTwinError(
                f"{self.path(cam, 'segmentation', frame)}: segmentation must be a single-channel 8-bit PNG"
            )
        return img

    def depth_raw(self, cam: str, frame: int) -> np.ndarray:
        """uint16 (H, W) depth as stored: metres = value * depth_scale, 0 = no reading."""
        img = self._checked(cam, "depth", frame)
        if img.dtype != np.uint16 or img.ndim != 2:
            raise SpareTwinError(f"{self.path(cam, 'depth', frame)}: depth must be a single-channel 16-bit PNG")
        return img

    def camera_poses(self, cam: str) -> np.ndarray | None:
        """(frames, 4, 4) camera-to-world poses of `cam` (a fixed camera's pose repeated), None when unknown."""
        c = self.camera(cam)
        if c.poses == "per_frame":
            return self._poses[cam].copy()
        if c.T_world_camera is None:
            return None
        return np.repeat(np.asarray(c.T_world_camera, np.float64)[None], self.n_frames, axis=0)

    def reference_poses(self, cam: str) -> np.ndarray | None:
        """(frames, 4, 4) poses `cam` came with (an importer's, a calibration's), before any registration
        replaced them (it keeps them as cameras/<cam>/T_world_camera.reference.npy); None when unknown."""
        p = self.root / "cameras" / cam / REFERENCE_POSES
        if p.is_file():
            return _load_poses(p, self.n_frames)
        if self.registration is not None:
            return None
        return self.camera_poses(cam)

    def T_world_camera(self, cam: str, frame: int) -> np.ndarray | None:
        c = self.camera(cam)
        if c.poses == "per_frame":
            return self._poses[cam][frame]
        return c.T_world_camera

    def ground_truth(self) -> dict[str, np.ndarray] | None:
        p = self.root / "ground_truth.npz"
        if not p.is_file():
            return None
        try:
            with np.load(p, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except Exception as exc:  # zip, npy header (ValueError, SyntaxError, tokenize errors), zlib...
            raise SpareTwinError(f"{p}: not a readable .npz file ({_one_line(exc)})") from None
        return with_paper_lengths(arrays, str(p))

    def write_ground_truth(self, arrays: dict[str, np.ndarray]) -> None:
        """Replace the recording's ground_truth.npz atomically (an importer keeps what is known of the object)."""
        write_bytes_atomic(self.root / "ground_truth.npz", npz_bytes(arrays))

    def _checked(self, cam: str, kind: str, frame: int) -> np.ndarray:
        if not 0 <= frame < self.n_frames:
            raise SpareTwinError(f"{self.root}: frame {frame} out of range 0..{self.n_frames - 1}")
        c = self.camera(cam)
        path = self.path(cam, kind, frame)
        if path.is_file() and path.stat().st_size == 0:  # OpenCV would log a warning of its own as well
            raise SpareTwinError(f"{path}: empty file (0 bytes), not an image")
        img = read_png(path)
        if img.shape[:2] != (c.height, c.width):
            raise SpareTwinError(
                f"{path}: size {img.shape[1]}x{img.shape[0]} does not match camera {cam} ({c.width}x{c.height})"
            )
        return img

    def validate(self) -> None:
        """Check that every camera has a colour and a depth picture for every frame (names the first gap)."""
        for cam in self.cameras:
            for kind in ("color", "depth"):
                folder = self.root / "cameras" / cam.name / kind
                have = sorted(p.name for p in folder.glob("*.png")) if folder.is_dir() else []
                if len(have) > self.n_frames:
                    raise SpareTwinError(f"{self.root}: {folder} holds {len(have)} pictures for {self.n_frames} frames")
                # same count: listing the expected names is cheap (a huge `frames` stops above or here)
                want = [frame_file_name(i) for i in range(min(self.n_frames, len(have) + 1))]
                if have != want:
                    missing = sorted(set(want) - set(have))
                    extra = sorted(set(have) - set(want))
                    what = f"missing {folder / missing[0]}" if missing else f"unexpected {folder / extra[0]}"
                    raise SpareTwinError(f"{self.root}: {what}")


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _check_meta(meta, meta_path: Path) -> None:
    """recording.json's keys have the types and ranges the format says (one-line errors naming the key)."""
    if not isinstance(meta, dict):
        raise SpareTwinError(f"{meta_path}: expected a JSON object, got {type(meta).__name__}")
    if meta.get("format") != FORMAT:
        raise SpareTwinError(f"{meta_path}: not a {FORMAT} file")
    version = meta.get("version")
    if type(version) is not int or version != VERSION:
        raise SpareTwinError(f"{meta_path}: unsupported version {version!r}")
    for key in ("frames", "fps", "depth_scale", "cameras"):
        if key not in meta:
            raise SpareTwinError(f"{meta_path}: missing key {key}")

    def bad(key: str, want: str) -> SpareTwinError:
        return SpareTwinError(f"{meta_path}: {key} {json.dumps(meta[key])[:40]}: must be {want}")

    frames = meta["frames"]
    if type(frames) is not int or not 1 <= frames <= MAX_FRAMES:
        raise bad("frames", f"a whole number of frames, 1..{MAX_FRAMES:,} (frame files have 6 digits)")
    if not _number(meta["fps"]) or meta["fps"] <= 0:
        raise bad("fps", "a positive number")
    if not _number(meta["depth_scale"]) or not 0 < meta["depth_scale"] <= 1:
        raise bad("depth_scale", "metres per depth unit, a number in (0, 1]")
    ts = meta.get("timestamps_s")
    if ts is not None and (not isinstance(ts, list) or len(ts) != frames or not all(_number(t) for t in ts)):
        raise bad("timestamps_s", f"null or a list of {frames} finite numbers (one per frame)")
    for key, kind, want in (
        ("source", dict, "an object"),
        ("object", dict, "an object or null"),
        ("rig", str, "a rig name or null"),
        ("registration", dict, "an object or null"),
    ):
        if meta.get(key) is not None and not isinstance(meta[key], kind):
            raise bad(key, want)
    if not isinstance(meta["cameras"], list) or not meta["cameras"]:
        raise bad("cameras", "a non-empty list of camera entries")


def _load_poses(p: Path, frames: int) -> np.ndarray:
    """A (frames, 4, 4) array of rigid camera-to-world poses from `p` (the writer refuses any other)."""
    poses = read_npy(p)  # header checked against the file size; any parse failure is one line
    if not isinstance(poses, np.ndarray) or poses.dtype.kind not in "fiu":
        raise SpareTwinError(f"{p}: expected a numeric array of poses")
    if poses.shape != (frames, 4, 4):
        raise SpareTwinError(f"{p}: expected shape ({frames}, 4, 4), got {poses.shape}")
    return check_poses(poses, str(p))  # finite, rigid, a proper bottom row, a plausible translation
