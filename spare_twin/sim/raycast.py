"""A second, independent renderer: open3d's ray caster (Embree) on the object's meshes.

It shares nothing with pybullet but the object folder: the URDF is read here (lxml), every link's STL
meshes are loaded with trimesh, posed by this module's own forward kinematics (joint origins and axes
as the URDF gives them, so a perturbed URDF of `spare_twin.sim.print_physics` is drawn as it is), and
cast against one ray per pixel. The table (a 1 m slab whose top is z = 0) and the clutter are meshes
too. `RaycastTwin` has the methods of `spare_twin.sim.twin.Twin` that `render_recording` uses, so the
same capture (camera path, motion, clutter, effects, noise) can be drawn by either renderer into the
same recording format.

Images: rays through the OpenCV pixel centres (u, v integers) of the pinhole K, each direction
K^-1 (u, v, 1) in the camera frame, so the hit distance is the z-depth itself; nothing within
[near, far] is 0, 'no reading'. Colour: Lambert shading (the `Lighting`'s ambient and diffuse terms,
no specular, no shadow) of the material colour; background white. Segmentation: each link is a
geometry of its own; table and clutter are 0.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from lxml import etree

from spare_twin.config import COLORS
from spare_twin.errors import SpareTwinError
from spare_twin.object.folder import ObjectFolder
from spare_twin.open3d_loader import quiet_open3d
from spare_twin.sim.choices import RENDERERS
from spare_twin.sim.print_physics import urdf_origin
from spare_twin.sim.rig import axis_angle
from spare_twin.sim.twin import DEFAULT_TABLE_RGBA, Frame, Lighting, Twin

BACKGROUND_RGB = (255, 255, 255)


def _mesh_arrays(mesh) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)


class _Link:
    """One URDF link's visual meshes, merged, in the link frame."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        self.vertices = vertices
        self.faces = faces


def load_link_meshes(urdf_path: Path, link_names: list[str]) -> list[_Link]:
    """Every named link's visual meshes (STL files beside the URDF, scaled and placed by their origins)."""
    import trimesh

    parser = etree.XMLParser(resolve_entities=False, no_network=True)
    try:
        root = etree.parse(str(urdf_path), parser).getroot()
    except (etree.XMLSyntaxError, OSError) as exc:
        raise SpareTwinError(f"{urdf_path}: not a readable URDF ({' '.join(str(exc).split())})") from None
    by_name = {el.get("name"): el for el in root.findall("link")}
    out = []
    for name in link_names:
        link = by_name.get(name)
        if link is None:
            raise SpareTwinError(f"{urdf_path}: no link named {name}")
        verts, faces, offset = [], [], 0
        for visual in link.findall("visual"):
            mesh_el = visual.find("geometry/mesh")
            if mesh_el is None:
                continue  # only meshes: the object folder's URDF has nothing else
            path = urdf_path.parent / (mesh_el.get("filename") or "")
            if not path.is_file():
                raise SpareTwinError(f"{urdf_path}: mesh {mesh_el.get('filename')!r}: no such file beside the URDF")
            mesh = trimesh.load(str(path), force="mesh")
            v, f = _mesh_arrays(mesh)
            v = v * np.asarray([float(s) for s in (mesh_el.get("scale") or "1 1 1").split()])
            T = urdf_origin(visual.find("origin"))
            verts.append(v @ T[:3, :3].T + T[:3, 3])
            faces.append(f + offset)
            offset += len(v)
        if not verts:
            raise SpareTwinError(f"{urdf_path}: link {name} has no mesh to draw")
        out.append(_Link(np.concatenate(verts), np.concatenate(faces)))
    return out


def load_chain_joints(urdf_path: Path, joint_names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(n, 4, 4) joint origins (in the parent link's frame) and (n, 3) unit axes of the named joints."""
    root = etree.parse(str(urdf_path), etree.XMLParser(resolve_entities=False, no_network=True)).getroot()
    by_name = {el.get("name"): el for el in root.findall("joint")}
    origins, axes = [], []
    for name in joint_names:
        j = by_name.get(name)
        if j is None:
            raise SpareTwinError(f"{urdf_path}: no joint named {name}")
        origins.append(urdf_origin(j.find("origin")))
        axis_el = j.find("axis")
        axis = np.array([float(v) for v in (axis_el.get("xyz") if axis_el is not None else "1 0 0").split()])
        axes.append(axis / np.linalg.norm(axis))
    return np.asarray(origins), np.asarray(axes)


class RaycastTwin:
    """An open3d ray-casting scene holding a table, optional clutter and (at most) one object."""

    def __init__(self, table: bool = True, table_rgba=DEFAULT_TABLE_RGBA):
        import trimesh

        self.obj: ObjectFolder | None = None
        self._links: list[_Link] = []
        self._link_rgb: np.ndarray = np.zeros((0, 3))
        self._static: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (vertices, faces, rgb) in the world
        self._angles = np.zeros(0)
        self._scene = None
        self._scene_key: bytes | None = None
        self._dirs, self._dirs_key = np.zeros((0, 3), np.float32), None
        if table:
            slab = trimesh.creation.box(extents=[1.0, 1.0, 0.02])
            v, f = _mesh_arrays(slab)
            self._static.append((v + [0.0, 0.0, -0.01], f, np.asarray(table_rgba[:3], float)))

    # -- scene -------------------------------------------------------------------------
    def load(self, obj: ObjectFolder) -> None:
        """The object folder's URDF meshes and joints, replacing any previous object."""
        if not obj.urdf_path.is_file():
            raise SpareTwinError(f"{obj.urdf_path}: no such URDF")
        self._links = load_link_meshes(obj.urdf_path, obj.link_names)
        self._origins, self._axes = load_chain_joints(obj.urdf_path, obj.joint_names)
        self._link_rgb = np.asarray([COLORS[c] for c in obj.spec.colors], float)
        self._angles = np.zeros(obj.spec.n_links)
        self.obj = obj
        self._scene_key = None

    def add_box(self, half_extents_m, position_m, rgba, yaw_rad: float = 0.0) -> None:
        import trimesh

        v, f = _mesh_arrays(trimesh.creation.box(extents=2 * np.asarray(half_extents_m, float)))
        R = axis_angle(np.array([0.0, 0.0, 1.0]), float(yaw_rad))
        self._static.append((v @ R.T + np.asarray(position_m, float), f, np.asarray(rgba[:3], float)))
        self._scene_key = None

    def add_cylinder(self, radius_m: float, height_m: float, position_m, rgba) -> None:
        import trimesh

        v, f = _mesh_arrays(trimesh.creation.cylinder(radius=float(radius_m), height=float(height_m), sections=32))
        self._static.append((v + np.asarray(position_m, float), f, np.asarray(rgba[:3], float)))
        self._scene_key = None

    def set_joints(self, angles_rad) -> None:
        self._angles = np.asarray(angles_rad, dtype=np.float64).reshape(-1)

    def link_poses(self) -> np.ndarray:
        """(n + 1, 4, 4) world poses of the URDF link frames (link 0 = base, at the origin)."""
        n = len(self._links)
        out = np.zeros((n, 4, 4))
        out[0] = np.eye(4)
        for k in range(1, n):
            R = np.eye(4)
            R[:3, :3] = axis_angle(self._axes[k - 1], float(self._angles[k - 1]))
            out[k] = out[k - 1] @ self._origins[k - 1] @ R
        return out

    def _build(self):
        """The ray-casting scene at the current joints (rebuilt only when they change)."""
        o3d = quiet_open3d()

        key = self._angles.tobytes() if self.obj is not None else b""
        if self._scene is not None and key == self._scene_key:
            return self._scene
        scene = o3d.t.geometry.RaycastingScene()
        labels, colours = [], []
        poses = self.link_poses() if self.obj is not None else np.zeros((0, 4, 4))
        for k, link in enumerate(self._links):
            v = link.vertices @ poses[k, :3, :3].T + poses[k, :3, 3]
            gid = scene.add_triangles(
                o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(link.faces.astype(np.uint32))
            )
            labels.append((gid, k + 1))
            colours.append((gid, self._link_rgb[k]))
        for v, f, rgb in self._static:
            gid = scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32)))
            labels.append((gid, 0))
            colours.append((gid, rgb))
        n_ids = max(g for g, _ in labels) + 1 if labels else 1
        self._label_lut = np.zeros(n_ids + 1, np.uint8)  # the last entry: no hit
        self._rgb_lut = np.tile(np.asarray(BACKGROUND_RGB, np.float32) / 255.0, (n_ids + 1, 1))
        for g, lab in labels:
            self._label_lut[g] = lab
        for g, rgb in colours:
            self._rgb_lut[g] = rgb
        self._scene, self._scene_key = scene, key
        return scene

    # -- rendering ---------------------------------------------------------------------
    def render(
        self,
        T_world_camera: np.ndarray,
        K: np.ndarray,
        width: int,
        height: int,
        near_m: float,
        far_m: float,
        lighting: Lighting = Lighting(),
        segmentation: bool = True,
    ) -> Frame:
        o3d = quiet_open3d()

        scene = self._build()
        T = np.asarray(T_world_camera, dtype=np.float64)
        dirs = self._pixel_directions(np.asarray(K, dtype=np.float64), width, height)
        # R (x, y, 1): unit z in the camera frame, so the hit distance is the z-depth (no BLAS: a (N, 3)
        # matmul in a threaded BLAS is several times slower than this on a busy machine)
        R = T[:3, :3].astype(np.float32)
        d_world = dirs[:, :1] * R[:, 0] + dirs[:, 1:2] * R[:, 1] + R[:, 2]
        rays = np.empty((len(dirs), 6), np.float32)
        rays[:, :3] = T[:3, 3]
        rays[:, 3:] = d_world
        hit = scene.cast_rays(o3d.core.Tensor.from_numpy(rays))
        z = hit["t_hit"].numpy()
        seen = np.isfinite(z) & (z >= near_m) & (z < far_m)
        none = len(self._label_lut) - 1
        ids = np.where(seen, np.minimum(hit["geometry_ids"].numpy(), none), none)
        depth = np.where(seen, z, 0.0).astype(np.float32).reshape(height, width)
        normals = hit["primitive_normals"].numpy()
        light = np.asarray(lighting.direction, np.float32)
        light /= np.linalg.norm(light)
        # the face turned towards the camera is the lit one (an STL's winding is not trusted)
        toward = np.where(np.einsum("ij,ij->i", normals, d_world) > 0, -1.0, 1.0).astype(np.float32)
        lambert = np.clip(toward * np.einsum("ij,j->i", normals, light), 0.0, None)
        shade = (lighting.ambient + lighting.diffuse * lambert).astype(np.float32)
        rgb = self._rgb_lut[ids] * np.asarray(lighting.color, np.float32) * shade[:, None]
        rgb[~seen] = np.asarray(BACKGROUND_RGB, np.float32) / 255.0
        rgb8 = np.clip(np.rint(rgb * 255.0), 0, 255).astype(np.uint8).reshape(height, width, 3)
        ids = ids.reshape(height, width)
        labels = self._label_lut[ids] if segmentation and self.obj is not None else None
        return Frame(rgb8, depth, labels)

    def _pixel_directions(self, K: np.ndarray, width: int, height: int) -> np.ndarray:
        """(H W, 3) float32 camera-frame directions K^-1 (u, v, 1) through the pixel centres (cached per camera)."""
        key = (K.tobytes(), width, height)
        if self._dirs_key != key:
            u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
            d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
            self._dirs, self._dirs_key = d.reshape(-1, 3).astype(np.float32), key
        return self._dirs

    def close(self) -> None:
        self._scene = None

    def __enter__(self) -> RaycastTwin:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def make_renderer(name: str):
    """A fresh scene of the named renderer (a context manager with Twin's methods)."""
    if name == "pybullet":
        return Twin()
    if name == "raycast":
        return RaycastTwin()
    raise SpareTwinError(f"renderer {name!r}: expected one of {', '.join(RENDERERS)}")
