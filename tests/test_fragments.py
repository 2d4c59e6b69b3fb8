"""A layer's stray fragments (`spare_twin.measure.fragments`): a few of one plate's points read a
layer off, apart from their layer's plate, go to the layer around them; nothing else moves."""

import numpy as np
import pytest
from plate_chain import leaning_chain

import spare_twin.measure.layers as L
from spare_twin.measure.fragments import adopt_fragments
from spare_twin.measure.layers import LayersConfig, measure_layers

PITCH_M = 0.0064
RADIUS_M = LayersConfig().radius_m
MIN_POINTS = LayersConfig().min_layer_points
PRINT_SCALE = 0.08


def _grid(s_lo, s_hi, z_lo, z_hi, spacing_m=0.0025) -> np.ndarray:
    s, z = np.meshgrid(np.arange(s_lo, s_hi, spacing_m), np.arange(z_lo, z_hi, spacing_m))
    return np.stack([s.ravel(), z.ravel()], 1)


def _column_and_arm():
    """(sz (N, 2), labels): a base column (layer 0) 12 mm wide and 12 cm tall, and link 1 (layer 1)
    running off its top to the side."""
    column = _grid(-0.006, 0.006, 0.02, 0.13)
    arm = _grid(0.0, 0.08, 0.118, 0.13)
    arm = arm[arm[:, 0] > 0.008]  # beside the column's top, as far as the grid goes
    sz = np.concatenate([column, arm])
    return sz, np.concatenate([np.zeros(len(column), np.int64), np.ones(len(arm), np.int64)])


def test_column_points_read_a_layer_up_go_back_to_the_column():
    sz, labels = _column_and_arm()
    stray = (sz[:, 0] < 0.006) & (((sz[:, 1] > 0.049) & (sz[:, 1] < 0.056)) | ((sz[:, 1] > 0.079) & (sz[:, 1] < 0.086)))
    read = np.where(stray, 1, labels)
    centres = read + 0.2
    assert MIN_POINTS <= stray.sum() / 2 < 0.1 * (read == 1).sum()  # two fragments, not pieces that count
    adopted, adopted_centres = adopt_fragments(sz, read, centres, RADIUS_M, MIN_POINTS)
    assert np.array_equal(adopted, labels)
    assert np.allclose(adopted_centres, labels + 0.2)  # moved by the same whole layer


@pytest.mark.parametrize(
    "why", ["a piece large enough to count", "among a layer two away", "alone", "a few points", "beside its own plate"]
)
def test_fragments_that_are_no_stray_stay_where_they_were_read(why):
    sz, labels = _column_and_arm()
    if why == "a piece large enough to count":  # 3 cm of the column: a link folded down beside it
        stray = (sz[:, 0] < 0.006) & (sz[:, 1] > 0.05) & (sz[:, 1] < 0.08)
        read = np.where(stray, 1, labels)
    elif why == "among a layer two away":
        stray = (sz[:, 0] < 0.006) & (sz[:, 1] > 0.049) & (sz[:, 1] < 0.056)
        read = np.where(stray, 3, labels)
    elif why == "a few points":  # noise, which the fit's robust loss holds: given to a plate, it stretches it
        stray = (sz[:, 0] < 0.006) & (sz[:, 1] > 0.049) & (sz[:, 1] < 0.051)
        assert 0 < stray.sum() < MIN_POINTS
        read = np.where(stray, 1, labels)
    elif why == "beside its own plate":  # within 12 mm of link 1's plate, where a joint's plates overlap
        stray = (sz[:, 0] < 0.006) & (sz[:, 1] > 0.104) & (sz[:, 1] < 0.111)
        assert MIN_POINTS <= stray.sum()
        read = np.where(stray, 1, labels)
    else:  # far from every other point: nothing to give it to
        sz = np.concatenate([sz, _grid(0.1, 0.11, 0.02, 0.03)])
        read = np.concatenate([labels, np.ones(len(sz) - len(labels), np.int64)])
    adopted, _ = adopt_fragments(sz, read, read.astype(float), RADIUS_M, MIN_POINTS)
    assert np.array_equal(adopted, read)


def test_readings_between_two_crossing_plates_go_to_the_nearer_of_them():
    """Link 3 (layer 3) crosses in front of the base column (layer 0), as in the rig view of bench
    seed 31004: readings that mix the two faces put plate centres between them, read as layers 1
    and 2, 6-7 cm from those layers' plates, among neighbours of layers 0 and 3 (about 40 % each,
    about 20 % the other piece). Each goes to the nearer of the two (its plate centre moved by the
    same whole layers); nothing else moves. Before release 0.6.29 both stayed: neither layer next
    to theirs held most of their neighbours."""
    column = _grid(-0.006, 0.006, 0.02, 0.13)
    arm = _grid(0.0, 0.08, 0.118, 0.13)
    arm = arm[arm[:, 0] > 0.008]
    down = _grid(0.07, 0.082, 0.06, 0.116)  # link 2, down from link 1's end
    across = _grid(-0.02, 0.068, 0.055, 0.06)  # link 3, back across the column
    sz = np.concatenate([column, arm, down, across])
    labels = np.repeat([0, 1, 2, 3], [len(column), len(arm), len(down), len(across)])
    at_crossing = (np.abs(sz[:, 0]) < 0.006) & (labels == 0)
    low = at_crossing & (sz[:, 1] > 0.049) & (sz[:, 1] < 0.0555)
    high = at_crossing & (sz[:, 1] > 0.0555) & (sz[:, 1] < 0.063)
    assert low.sum() >= MIN_POINTS and high.sum() >= MIN_POINTS
    read = np.where(low, 1, np.where(high, 2, labels))
    centres = np.where(low, 0.9, np.where(high, 2.3, labels.astype(np.float64)))
    adopted, adopted_centres = adopt_fragments(sz, read, centres, RADIUS_M, MIN_POINTS)
    assert np.all(adopted[low] == 0) and np.all(adopted[high] == 3)
    assert np.allclose(adopted_centres[low], -0.1) and np.allclose(adopted_centres[high], 3.3)
    assert np.array_equal(adopted[~(low | high)], labels[~(low | high)])


@pytest.fixture
def folded_chain():
    """A 2-link chain as bench seed 30601 (base 124 mm, link 1 out sideways 43 mm, link 2 folded back
    down 42 mm), seen from both sides."""
    p, v, _, _ = leaning_chain([0.124, 0.043, 0.042], [95.0, 105.0], [0.0, 0.0], PITCH_M, seed=3)
    return p, v


@pytest.mark.parametrize("adopt", [True, False])
def test_stray_column_points_no_longer_draw_the_first_link_down_the_base(monkeypatch, folded_chain, adopt):
    """Pieces of the base column read as link 1, 3-6 cm below its plate: with them adopted the
    lengths are those of the chain read right (within 1 mm); left in link 1 they drew it down along
    the base (8 mm or more off)."""
    p, v = folded_chain
    read_right = measure_layers(p, PRINT_SCALE, view_dirs=v)
    assert read_right.n_links == 2
    readings = L.layer_readings

    def misread(s, t, z, view_t, cfg, centre_t_m=None):
        stray = (np.abs(s) < 0.006) & (np.abs(t) < 0.004) & (((z > 0.06) & (z < 0.066)) | ((z > 0.085) & (z < 0.09)))
        read = readings(s, t, z, view_t, cfg, centre_t_m)
        return [(np.where(stray, 1, labels), np.where(stray, 1.0, c)) for labels, c in read]

    monkeypatch.setattr(L, "layer_readings", misread)
    if not adopt:
        monkeypatch.setattr(L, "adopt_fragments", lambda sz, labels, centres, *settings: (labels, centres))
    m = measure_layers(p, PRINT_SCALE, view_dirs=v)
    assert m.n_links == 2
    off_pu = np.abs(m.lengths_pu - read_right.lengths_pu).max()
    assert (off_pu < 0.0125) if adopt else (off_pu > 0.1)
