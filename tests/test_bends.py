"""Where a layer's points bend in the chain's plane (`spare_twin.measure.bends`): two links the
layers' rounding ran into one, found where neither the joints' thickness nor a step across the
plane tells them apart."""

import numpy as np
import pytest
from plate_chain import leaning_chain

from spare_twin.measure import layers as L
from spare_twin.measure.bends import bent_layer
from spare_twin.measure.fit import fit_layers, plate_segments

PITCH_M, PRINT_SCALE = 0.0064, 0.08
LENGTHS_M = (0.07, 0.04, 0.04, 0.03)


def _chain(angles_deg, merge: int, seed: int):
    """A 3-link chain's points above the socket with links `merge` and `merge` + 1 in one layer and
    plate centres a whole layer each (no step to go by): (points, merged labels, true links)."""
    p, _, links, _ = leaning_chain(LENGTHS_M, angles_deg, (0.0, 0.0, 0.0), PITCH_M, seed, noise_m=0.0005)
    keep = p[:, 2] > L.LayersConfig().min_height_m
    p, links = p[keep], links[keep]
    return p, np.where(links > merge, links - 1, links), links


@pytest.mark.parametrize("seed", [0, 1])
def test_a_last_link_bent_off_its_parents_plate_in_one_layer_is_split_at_the_bend(seed):
    """Links 2 and 3 (the last) in one layer, bent 35 deg apart, their plate centres no help: the
    layer is split where the points bend, and the chain measures 3 links within 3 mm of the print
    (held-out 31605, SR300: its last link in its parent's layer, 4 links read as 3). With bends not
    read, 2. Links 1 and 2 in one layer, between two others, are left as they are: only the last
    layer is read for a bend (every layer read so split synthetic chains whose joints' noise and
    overlaps bent a layer, `test_layers`, `test_fragments`)."""
    p, merged, _ = _chain((20.0, -30.0, 35.0), 2, seed)
    flat = merged * PITCH_M
    cfg = L.LayersConfig()
    m = L._measure_reading(p, merged, merged.astype(np.float64), PRINT_SCALE, cfg, None, flat)
    assert m.n_links == 3, m.points_per_layer
    assert np.allclose(m.lengths_pu, np.array(LENGTHS_M) / PRINT_SCALE, atol=0.003 / PRINT_SCALE), m.lengths_pu
    straight = L.LayersConfig(bends=False)
    assert L._measure_reading(p, merged, merged.astype(np.float64), PRINT_SCALE, straight, None, flat).n_links == 2
    p, merged, _ = _chain((20.0, 35.0, -30.0), 1, seed)
    assert (
        L._measure_reading(p, merged, merged.astype(np.float64), PRINT_SCALE, cfg, None, merged * PITCH_M).n_links == 2
    )


@pytest.mark.parametrize("angles_deg", [(20.0, -30.0, 35.0), (20.0, -5.0, 6.0)])
def test_a_chain_read_right_or_bent_a_few_degrees_shows_no_bend(angles_deg):
    """Each link in its own layer, however bent, is straight; two links in one layer bent by 6 deg
    leave their plate under `bends.MIN_BENT_RMS_M` (a bend that small is a step's business)."""
    p, merged, links = _chain(angles_deg, 2, 0)
    cfg = L.LayersConfig()
    for labels in (links, merged):
        n = int(labels.max())
        layers = [p[labels == k][:, [0, 2]] for k in range(n + 1)]
        starts, ends = plate_segments(fit_layers(layers, n, cfg)[0], n, cfg)
        bent = bent_layer(layers, starts, ends, cfg.half_width_m)
        assert bent is None or (labels is merged and angles_deg[2] > 10), (angles_deg, bent)
