"""The URDF twin, built with yourdfpy's data model from the very parts that get printed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
import yourdfpy
from lxml import etree

from spare_twin.config import COLORS, ChainSpec
from spare_twin.errors import SpareTwinError
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


#: URDF attributes holding numbers, each checked finite before pybullet parses them.
_NUMERIC_ATTRIBUTES = {
    "origin": ("xyz", "rpy"),
    "axis": ("xyz",),
    "mass": ("value",),
    "inertia": ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"),
    "limit": ("lower", "upper", "effort", "velocity"),
    "mesh": ("scale",),
}


def check_urdf(path: str | Path, n_links: int) -> None:
    """The URDF at `path` matches an object of `n_links` moving links, as pybullet will read it: links
    link0..linkN and revolute joints joint1..jointN chaining link k-1 -> link k, a tree rooted at link0,
    finite numbers, and every mesh file present. pybullet crashes (SIGSEGV) on a joint loop or a missing
    joint's orphaned link, and silently renders a joint made fixed; so this runs before it loads the file."""
    path = Path(path)

    def bad(what: str) -> SpareTwinError:
        return SpareTwinError(f"{path}: {what}")

    parser = etree.XMLParser(resolve_entities=False, no_network=True, huge_tree=False)
    try:
        root = etree.parse(str(path), parser).getroot()
    except (etree.XMLSyntaxError, OSError) as exc:
        raise bad(f"not a readable URDF ({' '.join(str(exc).split())})") from None
    if root.tag != "robot":
        raise bad(f"not a URDF (root element <{root.tag}>, expected <robot>)")
    links = [el.get("name") for el in root.findall("link")]
    joints = {el.get("name"): el for el in root.findall("joint")}
    if len(set(links)) != len(links) or len(joints) != len(root.findall("joint")):
        raise bad("link and joint names must be unique")
    for k in range(n_links + 1):
        if link_name(k) not in links:
            raise bad(f"no link named {link_name(k)} (the object has {n_links} moving links)")
    for k in range(1, n_links + 1):
        j = joints.get(joint_name(k))
        if j is None:
            raise bad(f"no joint named {joint_name(k)} (the object has {n_links} moving links)")
        if j.get("type") != "revolute":
            raise bad(f"joint {joint_name(k)} is {j.get('type')!r}, must be 'revolute' (a pin joint)")
        parent, child = j.find("parent"), j.find("child")
        have = (None if parent is None else parent.get("link"), None if child is None else child.get("link"))
        if have != (link_name(k - 1), link_name(k)):
            raise bad(
                f"joint {joint_name(k)} joins {have[0]} -> {have[1]}, must join {link_name(k - 1)} -> {link_name(k)}"
            )
    # every joint (the chain's and any other) hangs an existing link under an existing one, once: a tree
    parents: dict[str, str] = {}
    for name, j in joints.items():
        parent, child = j.find("parent"), j.find("child")
        a, b = (None if parent is None else parent.get("link")), (None if child is None else child.get("link"))
        if a not in links or b not in links:
            raise bad(f"joint {name} joins {a} -> {b}: no such link")
        if b in parents or b == link_name(0):
            raise bad(f"joint {name}: link {b} already has a parent (the links must form a tree from link0)")
        parents[b] = a
    for link in links:
        seen, at = set(), link
        while at in parents:
            if at in seen:
                raise bad(f"link {link}: its joints form a loop")
            seen.add(at)
            at = parents[at]
        if at != link_name(0):
            raise bad(f"link {link} is not attached to link0")
    for tag, names in _NUMERIC_ATTRIBUTES.items():
        for el in root.iter(tag):
            for attr in names:
                text = el.get(attr)
                try:
                    values = [float(v) for v in text.split()] if text is not None else []
                except ValueError:
                    values = [float("nan")]
                if not np.isfinite(values).all():
                    raise bad(f"<{tag} {attr}={text!r}>: must be finite numbers")
    for mesh in root.iter("mesh"):
        name = mesh.get("filename") or ""
        if not name or "://" in name or not (path.parent / name).is_file():
            raise bad(f"mesh {name!r}: no such file beside the URDF")
