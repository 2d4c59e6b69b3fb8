"""A pin joint is two plates thick (`spare_twin.measure.joints`): where a chain is seen from both sides
of its plane, its joints tell a link from a plate its lean cut in two, and find a joint where the
layers' rounding ran two links into one."""

import numpy as np
import pytest
from plate_chain import leaning_chain

from spare_twin.measure import layers as L
from spare_twin.measure.joints import Thickness, chain_sides, hidden_joint, joint_excess_layers

PITCH_M, PRINT_SCALE = 0.0064, 0.08
LENGTHS_M = (0.07, 0.045, 0.06, 0.04, 0.035)
ANGLES_DEG = (50.0, -70.0, 40.0, 60.0)
LEANS_DEG = (3.0, -2.5, 4.0, -1.5)


def _chain(lengths_m=LENGTHS_M, angles_deg=ANGLES_DEG, leans_deg=LEANS_DEG, seed=0):
    return leaning_chain(lengths_m, angles_deg, leans_deg, PITCH_M, seed)


def _thickness(p, v) -> Thickness:
    return Thickness(p[:, [0, 2]], p[:, 1], chain_sides(v[:, 1], 0.3), PITCH_M)


def test_a_joint_stands_a_layer_thicker_than_a_plate():
    p, v, labels, joints = _chain()
    thickness = _thickness(p, v)
    assert abs(thickness.plate_m - 0.006) < 0.001  # one plate: its two faces 6 mm apart
    layers = [p[labels == k][:, [0, 2]] for k in range(len(joints) + 1)]
    starts = np.concatenate([[[0.0, 0.0]], joints])
    assert np.allclose(joint_excess_layers(thickness, starts), 1.0, atol=0.2)
    assert hidden_joint(thickness, layers, starts) is None  # along the plates: one plate thick
    # links 2 and 3 in one layer: the pin between them, in the middle of the layer, is found
    merged = [*layers[:2], np.concatenate(layers[2:4]), layers[4]]
    j, place = hidden_joint(thickness, merged, starts[[0, 1, 2, 4]])
    assert j == 2 and np.linalg.norm(place - joints[2]) < 0.006
    # seen from one side only, a joint shows no thickness, and nothing is said
    front = v[:, 1] > 0
    assert np.isnan(joint_excess_layers(_thickness(p[front], v[front]), starts)).all()


def test_a_chain_of_short_links_reads_its_plates_not_its_overlaps():
    """Links 13 mm between pins on plates 12 mm wide: most places are a joint's overlap, and the
    median thickness is a joint's. The plate is the mode of the thinner places, and every joint still
    stands a layer thicker (bench seed 31697: with the median, 8.3 mm, its joints read 0.3-0.5 layers
    and a link was merged as a cut plate)."""
    for seed in (0, 1, 2):
        p, v, _, joints = _chain(
            (0.02, 0.013, 0.013, 0.013, 0.013, 0.012),
            (40.0, -60.0, 50.0, -45.0, 60.0),
            (2.0, -2.0, 3.0, -1.5, 2.0),
            seed,
        )
        thickness = _thickness(p, v)
        everywhere = thickness.at(p[v[:, 1] > 0][:, [0, 2]])
        assert np.nanmedian(everywhere) > 0.010  # the overlaps are most of the places
        assert abs(thickness.plate_m - 0.006) < 0.0006
        excess = joint_excess_layers(thickness, np.concatenate([[[0.0, 0.0]], joints]))
        assert np.allclose(excess, 1.0, atol=0.2), excess


def _measured(p, v, labels, with_thickness=True, bends=True):
    """`_measure_reading` of the chain's points with the given layer labels (their plate centres
    whole layers: no lean for the centres' step to go by)."""
    cfg = L.LayersConfig(bends=bends)
    keep = p[:, 2] > cfg.min_height_m
    thickness = _thickness(p[keep], v[keep]) if with_thickness else None
    labels = labels[keep]
    centres = labels.astype(np.float64)
    return L._measure_reading(p[keep], labels, centres, PRINT_SCALE, cfg, thickness, centres * PITCH_M)


def test_a_plate_read_as_two_links_is_one_where_the_cut_is_one_plate_thick():
    """Link 2's far half read a layer up (its lean climbed past the half-way mark), and every layer
    above with it: with plate centres whole layers apart the step where they meet looks like a joint
    (bench seed 30298's 25 mm link, read as two at a straight joint); its thickness says one plate."""
    p, v, labels, joints = _chain(leans_deg=(0.0, 0.0, 0.0, 0.0))
    along = (p[:, [0, 2]] - joints[1]) @ (joints[2] - joints[1])
    far_half = (labels == 2) & (along > 0.5 * np.sum((joints[2] - joints[1]) ** 2))
    misread = np.where(far_half | (labels > 2), labels + 1, labels)
    assert _measured(p, v, misread, with_thickness=False).n_links == 5  # the step alone: a link too many
    m = _measured(p, v, misread)
    assert m.n_links == 4, m.points_per_layer
    assert np.allclose(m.lengths_pu, np.asarray(LENGTHS_M) / PRINT_SCALE, atol=0.003 / PRINT_SCALE), m.lengths_pu


@pytest.mark.parametrize("merged", [2, 3])
def test_two_links_read_as_one_layer_are_split_at_the_pin_between_them(merged):
    """Links `merged` and `merged` + 1 read in one layer, every layer above one down (bench seed
    30316: two links at 15 deg read as one): the plate fitted to both stands a layer thicker at the
    pin between them, and is split there."""
    p, v, labels, _ = _chain()
    misread = np.where(labels > merged, labels - 1, labels)
    assert _measured(p, v, misread, with_thickness=False, bends=False).n_links == 3
    # the last layer bent where links 3 and 4 meet is split there without the thickness too (`measure.bends`)
    assert _measured(p, v, misread, with_thickness=False).n_links == (4 if merged == 3 else 3)
    m = _measured(p, v, misread)
    assert m.n_links == 4, m.points_per_layer
    assert np.allclose(m.lengths_pu, np.asarray(LENGTHS_M) / PRINT_SCALE, atol=0.003 / PRINT_SCALE), m.lengths_pu
