"""Reading a recording: `Recording.open(folder)`, then metadata, per-frame images, poses and ground truth."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spare_twin.errors import SpareTwinError
from spare_twin.io import read_png, write_bytes_atomic
from spare_twin.recording.format import (
    FORMAT,
    REFERENCE_POSES,
    VERSION,
    Camera,
    Registration,
    frame_file_name,
    npz_bytes,
)


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
        try:
            meta = json.loads(meta_path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise SpareTwinError(f"{meta_path}: not valid JSON ({exc})") from None
        if meta.get("format") != FORMAT:
            raise SpareTwinError(f"{meta_path}: not a {FORMAT} file")
        if meta.get("version") != VERSION:
            raise SpareTwinError(f"{meta_path}: unsupported version {meta.get('version')}")
        for key in ("frames", "fps", "depth_scale", "cameras"):
            if key not in meta:
                raise SpareTwinError(f"{meta_path}: missing key {key}")
        cameras = [Camera.from_dict(c, str(meta_path)) for c in meta["cameras"]]
        if not cameras:
            raise SpareTwinError(f"{meta_path}: no cameras")
        rec = cls(root, meta, cameras)
        for cam in cameras:
            if cam.poses == "per_frame":
                p = root / "cameras" / cam.name / "T_world_camera.npy"
                if not p.is_file():
                    raise SpareTwinError(f"{p}: missing (camera {cam.name} has per-frame poses)")
                poses = np.load(p)
                if poses.shape != (rec.n_frames, 4, 4):
                    raise SpareTwinError(f"{p}: expected shape ({rec.n_frames}, 4, 4), got {poses.shape}")
                rec._poses[cam.name] = poses
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
        return self.meta.get("object")

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
        return self._checked(cam, "segmentation", frame)

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
            return np.load(p)
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
        with np.load(p) as z:
            return {k: z[k] for k in z.files}

    def write_ground_truth(self, arrays: dict[str, np.ndarray]) -> None:
        """Replace the recording's ground_truth.npz atomically (an importer keeps what is known of the object)."""
        write_bytes_atomic(self.root / "ground_truth.npz", npz_bytes(arrays))

    def _checked(self, cam: str, kind: str, frame: int) -> np.ndarray:
        if not 0 <= frame < self.n_frames:
            raise SpareTwinError(f"{self.root}: frame {frame} out of range 0..{self.n_frames - 1}")
        c = self.camera(cam)
        path = self.path(cam, kind, frame)
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
                want = [frame_file_name(i) for i in range(self.n_frames)]
                if have != want:
                    missing = sorted(set(want) - set(have))
                    extra = sorted(set(have) - set(want))
                    what = f"missing {folder / missing[0]}" if missing else f"unexpected {folder / extra[0]}"
                    raise SpareTwinError(f"{self.root}: {what}")
