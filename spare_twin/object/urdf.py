"""The URDF twin, built with yourdfpy's data model from the very parts that get printed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
import yourdfpy
from lxml import etree

from spare_twin.config import COLORS, ChainSpec
from spare_twin.object.kinematics import JOINT_AXIS, joint_limits_rad, joint_origin
from spare_twin.object.parts import Part

MM = 1e-3


def link_name(k: int) -> str:
    return f"link{k}"


def joint_name(k: int) -> str:
    return f"joint{k}"


def effective_density_kg_m3(spec: ChainSpec, mesh_mm: trimesh.Trimesh) -> float:
    """PLA density times the printed fill: solid skins of `shell_thickness_mm`, `infill` inside."""
    pr = spec.printer
    shell_fraction = min(1.0, mesh_mm.area * pr.shell_thickness_mm / mesh_mm.volume)
    return pr.pla_density_kg_m3 * (shell_fraction + pr.infill * (1.0 - shell_fraction))


def link_inertial(spec: ChainSpec, parts: list[Part], meshes: dict[str, trimesh.Trimesh]) -> yourdfpy.Inertial:
    """Mass, centre of mass and inertia of a link's parts, in the link frame (SI)."""
    pieces = []
    for part in parts:
        mesh = meshes[part.name].copy()
        mesh.density = effective_density_kg_m3(spec, meshes[part.name])
        T = part.T_link_part_mm.copy()
        T[:3, 3] *= MM
        mesh.apply_scale(MM)  # about the part origin, before placing it in the link
        mesh.apply_transform(T)
        pieces.append(mesh)
    mass = sum(p.mass for p in pieces)
    com = sum(p.mass * p.center_mass for p in pieces) / mass
    inertia = np.zeros((3, 3))
    for p in pieces:  # parallel-axis theorem moves each part's inertia to the common centre of mass
        d = p.center_mass - com
        inertia += p.moment_inertia + p.mass * (d @ d * np.eye(3) - np.outer(d, d))
    origin = np.eye(4)
    origin[:3, 3] = com
    return yourdfpy.Inertial(origin=origin, mass=float(mass), inertia=inertia)


def build_robot(
    spec: ChainSpec, parts: list[Part], meshes: dict[str, trimesh.Trimesh], files: dict[str, str]
) -> yourdfpy.Robot:
    materials = [
        yourdfpy.Material(name=c, color=yourdfpy.Color(rgba=np.array([*COLORS[c], 1.0])))
        for c in sorted(set(spec.colors))
    ]
    links = []
    for k in range(spec.n_links + 1):
        own = [p for p in parts if p.link == k]
        visuals, collisions = [], []
        for part in own:
            origin = part.T_link_part_mm.copy()
            origin[:3, 3] *= MM
            geometry = yourdfpy.Geometry(mesh=yourdfpy.Mesh(filename=files[part.name], scale=np.array([MM, MM, MM])))
            # Pins and the foot keep the link's colour: they are printed in the same filament.
            material = yourdfpy.Material(name=spec.colors[k])
            visuals.append(yourdfpy.Visual(name=part.name, origin=origin, geometry=geometry, material=material))
            collisions.append(yourdfpy.Collision(name=part.name, origin=origin, geometry=geometry))
        links.append(
            yourdfpy.Link(
                name=link_name(k), inertial=link_inertial(spec, own, meshes), visuals=visuals, collisions=collisions
            )
        )
    limits = joint_limits_rad(spec)
    joints = [
        yourdfpy.Joint(
            name=joint_name(k),
            type="revolute",
            parent=link_name(k - 1),
            child=link_name(k),
            origin=joint_origin(spec, k),
            axis=JOINT_AXIS.copy(),
            limit=yourdfpy.Limit(
                effort=0.5, velocity=3.0, lower=float(limits[k - 1, 0]), upper=float(limits[k - 1, 1])
            ),
            dynamics=yourdfpy.Dynamics(damping=0.001, friction=0.0),
        )
        for k in range(1, spec.n_links + 1)
    ]
    return yourdfpy.Robot(name=spec.name, links=links, joints=joints, materials=materials)


def urdf_bytes(robot: yourdfpy.Robot) -> bytes:
    """Serialise with yourdfpy (no mesh loading needed to write)."""
    # Writing needs no mesh files: an identity filename handler stops yourdfpy looking for them.
    urdf = yourdfpy.URDF(robot=robot, build_scene_graph=False, load_meshes=False, filename_handler=lambda fname: fname)
    return etree.tostring(urdf.write_xml(), pretty_print=True, xml_declaration=True, encoding="UTF-8")


def load_urdf(path: str | Path) -> yourdfpy.URDF:
    return yourdfpy.URDF.load(str(path), build_collision_scene_graph=False, load_collision_meshes=False)
