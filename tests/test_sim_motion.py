"""Random joint motion: within limits, above the keep-out height, smooth, reproducible."""

import numpy as np
import pytest

from spare_twin.config import sample_chain
from spare_twin.errors import SpareTwinError
from spare_twin.sim.motion import MotionConfig, lowest_point_m, random_motion


@pytest.mark.parametrize("n", range(1, 7))
def test_motion_respects_limits_and_keepout(n):
    for seed in range(8):
        spec = sample_chain(n, seed)
        lengths = np.asarray(spec.link_lengths_pu) * spec.print_scale
        limits = np.tile([-np.pi, np.pi], (n, 1))
        limits[0] = [-2.0, 2.0]
        keepout, half_w = 0.017, 0.006
        a = random_motion(limits, lengths, keepout, half_w, np.random.default_rng(seed))
        assert a.shape == (100, n)
        assert (a >= limits[:, 0]).all() and (a <= limits[:, 1]).all()
        assert lowest_point_m(a, lengths, half_w).min() >= keepout
        assert np.abs(np.diff(a, axis=0)).max() < 0.5  # smooth: < 30 deg per frame at 10 fps
        assert np.array_equal(a, random_motion(limits, lengths, keepout, half_w, np.random.default_rng(seed)))
        try:  # the CAD stage's own clearance check, when it is present
            from spare_twin.object.kinematics import is_clear_of_foot
        except ImportError:
            continue
        assert all(is_clear_of_foot(spec, pose) for pose in a[::7])


def test_motion_actually_moves():
    spec = sample_chain(3, 0)
    lengths = np.asarray(spec.link_lengths_pu) * spec.print_scale
    a = random_motion(np.tile([-np.pi, np.pi], (3, 1)), lengths, 0.017, 0.006, np.random.default_rng(0), MotionConfig())
    assert np.ptp(a, axis=0).max() > 0.5


def test_upright_pose_below_keepout_is_an_error():
    with pytest.raises(SpareTwinError):
        random_motion(np.array([[-1.0, 1.0]]), np.array([0.01, 0.05]), 0.1, 0.006, np.random.default_rng(0))
