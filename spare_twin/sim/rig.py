"""Camera rigs: where the RGB-D cameras stand, what they look at, and their pinhole intrinsics.

A rig is a frozen dataclass stored as JSON in `capture/rigs/<name>.json`. Cameras stand on a circle
around the object (evenly spaced in azimuth, heights cycled from `heights_m`) and look at
`look_at_m`. Poses are 4x4 camera-to-world in the OpenCV convention (x right, y down, z forward),
world z up. Intrinsics are square-pixel pinholes with the principal point at the image centre
((W - 1) / 2, (H - 1) / 2: OpenCV puts pixel centres on integers), derived from `fov_y_deg` for any
resolution, so the network (96 x 128) and recording resolutions see exactly the same view.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spare_twin.errors import SpareTwinError
from spare_twin.io import read_json

#: Folder of the shipped rig files (repository root / capture / rigs).
RIGS_DIR = Path(__file__).resolve().parents[2] / "capture" / "rigs"
DEFAULT_RIG = "spare8"


@dataclass(frozen=True)
class Rig:
    """A ring of RGB-D cameras looking at the object."""

    name: str = DEFAULT_RIG
    n_cameras: int = 8
    radius_m: float = 0.42
    """Horizontal distance of every camera from the look-at point's vertical axis."""
    heights_m: tuple[float, ...] = (0.20,)
    """Camera heights above the table, cycled over the cameras (camera i uses heights_m[i % len])."""
    look_at_m: tuple[float, float, float] = (0.0, 0.0, 0.12)
    """World point every camera's optical axis passes through."""
    azimuth0_deg: float = 22.5
    """Azimuth of camera 0, measured from world +x towards +y. 22.5 deg keeps every camera off the
    chain's plane (x-z) and off its joint axes (y), so no view sees the chain exactly edge-on."""
    fov_y_deg: float = 42.0
    """Vertical field of view; the horizontal one follows from the aspect ratio (square pixels)."""
    width: int = 128
    """Network image width (pixels)."""
    height: int = 96
    """Network image height (pixels)."""
    record_width: int = 512
    """Recording (high-resolution) image width; same field of view."""
    record_height: int = 384
    near_m: float = 0.05
    """Near clipping plane for rendering."""
    far_m: float = 2.0
    """Far clipping plane; depth at or beyond it is 'no reading'."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "heights_m", tuple(float(h) for h in self.heights_m))
        object.__setattr__(self, "look_at_m", tuple(float(v) for v in self.look_at_m))
        if not isinstance(self.n_cameras, int) or self.n_cameras < 1:
            raise SpareTwinError(f"rig {self.name}: n_cameras must be a positive integer")
        if self.radius_m <= 0 or not self.heights_m or len(self.look_at_m) != 3:
            raise SpareTwinError(f"rig {self.name}: radius_m must be > 0, heights_m non-empty, look_at_m 3 values")
        if not 5.0 < self.fov_y_deg < 170.0:
            raise SpareTwinError(f"rig {self.name}: fov_y_deg {self.fov_y_deg} must be within 5..170")
        for w, h in ((self.width, self.height), (self.record_width, self.record_height)):
            if w < 8 or h < 8:
                raise SpareTwinError(f"rig {self.name}: image sizes must be at least 8x8")
        if not 0 < self.near_m < self.far_m:
            raise SpareTwinError(f"rig {self.name}: needs 0 < near_m < far_m")

    # -- geometry ----------------------------------------------------------------------
    def camera_names(self) -> list[str]:
        return [f"cam{i}" for i in range(self.n_cameras)]

    def positions_m(self) -> np.ndarray:
        """(V, 3) camera centres in the world frame."""
        out = np.zeros((self.n_cameras, 3))
        for i in range(self.n_cameras):
            az = math.radians(self.azimuth0_deg + 360.0 * i / self.n_cameras)
            out[i] = (
                self.look_at_m[0] + self.radius_m * math.cos(az),
                self.look_at_m[1] + self.radius_m * math.sin(az),
                self.heights_m[i % len(self.heights_m)],
            )
        return out

    def poses(self) -> np.ndarray:
        """(V, 4, 4) float64 camera-to-world poses, OpenCV axes."""
        return np.stack([look_at(p, self.look_at_m) for p in self.positions_m()])

    def K(self, width: int | None = None, height: int | None = None) -> np.ndarray:
        """3x3 intrinsics for an image of width x height pixels (default: the network size)."""
        width = self.width if width is None else width
        height = self.height if height is None else height
        return intrinsics(self.fov_y_deg, width, height)

    # -- files -------------------------------------------------------------------------
    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["heights_m"] = list(self.heights_m)
        d["look_at_m"] = list(self.look_at_m)
        return d

    @classmethod
    def from_dict(cls, d: dict, source: str = "rig") -> Rig:
        if not isinstance(d, dict):
            raise SpareTwinError(f"{source}: expected a JSON object")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - known - {"note"})
        if unknown:
            raise SpareTwinError(f"{source}: unknown key(s) {', '.join(unknown)}")
        try:
            return cls(**{k: v for k, v in d.items() if k in known})
        except (TypeError, ValueError) as exc:
            raise SpareTwinError(f"{source}: {exc}") from None

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2) + "\n"


def load_rig(name_or_path: str | Path | None = None) -> Rig:
    """A rig by name (a file in capture/rigs/) or by path to a JSON file; None is the default rig."""
    if name_or_path is None:
        name_or_path = DEFAULT_RIG
    p = Path(name_or_path)
    if p.suffix != ".json":
        p = RIGS_DIR / f"{name_or_path}.json"
    if not p.is_file():
        if str(name_or_path) == DEFAULT_RIG:
            return Rig()  # the shipped default, even when capture/ is not installed alongside
        raise SpareTwinError(f"rig {str(name_or_path)!r}: no such rig (looked for {p})")
    return Rig.from_dict(read_json(p), source=str(p))  # bounded: nesting, integer digits, size


def intrinsics(fov_y_deg: float, width: int, height: int) -> np.ndarray:
    fy = (height / 2.0) / math.tan(math.radians(fov_y_deg) / 2.0)
    return np.array([[fy, 0.0, (width - 1) / 2.0], [0.0, fy, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera-to-world pose (OpenCV axes) of a camera at `eye` looking at `target`, world z up."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)  # camera x (right) is horizontal
    if np.linalg.norm(x) < 1e-9:
        raise SpareTwinError("camera looks straight up or down: look_at is ambiguous")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)  # camera y points down in the image
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, eye
    return T


def jitter_rig_poses(poses: np.ndarray, rng: np.random.Generator, rot_deg: float, trans_m: float) -> np.ndarray:
    """Small random rigid perturbations of camera poses (sim-to-real: an imperfectly built rig)."""
    out = poses.copy()
    for i in range(len(poses)):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = math.radians(rng.normal(scale=rot_deg))
        out[i, :3, :3] = axis_angle(axis, angle) @ poses[i, :3, :3]
        out[i, :3, 3] = poses[i, :3, 3] + rng.normal(scale=trans_m, size=3)
    return out


def jitter_intrinsics(K: np.ndarray, rng: np.random.Generator, focal_rel: float, principal_px: float) -> np.ndarray:
    """Perturb focal length (relative) and principal point (pixels) of a 3x3 K."""
    out = K.copy()
    f = 1.0 + rng.normal(scale=focal_rel)
    out[0, 0] *= f
    out[1, 1] *= f
    out[:2, 2] += rng.normal(scale=principal_px, size=2)
    return out


def axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """3x3 rotation by `angle` (rad) about the unit vector `axis` (Rodrigues)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)
