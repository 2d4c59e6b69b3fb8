"""Table plane and object segmentation on a synthetic cloud with a known object frame."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation


def _scene(rng, T_world_table, with_object=True, clutter=True):
    """A 0.8 m table (z = 0) with an upright 40 x 20 x 120 mm box at (0.05, -0.03), yawed 30 deg."""
    g = np.arange(-0.4, 0.4, 0.004)
    table = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    pts = [np.column_stack([table, rng.normal(0, 0.001, len(table))])]
    if with_object:
        yaw = np.radians(30)
        R = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
        box = []
        for z in np.arange(0.0, 0.12, 0.003):  # side walls of the box, every 3 mm
            for s in np.linspace(-1, 1, 30):
                box += [(0.02 * s, -0.01, z), (0.02 * s, 0.01, z), (-0.02, 0.01 * s, z), (0.02, 0.01 * s, z)]
        box = np.array(box)
        box[:, :2] = box[:, :2] @ R.T + [0.05, -0.03]
        pts.append(box)
    if clutter:  # a floating blob (a lamp) that must not be taken for the object
        pts.append(rng.normal([-0.2, 0.2, 0.3], 0.01, (400, 3)))
    P = np.concatenate(pts)
    return P @ T_world_table[:3, :3].T + T_world_table[:3, 3]


def test_object_frame_on_the_table():
    from spare_twin.capture.segment import find_object

    rng = np.random.default_rng(0)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", [110, -20, 40], degrees=True).as_matrix()  # any world frame
    T[:3, 3] = [0.3, -0.2, 0.9]
    P = _scene(rng, T)
    cams = (np.array([[0.5, 0, 0.6], [-0.5, 0, 0.6], [0, 0.5, 0.6]]) @ T[:3, :3].T) + T[:3, 3]
    obj = find_object(P, None, cams)
    T_table_object = np.linalg.inv(T) @ obj.T_world_object
    assert np.allclose(T_table_object[:3, 2], [0, 0, 1], atol=0.01)  # z up
    assert np.allclose(T_table_object[:3, 3], [0.05, -0.03, 0], atol=0.004)  # footprint centre, on the table
    x = T_table_object[:3, 0]
    assert abs(abs(x @ [np.cos(np.radians(30)), np.sin(np.radians(30)), 0]) - 1) < 0.01  # long side of the box
    assert obj.height_m == pytest.approx(0.12, abs=0.006)
    assert obj.footprint_m[0] == pytest.approx(0.04, abs=0.004) and obj.footprint_m[1] == pytest.approx(0.02, abs=0.004)


def test_no_object_is_one_line_error():
    from spare_twin.capture.segment import find_object
    from spare_twin.errors import SpareTwinError

    rng = np.random.default_rng(1)
    P = _scene(rng, np.eye(4), with_object=False)
    with pytest.raises(SpareTwinError, match=r"^scene\.ply: no object found"):
        find_object(P, None, np.array([[0, 0, 0.6]]), source="scene.ply")
