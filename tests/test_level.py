"""The profile levelled by its layers' comb (`measure.level`): what the profile network reads."""

from __future__ import annotations

import numpy as np
import pytest

from spare_twin.measure.layers import LayersConfig, measure_layers
from spare_twin.measure.level import levelled_image
from spare_twin.observe.points import ObjectPoints
from spare_twin.observe.profile import ChainProfile, ProfileConfig, draw_profile
from tests.plate_chain import leaning_chain

PRINT_SCALE = 0.08
PITCH_M = LayersConfig().layer_pitch_m
#: Six links in a zigzag, each plate leaning 3 deg about its pin the same way: the leans add up along the chain,
#: and the last link ends more than a layer past its own.
LENGTHS_M = (0.07, 0.045, 0.045, 0.045, 0.045, 0.045, 0.04)
ANGLES_DEG = (60.0, -120.0, 120.0, -120.0, 120.0, -120.0)
LEANS_DEG = (3.0,) * 6


def _top_layer(image: np.ndarray) -> int:
    """The image's top layer, as docs/nets.md reads it: the 97th percentile of its occupied cells'
    mean t, rounded."""
    return int(np.rint(np.percentile(image[1][image[0] > 0], 97)))


def _observed(points_m: np.ndarray) -> tuple[ObjectPoints, ChainProfile]:
    """The points as an observation in the profile frame (the table frame is the profile frame)."""
    obj = ObjectPoints(points_m, None, np.eye(4), len(points_m))
    image = draw_profile(
        points_m[:, 0] / PRINT_SCALE, points_m[:, 2] / PRINT_SCALE, points_m[:, 1] / PITCH_M, ProfileConfig()
    )
    return obj, ChainProfile(image, np.eye(4), True)


@pytest.fixture(scope="module")
def leaning():
    points, dirs, owner, _ = leaning_chain(LENGTHS_M, ANGLES_DEG, LEANS_DEG, PITCH_M)
    return points, dirs, owner


def test_links_leaning_a_layer_off_are_levelled_back_to_their_own_layers(leaning):
    """Seen as it is, the last link lies more than a layer past its own and the image's top layer is
    7, past any chain's 6 moving links; levelled by the comb, each link's points lie within half a
    layer of its own layer and the top layer is the count."""
    points, dirs, owner = leaning
    m = measure_layers(points, PRINT_SCALE, True, LayersConfig(), dirs)
    assert m.n_links == 6 and m.comb_zero is not None
    level_t = m.comb_zero.levelled_t_m(points[:, 0], points[:, 1], points[:, 2])
    raw_layers = [np.median(points[owner == k, 1]) / PITCH_M for k in range(7)]
    levelled_layers = [np.median(level_t[owner == k]) / PITCH_M for k in range(7)]
    assert raw_layers[6] > 7.0, raw_layers
    assert np.abs(np.array(levelled_layers) - np.arange(7)).max() < 0.5, levelled_layers
    obj, profile = _observed(points)
    assert _top_layer(profile.image) >= 7
    image = levelled_image(obj, profile, m.comb_zero, PRINT_SCALE, ProfileConfig())
    assert _top_layer(image) == 6
    assert np.array_equal(image[0], profile.image[0])  # the same cells: only t moves


def test_a_chain_without_play_is_drawn_as_it_is():
    """Without leans there is nothing to level: every occupied cell's mean t moves by a small fraction
    of a layer at most (the comb's zero follows the plates' centres, a millimetre off the base axis)."""
    points, dirs, _, _ = leaning_chain(LENGTHS_M, ANGLES_DEG, (0.0,) * 6, PITCH_M)
    m = measure_layers(points, PRINT_SCALE, True, LayersConfig(), dirs)
    obj, profile = _observed(points)
    image = levelled_image(obj, profile, m.comb_zero, PRINT_SCALE, ProfileConfig())
    occupied = profile.image[0] > 0
    assert m.n_links == 6 and np.abs(image[1] - profile.image[1])[occupied].max() < 0.2


def test_a_profile_turned_half_round_is_levelled_in_its_own_frame(leaning):
    """A profile whose sign was read wrong (the links at smaller t than the base) is measured turned
    back (`measure.layers._links_ahead`); its zero is given in the profile's own frame, so the levelled
    image is the first one's turned half round: t negated, s mirrored."""
    points, dirs, _ = leaning
    turned, turned_dirs = points * [-1.0, -1.0, 1.0], dirs * [-1.0, -1.0, 1.0]
    m = measure_layers(turned, PRINT_SCALE, True, LayersConfig(), turned_dirs)
    assert m.n_links == 6
    level_t = m.comb_zero.levelled_t_m(turned[:, 0], turned[:, 1], turned[:, 2])
    first = measure_layers(points, PRINT_SCALE, True, LayersConfig(), dirs)
    assert np.allclose(-level_t, first.comb_zero.levelled_t_m(points[:, 0], points[:, 1], points[:, 2]), atol=1e-9)


def test_no_comb_leaves_the_profile_as_observed(leaning):
    points, _, _ = leaning
    obj, profile = _observed(points)
    assert levelled_image(obj, profile, None, PRINT_SCALE, ProfileConfig()) is profile.image


def test_predict_shows_the_network_the_levelled_profile(rig_rec):
    """`predict`'s network reads the levelled profile, and its answer says so."""
    from spare_twin.measure.chain import measure_views
    from spare_twin.nets import checkpoint as ckpt
    from spare_twin.observe.points import PosedView
    from spare_twin.observe.views import PosedViews
    from spare_twin.predict.run import answer_of

    path = ckpt.default_model("predict")
    model, net, _ = ckpt.load_model(path)
    views = [PosedView(rig_rec.depth_m(c.name, 1), c.K, rig_rec.T_world_camera(c.name, 1)) for c in rig_rec.cameras]
    obs, m = measure_views(PosedViews(tuple(views), "cameras"), PRINT_SCALE)
    p = answer_of(obs, m, model, net, str(path), "network", PRINT_SCALE)
    assert m.comb_zero is not None and p.n_links == 2
    expected = levelled_image(
        obj=obs.object, profile=obs.profile, zero=m.comb_zero, print_scale=PRINT_SCALE, cfg=ProfileConfig()
    )
    assert np.array_equal(p.network_input, expected)
    assert p.to_json()["input"].startswith("profile (levelled by its layers' comb, ")
