"""The printed twin in Rerun through Rerun's own URDF support (rerun-sdk 0.41: `rerun.urdf.UrdfTree`),
posed on the timeline by joint angles: what `live` and `compare` show.

The URDF is logged once (its meshes, materials and fixed transforms: static, as Rerun's URDF loader
writes them) under its own entity `<name>/<robot>` with its frames prefixed `<name>_`; its root link
is then placed in the view's world (a transform from `tf#/<world>`, the implicit frame of the world
entity) and each revolute joint turned by its angle (`UrdfJoint.compute_transform`), every time the
pose changes. Static data cannot be taken back, so a twin that is replaced (a new estimate built a new
one) is shrunk to nothing from then on (`hide`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spare_twin.config import PartDims

#: Scale of a hidden twin: far below a pixel (a zero scale would make a singular transform).
HIDDEN_SCALE = 1e-6


class UrdfTwin:
    """A URDF in a Rerun recording stream, posed by `pose` (see the module doc)."""

    def __init__(self, stream, urdf_path: str | Path, name: str, world: str = "world"):
        from rerun.urdf import UrdfTree

        self.stream, self.name, self.world_frame = stream, name, f"tf#/{world}"
        self.tree = UrdfTree.from_file_path(
            str(urdf_path), name, frame_prefix=f"{name}_", static_transform_entity_path=f"{name}/tf_static"
        )
        self.root_frame = f"{name}_{self.tree.root_link().name}"
        self.joints = [j for j in self.tree.joints() if j.joint_type in ("revolute", "continuous")]
        self.tree.log_urdf_to_recording(stream)

    @property
    def n_joints(self) -> int:
        return len(self.joints)

    def pose(self, T_world_base: np.ndarray, joint_angles_rad) -> None:
        """Place the root link at `T_world_base` (4x4, metres) and turn joint k by angle k (radians,
        the URDF's joint order), at the stream's current time."""
        import rerun as rr

        T = np.asarray(T_world_base, np.float64)
        self.stream.log(
            f"{self.name}/root",
            rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3], parent_frame=self.world_frame,
                           child_frame=self.root_frame),
        )  # fmt: skip
        angles = [] if joint_angles_rad is None else list(joint_angles_rad)
        for joint, angle in zip(self.joints, angles):
            self.stream.log(f"{self.name}/joints/{joint.name}", joint.compute_transform(float(angle), clamp=False))

    def hide(self) -> None:
        """Shrink the twin to nothing from the current time on."""
        import rerun as rr

        self.stream.log(
            f"{self.name}/root",
            rr.Transform3D(scale=HIDDEN_SCALE, parent_frame=self.world_frame, child_frame=self.root_frame),
        )


def chain_points_m(
    link_lengths_pu, joint_angles_rad, print_scale: float, layer_m: float = PartDims().layer_pitch_mm / 1000.0
) -> np.ndarray:
    """The chain's centre line in its base frame (x along the chain's plane, y along the joint axes,
    z up; metres): the base from the table to joint 1, then each link at its cumulative angle about
    +y, one layer (`layer_m`) further along y than its parent. (n + 2, 3) points."""
    lengths = np.asarray(link_lengths_pu, np.float64) * print_scale
    angles = np.zeros(len(lengths) - 1) if joint_angles_rad is None else np.asarray(joint_angles_rad, np.float64)
    pts = [np.zeros(3), np.array([0.0, 0.0, lengths[0]])]
    phi = 0.0
    for length, angle in zip(lengths[1:], angles):
        phi += angle
        pts.append(pts[-1] + length * np.array([np.sin(phi), 0.0, np.cos(phi)]))
    out = np.array(pts)
    out[2:, 1] = layer_m * np.arange(1, len(out) - 1)  # link k's tip in link k's layer
    return out
