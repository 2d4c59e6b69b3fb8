"""Rendering geometry: depth linearisation, pixel conventions, segmentation, link poses, the rig."""

import numpy as np
import pytest

from spare_twin.config import ChainSpec
from spare_twin.object.folder import build_sim_twin
from spare_twin.sim.rig import Rig, load_rig, look_at
from spare_twin.sim.twin import Twin, linearize_depth


def test_linearize_depth_formula():
    near, far = 0.05, 2.0
    z_true = np.array([0.05, 0.3, 1.0, 1.99])
    # the OpenGL depth buffer value of eye depth z: (f + n - 2fn/z) / (f - n) mapped to 0..1
    zbuf = ((far + near - 2 * far * near / z_true) / (far - near) + 1) / 2
    assert np.allclose(linearize_depth(zbuf.astype(np.float32), near, far), z_true, rtol=1e-4)
    assert linearize_depth(np.ones(3, np.float32), near, far).tolist() == [0, 0, 0]  # far plane = no reading


def test_plane_at_known_distance_gives_constant_z_depth():
    twin = Twin(table=False)
    twin.add_box([0.01, 1.0, 1.0], [0.0, 0.0, 0.3], [1, 1, 1, 1])  # wall, face at x = 0.01
    rig = Rig()
    T = look_at([0.5, 0.0, 0.3], [0.0, 0.0, 0.3])  # camera 0.49 m from the face, looking straight at it
    f = twin.render(T, rig.K(), 128, 96, rig.near_m, rig.far_m)
    # z-depth (not ray length): the same at the centre and in the corners
    assert np.abs(f.depth_m - 0.49).max() < 2e-4
    twin.close()


@pytest.mark.parametrize("wh", [(128, 96), (512, 384)])
def test_point_lands_on_the_pixel_K_predicts(wh):
    W, H = wh
    rig = Rig()
    K = rig.K(W, H)
    T = look_at([0.5, 0.0, 0.3], [0.0, 0.0, 0.3])
    for p in ([0.0, 0.08, 0.35], [0.0, -0.1, 0.25]):
        twin = Twin(table=False)
        twin.add_box([0.004] * 3, p, [1, 0, 0, 1])
        f = twin.render(T, K, W, H, rig.near_m, rig.far_m)
        ys, xs = np.nonzero(f.depth_m > 0)
        pc = np.linalg.inv(T) @ np.r_[p, 1.0]
        u, v = (K @ pc[:3])[:2] / pc[2]
        assert abs(xs.mean() - u) < 0.6 and abs(ys.mean() - v) < 0.6, (xs.mean(), ys.mean(), u, v)
        twin.close()


def test_segmentation_and_link_poses(tmp_path):
    spec = ChainSpec(n_links=3, link_lengths_pu=(1.6, 0.6, 0.5, 0.4), colors=("red", "blue", "green", "yellow"))
    obj = build_sim_twin(spec, tmp_path / "o")
    rig = Rig()
    with Twin() as twin:
        twin.load(obj)
        angles = [0.5, -0.4, 0.3]
        twin.set_joints(angles)
        poses = twin.link_poses()
        # link 1's frame sits on joint 1: (0, pitch, L0 * scale), turned by angle 1 about +y
        assert np.allclose(poses[1][:3, 3], [0, spec.layer_pitch_mm / 1000, 1.6 * 0.08], atol=1e-6)
        assert np.isclose(np.arctan2(poses[1][0, 2], poses[1][2, 2]), 0.5, atol=1e-6)
        try:
            from spare_twin.object.kinematics import forward_kinematics
        except ImportError:
            forward_kinematics = None
        if forward_kinematics is not None:
            assert np.allclose(poses, forward_kinematics(spec, angles), atol=1e-6)
        seen = set()
        for T in rig.poses():
            f = twin.render(T, rig.K(), rig.width, rig.height, rig.near_m, rig.far_m)
            seen |= set(np.unique(f.segmentation).tolist())
            # every labelled pixel has a depth reading; the table has depth but label 0
            assert (f.depth_m[f.segmentation > 0] > 0).all()
            assert ((f.depth_m > 0) & (f.segmentation == 0)).any()
        assert seen == {0, 1, 2, 3, 4}


def test_default_rig_frames_the_largest_object(tmp_path):
    rig = load_rig("spare8")
    assert rig.n_cameras == 8 and (rig.height, rig.width) == (96, 128)
    P = rig.poses()
    for T in P:
        assert np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-9)
        to_target = np.asarray(rig.look_at_m) - T[:3, 3]
        assert np.allclose(T[:3, 2], to_target / np.linalg.norm(to_target))
        assert T[:3, 1][2] < 0  # image y points down in the world
    # the tallest chain (sum of lengths 3 paper m) and the widest sweep stay inside every view
    spec = ChainSpec(n_links=1, link_lengths_pu=(1.3, 1.7), colors=("red", "blue"))
    with Twin() as twin:
        twin.load(build_sim_twin(spec, tmp_path / "o"))
        for angle in (0.0, 1.4, -1.4):
            twin.set_joints([angle])
            for T in P:
                seg = twin.render(T, rig.K(), rig.width, rig.height, rig.near_m, rig.far_m).segmentation
                ys, xs = np.nonzero(seg)
                assert ys.min() > 0 and xs.min() > 0 and ys.max() < rig.height - 1 and xs.max() < rig.width - 1
