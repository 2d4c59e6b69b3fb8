"""The pybullet twin: an object folder in a headless simulator, rendered by pinhole cameras.

Kinematic only: joints are set with resetJointState (the motion is prescribed, nothing is stepped),
so a frame costs one forward-kinematics update plus one render per camera. Rendering uses
ER_TINY_RENDERER (CPU, no display) in a DIRECT client of its own, so several Twins (one per data
loader worker or process) never share state.

Camera conventions: poses are camera-to-world in OpenCV axes; pybullet wants OpenGL view and
projection matrices (column-major 16-tuples). The projection is built from K so that pixel centres
sit on integer OpenCV coordinates (see `projection_matrix`); depth is linearised from the OpenGL depth
buffer, which gives the eye-space z, i.e. z-depth (not the ray length), as recordings require.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass

import numpy as np

from spare_twin.errors import SpareTwinError
from spare_twin.object.folder import ObjectFolder
from spare_twin.object.urdf import check_urdf

_CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])  # flip y (down -> up) and z (forward -> backward)
DEFAULT_TABLE_RGBA = (0.55, 0.5, 0.45, 1.0)


@dataclass(frozen=True)
class Lighting:
    """TinyRenderer lighting (used for the colour / grey images; depth ignores it)."""

    direction: tuple[float, float, float] = (0.4, -0.6, 1.0)
    """World position of the light; light travels from it towards the origin."""
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    ambient: float = 0.45
    diffuse: float = 0.55
    specular: float = 0.05
    shadow: bool = False


def view_matrix(T_world_camera: np.ndarray) -> tuple[float, ...]:
    """pybullet view matrix (world -> OpenGL eye, column-major) of an OpenCV camera-to-world pose."""
    V = _CV_TO_GL @ np.linalg.inv(np.asarray(T_world_camera, dtype=np.float64))
    return tuple(V.T.reshape(-1))


def projection_matrix(K: np.ndarray, width: int, height: int, near_m: float, far_m: float) -> tuple[float, ...]:
    """OpenGL projection (column-major) that reproduces the pinhole K on a width x height image.

    TinyRenderer samples pixel (col i, row r) at window coordinates (i, H - 1 - r) (integer corners,
    rows flipped to put row 0 on top), not at the pixel centres (i + 0.5, ...) OpenGL uses, so the
    principal point enters shifted by half a pixel: then a point at u = fx x / z + cx is drawn in
    column round(u), row round(v), as OpenCV's K says (checked in tests/test_sim_render.py).
    """
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    P = np.zeros((4, 4))
    P[0, 0] = 2.0 * fx / width
    P[0, 2] = 1.0 - 2.0 * cx / width
    P[1, 1] = 2.0 * fy / height
    P[1, 2] = 2.0 * (cy + 1.0) / height - 1.0
    P[2, 2] = -(far_m + near_m) / (far_m - near_m)
    P[2, 3] = -2.0 * far_m * near_m / (far_m - near_m)
    P[3, 2] = -1.0
    return tuple(P.T.reshape(-1))


def linearize_depth(zbuf: np.ndarray, near_m: float, far_m: float) -> np.ndarray:
    """pybullet's non-linear depth buffer (0..1) to z-depth in metres; the far plane (nothing hit)
    becomes 0, 'no reading'."""
    z = np.asarray(zbuf, dtype=np.float32)
    depth = (far_m * near_m) / (far_m - (far_m - near_m) * z)
    depth[z >= 1.0 - 1e-7] = 0.0
    return depth.astype(np.float32, copy=False)


@dataclass
class Frame:
    """One rendered camera image."""

    rgb: np.ndarray
    """uint8 (H, W, 3)."""
    depth_m: np.ndarray
    """float32 (H, W) z-depth, 0 = nothing within the far plane."""
    segmentation: np.ndarray | None
    """uint8 (H, W): 0 background / table / clutter, k = link k - 1."""


def import_pybullet():
    """Import pybullet without the build-time banner it prints on stderr (noise between progress bars)."""
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            import pybullet
    finally:
        os.dup2(saved, 2)
        os.close(saved)
    return pybullet


class Twin:
    """One pybullet DIRECT client holding a table, optional clutter and (at most) one object."""

    def __init__(self, table: bool = True, table_rgba=DEFAULT_TABLE_RGBA):
        p = import_pybullet()
        self.p = p
        self.cid = p.connect(p.DIRECT)
        self.body: int | None = None
        self.obj: ObjectFolder | None = None
        self._extra: list[int] = []
        self.table_id: int | None = None
        if table:
            # A 1 m square slab whose top face is the table top, z = 0.
            vis = p.createVisualShape(
                p.GEOM_BOX, halfExtents=[0.5, 0.5, 0.01], rgbaColor=list(table_rgba), physicsClientId=self.cid
            )
            self.table_id = p.createMultiBody(0, -1, vis, basePosition=[0, 0, -0.01], physicsClientId=self.cid)

    # -- scene -------------------------------------------------------------------------
    def load(self, obj: ObjectFolder) -> None:
        """Load an object folder's URDF (fixed base on the table), replacing any previous object."""
        p = self.p
        if self.body is not None:
            p.removeBody(self.body, physicsClientId=self.cid)
            self.body = None
        if not obj.urdf_path.is_file():
            raise SpareTwinError(f"{obj.urdf_path}: no such URDF")
        check_urdf(obj.urdf_path, obj.spec.n_links)  # pybullet crashes or misreads on a URDF that does not fit
        try:
            body = p.loadURDF(str(obj.urdf_path), useFixedBase=True, physicsClientId=self.cid)
        except p.error as exc:
            raise SpareTwinError(f"{obj.urdf_path}: pybullet cannot load it ({exc})") from None
        joint_index, link_label = {}, np.zeros(128, np.uint8)
        base_name = p.getBodyInfo(body, physicsClientId=self.cid)[0].decode()
        names = {base_name: -1}
        for j in range(p.getNumJoints(body, physicsClientId=self.cid)):
            info = p.getJointInfo(body, j, physicsClientId=self.cid)
            joint_index[info[1].decode()] = j
            names[info[12].decode()] = j
        for k, link in enumerate(obj.link_names):
            if link not in names:
                raise SpareTwinError(f"{obj.urdf_path}: no link named {link}")
            # Segmentation value >> 24 is pybullet's link index + 1 (0 for the base).
            link_label[names[link] + 1] = k + 1
        missing = [j for j in obj.joint_names if j not in joint_index]
        if missing:
            raise SpareTwinError(f"{obj.urdf_path}: no joint named {missing[0]}")
        self.body, self.obj = body, obj
        self._joints = [joint_index[j] for j in obj.joint_names]
        self._links = [names[link] for link in obj.link_names]
        self._label_lut = link_label

    def add_box(self, half_extents_m, position_m, rgba, yaw_rad: float = 0.0) -> int:
        """A static box (table clutter); returns its body id."""
        p = self.p
        vis = p.createVisualShape(
            p.GEOM_BOX, halfExtents=list(half_extents_m), rgbaColor=list(rgba), physicsClientId=self.cid
        )
        orn = p.getQuaternionFromEuler([0, 0, yaw_rad])
        b = p.createMultiBody(0, -1, vis, basePosition=list(position_m), baseOrientation=orn, physicsClientId=self.cid)
        self._extra.append(b)
        return b

    def add_cylinder(self, radius_m: float, height_m: float, position_m, rgba) -> int:
        """A static upright cylinder (table clutter) centred at `position_m`; returns its body id."""
        p = self.p
        vis = p.createVisualShape(
            p.GEOM_CYLINDER, radius=radius_m, length=height_m, rgbaColor=list(rgba), physicsClientId=self.cid
        )
        b = p.createMultiBody(0, -1, vis, basePosition=list(position_m), physicsClientId=self.cid)
        self._extra.append(b)
        return b

    def clear_extras(self) -> None:
        for b in self._extra:
            self.p.removeBody(b, physicsClientId=self.cid)
        self._extra = []

    def set_link_color(self, link: int, rgb) -> None:
        """Recolour link `link` (0 = base); the scene randomisation varies the printed colours."""
        self.p.changeVisualShape(self.body, self._links[link], rgbaColor=[*rgb, 1.0], physicsClientId=self.cid)

    def set_table_color(self, rgba) -> None:
        if self.table_id is not None:
            self.p.changeVisualShape(self.table_id, -1, rgbaColor=list(rgba), physicsClientId=self.cid)

    def set_joints(self, angles_rad) -> None:
        for j, a in zip(self._joints, angles_rad):
            self.p.resetJointState(self.body, j, float(a), physicsClientId=self.cid)

    def link_poses(self) -> np.ndarray:
        """(n + 1, 4, 4) world poses of the link frames (link 0 = base), at the current joints."""
        p = self.p
        out = np.zeros((len(self._links), 4, 4))
        for i, li in enumerate(self._links):
            if li < 0:
                # pybullet reports the base's inertial frame; undo the URDF's inertial offset.
                pos, orn = p.getBasePositionAndOrientation(self.body, physicsClientId=self.cid)
                lpos, lorn = p.getDynamicsInfo(self.body, -1, physicsClientId=self.cid)[3:5]
                inv_pos, inv_orn = p.invertTransform(lpos, lorn)
                pos, orn = p.multiplyTransforms(pos, orn, inv_pos, inv_orn)
            else:
                st = p.getLinkState(self.body, li, computeForwardKinematics=True, physicsClientId=self.cid)
                pos, orn = st[4], st[5]  # URDF link frame (not the inertial frame)
            out[i, :3, :3] = np.asarray(p.getMatrixFromQuaternion(orn)).reshape(3, 3)
            out[i, :3, 3] = pos
            out[i, 3, 3] = 1.0
        return out

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
        view = view_matrix(T_world_camera)
        proj = projection_matrix(K, width, height, near_m, far_m)
        rgba, zbuf, seg = self.render_raw(view, proj, width, height, lighting, segmentation)
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[..., :3]
        depth = linearize_depth(np.asarray(zbuf).reshape(height, width), near_m, far_m)
        labels = None
        if segmentation and self.body is not None:
            labels = self.labels(np.asarray(seg).reshape(height, width))
        return Frame(rgb, depth, labels)

    def render_raw(self, view: tuple, proj: tuple, width: int, height: int, lighting: Lighting, segmentation: bool):
        """pybullet's own buffers, no conversion: (rgba uint8 (H, W, 4), depth buffer float32 (H, W),
        segmentation int32 (H, W) or None). The dataset converts whole sequences at once instead of
        paying numpy overhead per image."""
        p = self.p
        flags = p.ER_SEGMENTATION_MASK_OBJECT_AND_LINKINDEX if segmentation else p.ER_NO_SEGMENTATION_MASK
        _, _, rgba, zbuf, seg = p.getCameraImage(
            width,
            height,
            viewMatrix=view,
            projectionMatrix=proj,
            renderer=p.ER_TINY_RENDERER,
            flags=flags,
            lightDirection=list(lighting.direction),
            lightColor=list(lighting.color),
            lightAmbientCoeff=lighting.ambient,
            lightDiffuseCoeff=lighting.diffuse,
            lightSpecularCoeff=lighting.specular,
            shadow=int(lighting.shadow),
            physicsClientId=self.cid,
        )
        return rgba, zbuf, (seg if segmentation else None)

    def labels(self, seg: np.ndarray) -> np.ndarray:
        """pybullet's object+link segmentation to link labels (0 background, k = link k - 1).

        pybullet encodes body + ((link index + 1) << 24); background is -1, other bodies (table,
        clutter) have other low bits."""
        seg = np.asarray(seg, dtype=np.int32)
        ours = (seg & 0xFFFFFF) == self.body
        return np.where(ours, self._label_lut[(seg >> 24) & 0x7F], 0).astype(np.uint8)

    def close(self) -> None:
        if self.cid is not None:
            try:
                self.p.disconnect(physicsClientId=self.cid)
            except self.p.error:
                pass
            self.cid = None

    def __enter__(self) -> Twin:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass
