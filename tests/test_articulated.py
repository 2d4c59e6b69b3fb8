"""Articulated registration recovers a known base pose and joint angles from a noisy cloud."""

import numpy as np
import pytest

from spare_twin.articulated import base_pose, fit_articulated, twin_surface_points
from spare_twin.kinematics import forward_kinematics, sample_pose


def _wrap_deg(a):
    return np.degrees(np.abs((a + np.pi) % (2 * np.pi) - np.pi))


@pytest.mark.parametrize("n, seed", [(3, 0), (5, 1)])
def test_recovers_joint_angles_within_5_degrees(object_dirs, n, seed):
    obj = object_dirs[n]
    rng = np.random.default_rng(seed)
    q = sample_pose(obj.spec, rng)
    x, y, yaw = rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), rng.uniform(-np.pi, np.pi)
    poses = forward_kinematics(obj.spec, q, base_pose(x, y, yaw))
    # A denser, independent sampling of the twin than the fit uses, with 1 mm sensor-like noise.
    cloud = np.vstack([p @ T[:3, :3].T + T[:3, 3] for p, T in zip(twin_surface_points(obj, 1500, seed=99), poses)])
    cloud += rng.normal(0.0, 0.001, cloud.shape)
    fit = fit_articulated(obj, cloud)
    assert _wrap_deg(fit.joint_angles_rad - q).max() < 5.0
    assert np.hypot(*(fit.T_world_base[:2, 3] - [x, y])) < 0.005
    assert _wrap_deg(np.arctan2(fit.T_world_base[1, 0], fit.T_world_base[0, 0]) - yaw) < 5.0
    assert fit.inlier_fraction > 0.8


def test_rejects_an_empty_cloud(object_dirs):
    from spare_twin import SpareTwinError

    with pytest.raises(SpareTwinError, match="needs an object cloud"):
        fit_articulated(object_dirs[2], np.zeros((10, 3)))
