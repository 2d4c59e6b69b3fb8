"""A printed object is not its CAD: joint play and print error, as a perturbed copy of the object folder.

What is drawn (per capture, from the effects' own seeded streams; ranges in `CaptureEffects`):
- joint play: each moving link k is tilted out of the chain's plane by delta_k about its own x axis
  (through its joint centre: the pin leaning in its hole), and joint k's centre shifts in the parent's
  plane (x, z) by up to the pin's radial clearance. A link of length L then ends L sin(delta) off its
  nominal layer, and the links after it follow;
- print error: the whole object scaled by (1 + e) about its base origin, and standing off level by a
  fraction of a degree (link 0 turned about a horizontal axis through its origin).

The perturbation is written as a new URDF (joint origins and the links' visual / collision origins and
mesh scales changed; names, limits and the chain unchanged) in a folder of its own with copies of the
meshes, so pybullet, which caches a URDF and its meshes by path, loads it fresh, and the raycast
renderer reads the same file. Link k's geometry then sits at `T_urdf_link_k @ W[k]`, where
T_urdf_link_k is the link frame a renderer reports and W (`PrintPerturbation.W_link_geometry`) what
was drawn; the recording's ground truth keeps the nominal configuration and records W.
"""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from lxml import etree

from spare_twin.errors import SpareTwinError
from spare_twin.object.folder import ObjectFolder
from spare_twin.object.urdf import joint_name, link_name
from spare_twin.sim.effects import CaptureEffects, effect_rng
from spare_twin.sim.rig import axis_angle


@dataclass(frozen=True)
class PrintPerturbation:
    """What was drawn for one capture's object (zeros / ones where an effect is off)."""

    tilt_deg: np.ndarray
    """(n,) out-of-plane tilt of links 1..n, degrees (signed: + turns the link's far end towards -y)."""
    shift_mm: np.ndarray
    """(n, 2) in-plane (x, z) shift of joints 1..n's centres in the parent link's frame, millimetres."""
    scale: float
    """Whole-object scale factor (1 + scale error)."""
    level_deg: float
    """How far the object stands off level, degrees."""
    level_axis: np.ndarray
    """(3,) the horizontal axis it is turned about."""
    W_link_geometry: np.ndarray
    """(n + 1, 4, 4) where each link's geometry sits in the frame its URDF link reports (scale aside)."""

    @property
    def active(self) -> bool:
        return bool(np.any(self.tilt_deg) or np.any(self.shift_mm) or self.scale != 1.0 or self.level_deg)

    def to_dict(self) -> dict:
        return {
            "tilt_deg": np.round(self.tilt_deg, 6).tolist(),
            "shift_mm": np.round(self.shift_mm, 6).tolist(),
            "scale": round(float(self.scale), 9),
            "level_deg": round(float(self.level_deg), 6),
            "level_axis": np.round(self.level_axis, 9).tolist(),
        }


def _rot_x(angle_rad: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = axis_angle(np.array([1.0, 0.0, 0.0]), angle_rad)
    return T


def draw_perturbation(n_links: int, effects: CaptureEffects, seed: int) -> PrintPerturbation:
    """The joint play and print error of one capture (a pure function of the effects and the seed)."""
    tilt = np.zeros(n_links)
    shift = np.zeros((n_links, 2))
    if effects.joint_play:
        rng = effect_rng(seed, "joint_play")
        sign = np.where(rng.random(n_links) < 0.5, -1.0, 1.0)
        tilt = sign * rng.uniform(*effects.joint_tilt_deg, size=n_links)
        r = effects.joint_shift_mm * np.sqrt(rng.random(n_links))  # uniform over the clearance's disc
        a = rng.uniform(0.0, 2 * math.pi, n_links)
        shift = np.stack([r * np.cos(a), r * np.sin(a)], 1)
    scale, level, axis = 1.0, 0.0, np.array([1.0, 0.0, 0.0])
    if effects.print_error:
        rng = effect_rng(seed, "print_error")
        scale = 1.0 + float(rng.uniform(*effects.scale_error))
        level = float(rng.uniform(*effects.level_error_deg))
        az = float(rng.uniform(0.0, 2 * math.pi))
        axis = np.array([math.cos(az), math.sin(az), 0.0])
    W = np.stack([np.eye(4)] * (n_links + 1))
    W[0, :3, :3] = axis_angle(axis, math.radians(level))
    for k in range(1, n_links + 1):
        W[k] = _rot_x(math.radians(tilt[k - 1]))
    return PrintPerturbation(tilt, shift, scale, level, axis, W)


def urdf_origin(el) -> np.ndarray:
    """4x4 of an <origin> element (URDF rpy: R = Rz(yaw) Ry(pitch) Rx(roll))."""
    T = np.eye(4)
    if el is None:
        return T
    xyz = [float(v) for v in (el.get("xyz") or "0 0 0").split()]
    r, p, y = (float(v) for v in (el.get("rpy") or "0 0 0").split())
    Rx, Ry, Rz = (axis_angle(np.eye(3)[i], a) for i, a in enumerate((r, p, y)))
    T[:3, :3] = Rz @ Ry @ Rx
    T[:3, 3] = xyz
    return T


def _rpy(R: np.ndarray) -> tuple[float, float, float]:
    """URDF roll, pitch, yaw of a rotation (inverse of `urdf_origin`'s convention)."""
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    if abs(math.cos(pitch)) > 1e-9:
        return math.atan2(R[2, 1], R[2, 2]), pitch, math.atan2(R[1, 0], R[0, 0])
    return math.atan2(-R[1, 2], R[1, 1]), pitch, 0.0  # gimbal lock: yaw folded into roll


def _set_origin(parent, T: np.ndarray) -> None:
    el = parent.find("origin")
    if el is None:
        el = etree.SubElement(parent, "origin")
    el.set("xyz", " ".join(f"{v:.10g}" for v in T[:3, 3]))
    el.set("rpy", " ".join(f"{v:.10g}" for v in _rpy(T[:3, :3])))


def perturbed_urdf_bytes(urdf_path: Path, n_links: int, p: PrintPerturbation) -> bytes:
    """The object's URDF with `p` applied: scaled, link geometry moved by W, joint centres shifted."""
    parser = etree.XMLParser(resolve_entities=False, no_network=True, remove_blank_text=True)
    try:
        root = etree.parse(str(urdf_path), parser).getroot()
    except (etree.XMLSyntaxError, OSError) as exc:
        raise SpareTwinError(f"{urdf_path}: not a readable URDF ({' '.join(str(exc).split())})") from None
    links = {el.get("name"): el for el in root.findall("link")}
    joints = {el.get("name"): el for el in root.findall("joint")}
    for k in range(n_links + 1):
        link = links.get(link_name(k))
        if link is None:
            raise SpareTwinError(f"{urdf_path}: no link named {link_name(k)}")
        for tag in ("visual", "collision"):
            for el in link.findall(tag):
                T = urdf_origin(el.find("origin"))
                T[:3, 3] *= p.scale
                _set_origin(el, p.W_link_geometry[k] @ T)
                for mesh in el.iter("mesh"):
                    s = [float(v) for v in (mesh.get("scale") or "1 1 1").split()]
                    mesh.set("scale", " ".join(f"{v * p.scale:.10g}" for v in s))
    for k in range(1, n_links + 1):
        j = joints.get(joint_name(k))
        if j is None:
            raise SpareTwinError(f"{urdf_path}: no joint named {joint_name(k)}")
        T = urdf_origin(j.find("origin"))
        T[:3, 3] *= p.scale
        T[0, 3] += p.shift_mm[k - 1, 0] / 1000.0  # the pin's centre moves within its hole, in the parent's plane
        T[2, 3] += p.shift_mm[k - 1, 1] / 1000.0
        _set_origin(j, p.W_link_geometry[k - 1] @ T)  # joint k hangs on link k-1's (moved) geometry
    return etree.tostring(root, pretty_print=True, xml_declaration=True, encoding="UTF-8")


def perturbed_object(obj: ObjectFolder, p: PrintPerturbation, folder: str | Path) -> ObjectFolder:
    """A copy of `obj` in `folder` (a fresh, unique path: pybullet caches by path) with `p` applied."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    data = perturbed_urdf_bytes(obj.urdf_path, obj.spec.n_links, p)
    root = etree.fromstring(data)
    for mesh in root.iter("mesh"):  # the meshes the URDF names, beside it as the object folder has them
        name = mesh.get("filename") or ""
        src = obj.urdf_path.parent / name
        if not name or "://" in name or Path(name).is_absolute() or not src.is_file():
            raise SpareTwinError(f"{obj.urdf_path}: mesh {name!r}: no such file beside the URDF")
        dst = folder / name
        dst.parent.mkdir(parents=True, exist_ok=True)
        if not dst.exists():
            shutil.copyfile(src, dst)
    urdf = folder / obj.urdf_path.name
    urdf.write_bytes(data)
    if (obj.root / "object.json").is_file():
        shutil.copyfile(obj.root / "object.json", folder / "object.json")
    return ObjectFolder(folder, obj.spec, urdf)
