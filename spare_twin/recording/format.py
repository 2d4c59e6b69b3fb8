"""What a recording folder holds, as types: the format's constants, a camera entry, the registration
result and the byte encodings every writer shares (see the package doc for the layout)."""

from __future__ import annotations

import io
import json
import zipfile
from dataclasses import dataclass
from typing import Any

import numpy as np

from spare_twin.errors import SpareTwinError
from spare_twin.validate import check_pose

FORMAT = "spare-twin-recording"
VERSION = 1
SIM_DEPTH_SCALE = 1e-4  # 0.1 mm per unit: up to 6.5 m in uint16
POSES = ("fixed", "per_frame", "unknown")
#: Beside cameras/<cam>/T_world_camera.npy: the poses a camera had before its first registration.
REFERENCE_POSES = "T_world_camera.reference.npy"


#: Most frames in a recording: the frame files are numbered with 6 digits (at 30 fps, over 9 hours).
MAX_FRAMES = 999_999


def frame_file_name(i: int) -> str:
    """The picture of frame `i` inside cameras/<cam>/<kind>/."""
    return f"{i:06d}.png"


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
        if not isinstance(d, dict):
            raise SpareTwinError(f"{source}: bad camera entry (expected an object, got {type(d).__name__})")
        for key in ("name", "width", "height", "K"):
            if key not in d:
                raise SpareTwinError(f"{source}: bad camera entry (missing key {key})")
        name = d["name"]
        # the name is a folder under cameras/: a plain, visible name
        if not isinstance(name, str) or not name or name.startswith(".") or "/" in name or "\\" in name:
            raise SpareTwinError(f"{source}: camera name {json.dumps(name)[:40]}: must be a plain folder name")
        for key in ("width", "height"):
            if type(d[key]) is not int or not 0 < d[key] < 2**31:
                raise SpareTwinError(f"{source}: camera {name}: {key} {json.dumps(d[key])[:40]}: must be a pixel count")
        poses = d.get("poses", "fixed")
        if poses not in POSES:
            raise SpareTwinError(f"{source}: camera {name}: poses must be fixed, per_frame or unknown")
        try:
            K = np.asarray(d["K"], dtype=np.float64)
            T = d.get("T_world_camera")
            T = None if T is None else np.asarray(T, dtype=np.float64)
        except (TypeError, ValueError, OverflowError) as exc:
            raise SpareTwinError(f"{source}: camera {name}: bad K or T_world_camera ({exc})") from None
        if K.shape != (3, 3) or (T is not None and T.shape != (4, 4)):
            raise SpareTwinError(f"{source}: camera {name}: K must be 3x3 and T_world_camera 4x4")
        if not np.isfinite(K).all() or (T is not None and not np.isfinite(T).all()):
            raise SpareTwinError(f"{source}: camera {name}: K and T_world_camera must be finite")
        if T is not None:
            check_pose(T, f"{source}: camera {name}: T_world_camera")
        return cls(name, d["width"], d["height"], K, T, poses)


@dataclass(frozen=True)
class Registration:
    """What `capture register` stored under recording.json's ``registration``.

    The world frame is the reference world when the recording's own poses were used, else the first
    frame's camera.
    """

    camera: str
    """The registered camera; its poses are now per frame."""
    used_reference: bool
    world: str
    """"reference" or "first camera"."""
    config: dict[str, Any]
    """The registration, fusion and segmentation settings, as ``{"registration": ..., "fusion": ...,
    "segment": ...}``."""
    summary: dict[str, Any]
    """Edges, fitness, timings and the fused point count."""
    fused: str
    """The fused cloud's file, relative to the recording."""
    mesh: str | None = None
    """The fused mesh's file, when one was made."""
    object: dict[str, Any] | None = None
    """The object found on the table (``file``, ``points``, ``height_m``, ``footprint_m``,
    ``T_world_object``, ``table_plane``), or None."""

    def to_dict(self) -> dict:
        """The recording.json entry (keys in the order `capture register` has always written them)."""
        return {
            "camera": self.camera,
            "used_reference": self.used_reference,
            "world": self.world,
            "config": self.config,
            "summary": self.summary,
            "fused": self.fused,
            "mesh": self.mesh,
            "object": self.object,
        }

    @classmethod
    def from_dict(cls, d: dict, source: str) -> Registration:
        try:
            reg = cls(
                camera=str(d["camera"]),
                used_reference=bool(d["used_reference"]),
                world=str(d["world"]),
                config=dict(d.get("config") or {}),
                summary=dict(d.get("summary") or {}),
                fused=str(d["fused"]),
                mesh=d.get("mesh"),
                object=None if d.get("object") is None else dict(d["object"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise SpareTwinError(f"{source}: bad registration entry ({exc})") from None
        if reg.object is not None and ("file" not in reg.object or "T_world_object" not in reg.object):
            raise SpareTwinError(f"{source}: registration object needs a file and T_world_object")
        if reg.object is not None:
            try:
                T = np.asarray(reg.object["T_world_object"], dtype=np.float64)
            except (TypeError, ValueError, OverflowError) as exc:
                raise SpareTwinError(f"{source}: registration: object: bad T_world_object ({exc})") from None
            check_pose(T, f"{source}: registration: object: T_world_object")
        return reg

    @property
    def object_file(self) -> str | None:
        """The object's points (relative to the recording), None when no object was found."""
        return None if self.object is None else str(self.object["file"])

    @property
    def T_world_object(self) -> np.ndarray | None:
        """4x4 pose of the object frame (z up, table z = 0) in the registered world; None without an object."""
        return None if self.object is None else np.asarray(self.object["T_world_object"], np.float64)


def depth_to_uint16(depth_m: np.ndarray, depth_scale: float) -> np.ndarray:
    """Metres to uint16 units; non-finite, non-positive and out-of-range depths become 0 (no reading)."""
    d = np.asarray(depth_m, dtype=np.float64) / depth_scale
    valid = np.isfinite(d) & (d > 0) & (d < 65535.5)
    out = np.zeros(d.shape, dtype=np.uint16)
    out[valid] = np.rint(d[valid]).astype(np.uint16)
    return out


def npy_bytes(array) -> bytes:
    """np.save into bytes (for `update_recording` and the writers' atomic file writes)."""
    b = io.BytesIO()
    np.save(b, np.asarray(array), allow_pickle=False)
    return b.getvalue()


def npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    """np.savez without zip timestamps, so the same arrays always give the same bytes."""
    b = io.BytesIO()
    with zipfile.ZipFile(b, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name in sorted(arrays):
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            zf.writestr(info, npy_bytes(arrays[name]))
    return b.getvalue()
