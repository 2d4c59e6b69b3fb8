"""The recording format: one folder layout that the twin simulation and the capture tools both write,
and that `predict`, `compare` and the Rerun logger read.

Layout (all paths relative to the recording folder)::

    recording.json                      metadata, below
    cameras/<cam>/color/000000.png      8-bit RGB
    cameras/<cam>/depth/000000.png      uint16, depth_m = value * depth_scale, 0 = no reading (z-depth)
    cameras/<cam>/segmentation/000000.png   uint8, 0 = background, k = link k-1 (sim only, optional)
    cameras/<cam>/T_world_camera.npy    float64 (frames, 4, 4), only for cameras that move
    ground_truth.npz                    sim only, optional: joint_angles_rad (frames, n),
                                        T_world_link (frames, n + 1, 4, 4), link_lengths_pu (n + 1,)

recording.json keys: ``format`` ("spare-twin-recording"), ``version`` (1), ``frames`` (int),
``fps`` (float), ``depth_scale`` (metres per depth unit), ``timestamps_s`` (one per frame),
``source`` ({"kind": "sim" | "sensor", "sensor_model": str, ...}), ``object`` (the object.json
configuration, or null), ``rig`` (name of the training rig the cameras are, or null) and
``cameras``: a list of {``name``, ``width``, ``height``, ``K`` (3x3, pixels), ``T_world_camera``
(4x4 camera-to-world, OpenCV axes: x right, y down, z forward; null when per-frame or unknown),
``poses`` ("fixed" | "per_frame" | "unknown")}.

Every camera has a picture for every frame. Writers build the folder under a temporary name and
rename it into place, so an existing recording is never half-overwritten.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spare_twin.errors import SpareTwinError
from spare_twin.io import atomic_dir, encode_png, read_png, write_bytes_atomic

FORMAT = "spare-twin-recording"
VERSION = 1
SIM_DEPTH_SCALE = 1e-4  # 0.1 mm per unit: up to 6.5 m in uint16


@dataclass(frozen=True)
class Camera:
    """One camera of a recording: intrinsics and, where known, its fixed pose."""

    name: str
    width: int
    height: int
    K: np.ndarray
    """3x3 pinhole intrinsics in pixels."""
    T_world_camera: np.ndarray | None = None
    """4x4 camera-to-world pose when the camera is fixed."""
    poses: str = "fixed"
    """"fixed", "per_frame" (cameras/<name>/T_world_camera.npy) or "unknown"."""

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "width": int(self.width),
            "height": int(self.height),
            "K": np.asarray(self.K, dtype=np.float64).tolist(),
            "T_world_camera": None
            if self.T_world_camera is None
            else np.asarray(self.T_world_camera, np.float64).tolist(),
            "poses": self.poses,
        }

    @classmethod
    def from_dict(cls, d: dict, source: str) -> Camera:
        try:
            K = np.asarray(d["K"], dtype=np.float64)
            T = d.get("T_world_camera")
            T = None if T is None else np.asarray(T, dtype=np.float64)
            cam = cls(str(d["name"]), int(d["width"]), int(d["height"]), K, T, str(d.get("poses", "fixed")))
        except (KeyError, TypeError, ValueError) as exc:
            raise SpareTwinError(f"{source}: bad camera entry ({exc})") from None
        if cam.K.shape != (3, 3) or (cam.T_world_camera is not None and cam.T_world_camera.shape != (4, 4)):
            raise SpareTwinError(f"{source}: camera {cam.name}: K must be 3x3 and T_world_camera 4x4")
        if cam.poses not in ("fixed", "per_frame", "unknown"):
            raise SpareTwinError(f"{source}: camera {cam.name}: poses must be fixed, per_frame or unknown")
        return cam


def _frame_name(i: int) -> str:
    return f"{i:06d}.png"


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
    def registration(self) -> dict | None:
        """What `capture register` wrote into recording.json (camera, world, summary, fused cloud, object),
        or None for a recording that was never registered."""
        return self.meta.get("registration") or None

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
        return self.root / "cameras" / cam / kind / _frame_name(frame)

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
                want = [_frame_name(i) for i in range(self.n_frames)]
                if have != want:
                    missing = sorted(set(want) - set(have))
                    extra = sorted(set(have) - set(want))
                    what = f"missing {folder / missing[0]}" if missing else f"unexpected {folder / extra[0]}"
                    raise SpareTwinError(f"{self.root}: {what}")


class RecordingWriter:
    """Writes a recording under a temporary name; `close()` renames it into place.

    Use as a context manager: on an exception nothing at `root` changes.
    """

    def __init__(
        self,
        root: str | Path,
        cameras: list[Camera],
        n_frames: int,
        fps: float,
        source: dict,
        depth_scale: float = SIM_DEPTH_SCALE,
        object_config: dict | None = None,
        rig: str | None = None,
        timestamps_s: list[float] | None = None,
        png_compression: int = 1,
    ):
        if n_frames <= 0:
            raise SpareTwinError("a recording needs at least one frame")
        names = [c.name for c in cameras]
        if len(set(names)) != len(names) or not names:
            raise SpareTwinError(f"camera names must be unique and non-empty: {names}")
        self.root = Path(root)
        self.cameras = cameras
        self.n_frames = n_frames
        self.depth_scale = float(depth_scale)
        self.png_compression = png_compression
        self._poses = {c.name: np.full((n_frames, 4, 4), np.nan) for c in cameras if c.poses == "per_frame"}
        self.meta = {
            "format": FORMAT,
            "version": VERSION,
            "frames": int(n_frames),
            "fps": float(fps),
            "depth_scale": self.depth_scale,
            "timestamps_s": [
                float(t) for t in (timestamps_s if timestamps_s is not None else np.arange(n_frames) / fps)
            ],
            "source": source,
            "object": object_config,
            "rig": rig,
            "cameras": [c.to_dict() for c in cameras],
        }
        self._ctx = atomic_dir(self.root)
        self.tmp: Path | None = None

    def __enter__(self) -> RecordingWriter:
        self.tmp = self._ctx.__enter__()
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self._finish()
        return self._ctx.__exit__(exc_type, exc, tb)

    def _write_png(self, cam: str, kind: str, frame: int, img: np.ndarray) -> None:
        write_bytes_atomic(
            self.tmp / "cameras" / cam / kind / _frame_name(frame), encode_png(img, self.png_compression)
        )

    def add_frame(
        self,
        cam: str,
        frame: int,
        color_rgb: np.ndarray,
        depth_m: np.ndarray,
        segmentation: np.ndarray | None = None,
        T_world_camera: np.ndarray | None = None,
    ) -> None:
        import cv2

        assert self.tmp is not None, "use RecordingWriter as a context manager"
        self._write_png(cam, "color", frame, cv2.cvtColor(np.asarray(color_rgb, np.uint8), cv2.COLOR_RGB2BGR))
        self._write_png(cam, "depth", frame, depth_to_uint16(depth_m, self.depth_scale))
        if segmentation is not None:
            self._write_png(cam, "segmentation", frame, np.asarray(segmentation, np.uint8))
        if T_world_camera is not None:
            self._poses[cam][frame] = T_world_camera

    def add_encoded(self, cam: str, frame: int, color_png: bytes, depth_u16: np.ndarray) -> None:
        """Store already-encoded colour and raw uint16 depth (importers: no lossy round trip)."""
        write_bytes_atomic(self.tmp / "cameras" / cam / "color" / _frame_name(frame), color_png)
        self._write_png(cam, "depth", frame, np.asarray(depth_u16, np.uint16))

    def set_pose(self, cam: str, frame: int, T_world_camera: np.ndarray) -> None:
        self._poses[cam][frame] = T_world_camera

    def set_ground_truth(self, **arrays: np.ndarray) -> None:
        buf = npz_bytes(arrays)
        write_bytes_atomic(self.tmp / "ground_truth.npz", buf)

    def _finish(self) -> None:
        import io as _io

        for cam, poses in self._poses.items():
            if np.isnan(poses).any():
                raise SpareTwinError(f"{self.root}: camera {cam} is missing per-frame poses")
            b = _io.BytesIO()
            np.save(b, poses)
            write_bytes_atomic(self.tmp / "cameras" / cam / "T_world_camera.npy", b.getvalue())
        write_bytes_atomic(self.tmp / "recording.json", (json.dumps(self.meta, indent=2) + "\n").encode())
        Recording.open(self.tmp).validate()


def depth_to_uint16(depth_m: np.ndarray, depth_scale: float) -> np.ndarray:
    """Metres to uint16 units; non-finite, non-positive and out-of-range depths become 0 (no reading)."""
    d = np.asarray(depth_m, dtype=np.float64) / depth_scale
    valid = np.isfinite(d) & (d > 0) & (d < 65535.5)
    out = np.zeros(d.shape, dtype=np.uint16)
    out[valid] = np.rint(d[valid]).astype(np.uint16)
    return out


def npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    """np.savez without zip timestamps, so the same arrays always give the same bytes."""
    import io as _io
    import zipfile

    b = _io.BytesIO()
    with zipfile.ZipFile(b, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name in sorted(arrays):
            arr_buf = _io.BytesIO()
            np.save(arr_buf, np.asarray(arrays[name]), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            zf.writestr(info, arr_buf.getvalue())
    return b.getvalue()
