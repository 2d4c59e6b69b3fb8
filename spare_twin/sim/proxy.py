"""A proxy twin: the object's kinematics with box geometry, written as a URDF in microseconds.

Same link / joint names, frames, axes and colours as the printable object's URDF (docs/CONTRACTS.md):
link k's frame sits on its proximal joint axis, the link extends along +z, joint k turns about +y and
sits at (0, layer_pitch, L_{k-1} * print_scale) in link k-1's frame. Link plates are stadiums
(a box between the axes and a cylinder round each axis), the printed plates without their holes; the base is a post in a
foot plate with a socket. Used for tests, and by the dataset where building the CAD meshes for every
sampled chain would cost more than rendering it (`--geometry proxy`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spare_twin.config import COLORS, ChainSpec

#: Joint range of the proxy (the printed pin joint turns further; the keep-out height binds first).
PROXY_JOINT_LIMIT_RAD = math.radians(150.0)


@dataclass(frozen=True)
class TwinObject:
    """What the simulation needs from an object folder (the fields of objects.load_object's result)."""

    root: Path
    spec: ChainSpec
    urdf_path: Path
    link_names: tuple[str, ...]
    joint_names: tuple[str, ...]
    joint_limits_rad: np.ndarray
    """(n, 2) lower, upper."""
    keepout_height_m: float
    """Every link must stay above this height (foot plate + socket)."""

    @property
    def link_lengths_phys_m(self) -> np.ndarray:
        """(n + 1,) physical link lengths (metres at print scale), base first."""
        return np.asarray(self.spec.link_lengths_m, dtype=np.float64) * self.spec.print_scale

    @property
    def link_half_width_m(self) -> float:
        return self.spec.parts.link_width_mm / 2000.0


def as_twin_object(obj) -> TwinObject:
    """Adapt an objects.ObjectFolder (or anything with the same attributes) to a TwinObject."""
    if isinstance(obj, TwinObject):
        return obj
    return TwinObject(
        root=Path(obj.root),
        spec=obj.spec,
        urdf_path=Path(obj.urdf_path),
        link_names=tuple(obj.link_names),
        joint_names=tuple(obj.joint_names),
        joint_limits_rad=np.asarray(obj.joint_limits_rad, dtype=np.float64).reshape(-1, 2),
        keepout_height_m=float(obj.keepout_height_m),
    )


def _box(name: str, size_m, xyz_m, rgba) -> str:
    sx, sy, sz = size_m
    x, y, z = xyz_m
    geom = f'<geometry><box size="{sx:.6f} {sy:.6f} {sz:.6f}"/></geometry>'
    origin = f'<origin xyz="{x:.6f} {y:.6f} {z:.6f}" rpy="0 0 0"/>'
    r, g, b = rgba
    return (
        f"    <visual>{origin}{geom}<material name=\"{name}\"><color rgba=\"{r:.4f} {g:.4f} {b:.4f} 1\"/></material></visual>\n"
        f"    <collision>{origin}{geom}</collision>\n"
    )


def _disc(name: str, radius_m: float, thickness_m: float, xyz_m, rgba) -> str:
    """A cylinder whose axis is the joint axis (+y): URDF cylinders run along z, so roll by 90 deg."""
    x, y, z = xyz_m
    geom = f'<geometry><cylinder radius="{radius_m:.6f}" length="{thickness_m:.6f}"/></geometry>'
    origin = f'<origin xyz="{x:.6f} {y:.6f} {z:.6f}" rpy="1.5707963 0 0"/>'
    r, g, b = rgba
    return (
        f"    <visual>{origin}{geom}<material name=\"{name}\"><color rgba=\"{r:.4f} {g:.4f} {b:.4f} 1\"/></material></visual>\n"
        f"    <collision>{origin}{geom}</collision>\n"
    )


def proxy_urdf(spec: ChainSpec, colors_rgb=None) -> str:
    """URDF text of the proxy twin of `spec` (metres, z up, table at z = 0).

    `colors_rgb` (n + 1 RGB triples, 0..1) overrides the spec's named colours (colour jitter)."""
    p = spec.parts
    mm = 0.001
    w, t = p.link_width_mm * mm, p.link_thickness_mm * mm
    lengths = [length * spec.print_scale for length in spec.link_lengths_m]
    pitch = spec.layer_pitch_mm * mm
    inertial = '    <inertial><mass value="0.01"/><inertia ixx="1e-6" iyy="1e-6" izz="1e-6" ixy="0" ixz="0" iyz="0"/></inertial>\n'
    parts = [f'<?xml version="1.0"?>\n<robot name="{spec.name}">\n']
    foot_t, sock_h = p.foot_thickness_mm * mm, p.socket_height_mm * mm
    sock = w + 2 * p.socket_wall_mm * mm
    rgbs = [COLORS[c] for c in spec.colors] if colors_rgb is None else [tuple(c) for c in colors_rgb]
    base_rgb = rgbs[0]
    parts.append('  <link name="link0">\n' + inertial)
    parts.append(_box("link0_post", (w, t, lengths[0] + w / 2), (0, 0, (lengths[0] + w / 2) / 2), base_rgb))
    parts.append(_box("link0_foot", (p.foot_size_mm * mm, p.foot_size_mm * mm, foot_t), (0, 0, foot_t / 2), base_rgb))
    parts.append(_box("link0_socket", (sock, sock, sock_h), (0, 0, foot_t + sock_h / 2), base_rgb))
    parts.append("  </link>\n")
    lo, hi = -PROXY_JOINT_LIMIT_RAD, PROXY_JOINT_LIMIT_RAD
    for k in range(1, spec.n_links + 1):
        length = lengths[k]
        parts.append(f'  <link name="link{k}">\n' + inertial)
        # A stadium plate like the printed one: a box between the axes and a disc round each axis.
        rgb = rgbs[k]
        parts.append(_box(f"link{k}", (w, t, length), (0, 0, length / 2), rgb))
        end = length - w / 2 if k == spec.n_links else length  # the last link's tip is its rounded end
        parts.append(_disc(f"link{k}_a", w / 2, t, (0, 0, 0), rgb))
        parts.append(_disc(f"link{k}_b", w / 2, t, (0, 0, end), rgb))
        parts.append("  </link>\n")
        parts.append(
            f'  <joint name="joint{k}" type="revolute"><parent link="link{k - 1}"/><child link="link{k}"/>'
            f'<origin xyz="0 {pitch:.6f} {lengths[k - 1]:.6f}" rpy="0 0 0"/><axis xyz="0 1 0"/>'
            f'<limit lower="{lo:.6f}" upper="{hi:.6f}" effort="1" velocity="10"/></joint>\n'
        )
    parts.append("</robot>\n")
    return "".join(parts)


def build_proxy(spec: ChainSpec, out_dir: str | Path, colors_rgb=None) -> TwinObject:
    """Write `<out_dir>/<name>.urdf` (use a fresh folder per object: pybullet caches by path)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    urdf = out_dir / f"{spec.name}.urdf"
    urdf.write_text(proxy_urdf(spec, colors_rgb))
    n = spec.n_links
    return TwinObject(
        root=out_dir,
        spec=spec,
        urdf_path=urdf,
        link_names=tuple(f"link{k}" for k in range(n + 1)),
        joint_names=tuple(f"joint{k}" for k in range(1, n + 1)),
        joint_limits_rad=np.tile([-PROXY_JOINT_LIMIT_RAD, PROXY_JOINT_LIMIT_RAD], (n, 1)),
        keepout_height_m=(spec.parts.foot_thickness_mm + spec.parts.socket_height_mm) / 1000.0,
    )
