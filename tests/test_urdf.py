"""The URDF twin: loads in yourdfpy, pybullet and ROS's check_urdf, and matches the printed parts."""

import shutil
import subprocess

import numpy as np
import pytest
import trimesh

from spare_twin.object.kinematics import forward_kinematics, is_clear_of_foot, joint_limits_rad, sample_pose
from spare_twin.object.urdf import load_urdf


def test_check_urdf_accepts_every_object(object_dirs):
    assert shutil.which("check_urdf"), "liburdfdom-tools is installed by scripts/setup.sh"
    for obj in object_dirs.values():
        res = subprocess.run(["check_urdf", str(obj.urdf_path)], capture_output=True, text=True)
        assert res.returncode == 0, res.stderr
        assert "Successfully Parsed XML" in res.stdout
        assert f"link{obj.spec.n_links}" in res.stdout


def test_yourdfpy_loads_meshes_and_inertia(object_dirs):
    for n, obj in object_dirs.items():
        urdf = load_urdf(obj.urdf_path)
        assert [j for j in urdf.actuated_joint_names] == [f"joint{k}" for k in range(1, n + 1)]
        for link in urdf.robot.links:
            assert link.inertial.mass > 0
            assert np.all(np.linalg.eigvalsh(link.inertial.inertia) > 0)
            assert len(link.visuals) == len(link.collisions) >= 1
        # Every visual mesh is a file of the folder, scaled from millimetres.
        meshes = [v.geometry.mesh for l in urdf.robot.links for v in l.visuals]
        assert all((obj.root / m.filename).is_file() and np.allclose(m.scale, 1e-3) for m in meshes)


def test_joint_axis_distances_equal_configured_lengths(object_dirs):
    for obj in object_dirs.values():
        urdf = load_urdf(obj.urdf_path)
        joints = {j.name: j for j in urdf.robot.joints}
        L_m = np.array(obj.spec.link_lengths_pu) * obj.spec.print_scale
        for k in range(1, obj.spec.n_links + 1):
            j = joints[f"joint{k}"]
            assert np.allclose(j.axis, [0, 1, 0])
            # The offset along the (parallel) axes is the layer pitch; across them it is the link length.
            xyz = j.origin[:3, 3]
            assert abs(np.hypot(xyz[0], xyz[2]) - L_m[k - 1]) < 1e-4  # 0.1 mm
            assert abs(xyz[1] - obj.spec.layer_pitch_mm / 1000) < 1e-9


def _stl_hole_centres_mm(path, z_mm):
    mesh = trimesh.load(path, file_type="stl")
    section = mesh.section(plane_origin=[0, 0, z_mm], plane_normal=[0, 0, 1])
    planar, _ = section.to_2D(to_2D=np.eye(4))
    centres = [np.asarray(h.coords)[:-1].mean(axis=0) for p in planar.polygons_full for h in p.interiors]
    return sorted(centres, key=lambda c: c[0])


def test_forward_kinematics_puts_each_pin_on_its_parent_hole(object_dirs):
    """STL hole centres, placed by the URDF's visual origins and pybullet's forward kinematics."""
    import pybullet as pb

    rng = np.random.default_rng(0)
    for n, obj in object_dirs.items():
        urdf = load_urdf(obj.urdf_path)
        visual_origin = {v.name: v.origin for l in urdf.robot.links for v in l.visuals}
        client = pb.connect(pb.DIRECT)
        try:
            body = pb.loadURDF(str(obj.urdf_path), useFixedBase=True, physicsClientId=client)
            assert pb.getNumJoints(body, physicsClientId=client) == n
            for _ in range(5):
                angles = sample_pose(obj.spec, rng)
                for k, a in enumerate(angles):
                    pb.resetJointState(body, k, a, physicsClientId=client)
                T_world = [np.eye(4)]
                for k in range(n):
                    pos, quat = pb.getLinkState(body, k, computeForwardKinematics=True, physicsClientId=client)[4:6]
                    T = np.eye(4)
                    T[:3, :3] = np.array(pb.getMatrixFromQuaternion(quat)).reshape(3, 3)
                    T[:3, 3] = pos
                    T_world.append(T)
                # pybullet agrees with the library's own kinematics.
                ours = forward_kinematics(obj.spec, angles)
                assert np.allclose(np.array(T_world), ours, atol=1e-6)
                for k in range(1, n + 1):
                    parent_file = "link0_base" if k == 1 else f"link{k - 1}"
                    parent_hole = _stl_hole_centres_mm(obj.root / f"{parent_file}.stl", 1.0)[-1]
                    child_hole = _stl_hole_centres_mm(obj.root / f"link{k}.stl", 1.0)[0]
                    p = T_world[k - 1] @ visual_origin[parent_file] @ np.array([*parent_hole * 1e-3, 0.0, 1.0])
                    c = T_world[k] @ visual_origin[f"link{k}"] @ np.array([*child_hole * 1e-3, 0.0, 1.0])
                    axis = T_world[k][:3, 1]
                    d = (c - p)[:3]
                    off_axis = d - (d @ axis) * axis
                    assert np.linalg.norm(off_axis) < 2e-5, (
                        f"n={n} joint {k}: pin {np.linalg.norm(off_axis) * 1e3:.3f} mm off its hole"
                    )
        finally:
            pb.disconnect(client)


def test_joint_limits_keep_link1_off_the_foot(object_dirs):
    from spare_twin.config import ChainSpec
    from spare_twin.object.kinematics import KEEPOUT_MARGIN_M, keepout_height_m, link_segment_m

    limited = 0
    # The fixture's chains plus one whose first link nearly reaches the foot (base 1.3, link 1.0).
    long_first = ChainSpec(n_links=2, link_lengths_pu=(1.3, 1.0, 0.5), colors=("red", "blue", "green"))
    for spec in [obj.spec for obj in object_dirs.values()] + [long_first]:
        lo, hi = joint_limits_rad(spec)[0]
        _, reach = link_segment_m(spec, 1)
        axis_z = spec.link_lengths_pu[0] * spec.print_scale
        floor = keepout_height_m(spec) + KEEPOUT_MARGIN_M - 1e-9
        half_width = spec.parts.link_width_mm / 2000

        def link1_bottom(a, axis_z=axis_z, reach=reach, half_width=half_width):
            return axis_z + min(0.0, reach * np.cos(a)) - half_width

        assert all(link1_bottom(a) >= floor for a in np.linspace(lo, hi, 200))
        if hi < np.pi:  # the limit is tight: a little further and link 1 would hit the foot
            limited += 1
            assert link1_bottom(hi + 0.05) < floor
    assert limited >= 1


def test_sampled_poses_clear_the_foot_and_respect_limits(object_dirs):
    rng = np.random.default_rng(1)
    for obj in object_dirs.values():
        lim = joint_limits_rad(obj.spec)
        for _ in range(20):
            q = sample_pose(obj.spec, rng)
            assert np.all(q >= lim[:, 0]) and np.all(q <= lim[:, 1])
            assert is_clear_of_foot(obj.spec, q)


def test_closed_form_lowest_point_matches_forward_kinematics(object_dirs):
    from spare_twin.object.kinematics import link_segment_m, lowest_point_m

    rng = np.random.default_rng(3)
    for obj in object_dirs.values():
        spec = obj.spec
        for _ in range(20):
            q = rng.uniform(-np.pi, np.pi, spec.n_links)
            poses = forward_kinematics(spec, q)
            low = (
                min(
                    min(P[2, 3] + a * P[2, 2], P[2, 3] + b * P[2, 2])
                    for k, P in enumerate(poses[1:], start=1)
                    for a, b in [link_segment_m(spec, k)]
                )
                - spec.parts.link_width_mm / 2000
            )
            assert lowest_point_m(spec, q) == pytest.approx(low, abs=1e-12)
