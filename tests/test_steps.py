"""Where a layer's plate centres step along it (`spare_twin.measure.steps`): two links the layers'
rounding ran into one, found where the joints' thickness is not read."""

import numpy as np
import pytest
from plate_chain import HALF_THICKNESS_M, HALF_WIDTH_M, leaning_chain
from scipy.spatial import cKDTree

from spare_twin.measure import layers as L
from spare_twin.measure.medians import grouped_medians
from spare_twin.measure.steps import stepped_layer

PITCH_M, PRINT_SCALE = 0.0064, 0.08


def _layer(step_layers: float, step_at_m: float, lean_layers: float = 0.0, smooth_m: float = 0.005, seed: int = 0):
    """One layer's points along a 70 mm plate up the z axis (600 points) and their plate centres: a
    step of `step_layers` pitches at `step_at_m` from its joint, spread over `smooth_m` either side (a
    Kinect's smoothing), on a plate leaning by `lean_layers` pitches over its length, 0.3 mm of noise."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(0.0, 0.07, 600)
    sz = np.stack([rng.uniform(-HALF_WIDTH_M, HALF_WIDTH_M, len(u)), u], 1)
    ramp = np.clip((u - step_at_m + smooth_m) / (2 * smooth_m), 0.0, 1.0)
    t = PITCH_M * (step_layers * ramp + lean_layers * u / 0.07) + rng.normal(0.0, 0.0003, len(u))
    return sz, t


def _stepped(sz, t):
    starts, ends = np.array([[0.0, 0.0], [0.0, 0.0]]), np.array([[0.0, 0.0], [0.0, 0.07]])
    return stepped_layer([np.zeros((0, 2)), sz], [np.zeros(0), t], starts, ends, PITCH_M)


@pytest.mark.parametrize("step_layers, smooth_m", [(1.0, 0.005), (0.65, 0.003)])
def test_a_layer_whose_plate_centres_step_by_part_of_a_pitch_holds_a_joint_where_they_step(step_layers, smooth_m):
    """A joint's whole pitch spread over a centimetre, or plateaus 0.65 of a pitch apart (bench seed
    30545, 6 links, Kinect v1: its layer 2 held links 2-4, its plateaus 0.6-0.7 of a pitch apart
    stepping at the true joints)."""
    j, place = _stepped(*_layer(step_layers, 0.04, smooth_m=smooth_m))
    assert j == 1 and abs(place[1] - 0.04) < 0.003, place


@pytest.mark.parametrize(
    "why, layer",
    [
        ("a plate leaning out of its layer by most of a pitch is one line", _layer(0.0, 0.04, lean_layers=0.8)),
        ("a step of a third of a pitch is a lean's drift, not a joint", _layer(0.3, 0.04)),
        ("a step by the layer's own joint is its parent's overlap", _layer(0.8, 0.008)),
        ("a step by its far end is its child's overlap", _layer(0.8, 0.065)),
        ("a step down is no joint: a child is a layer up", _layer(-0.8, 0.04)),
    ],
)
def test_no_step_is_read_where_there_is_no_joint(why, layer):
    assert _stepped(*layer) is None, why


def _straight_run(lengths_m=(0.07, 0.04, 0.035, 0.03), angles_deg=(20.0, 3.0, -4.0), seed=0):
    """A chain of short links in a nearly straight run and its points' plate centres, their medians
    within 5 mm in the plane: (points (N, 3) s, t, z, each point's link, plate centres (N,))."""
    no_lean = (0.0,) * len(angles_deg)
    p, v, links, _ = leaning_chain(lengths_m, angles_deg, no_lean, PITCH_M, seed, noise_m=0.0005)
    centre_t = p[:, 1] - v[:, 1] * HALF_THICKNESS_M
    return p, links, grouped_medians(centre_t, cKDTree(p[:, [0, 2]]).query_ball_point(p[:, [0, 2]], 0.005))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_two_links_read_as_one_layer_without_thickness_are_split_where_their_plate_centres_step(seed):
    """Its joints' thickness unread (the two sides' views out of register, or one side seen only),
    links 1 and 2 of a straight run in one layer are split at the joint between them: the count as
    the layers read right, the lengths within 2 mm of that reading's (a straight joint is placed by
    where the layers part) and 4 mm of the print's (the layers alone: link 1 75 mm for 40)."""
    p, links, plate_t_m = _straight_run(seed=seed)
    cfg = L.LayersConfig()
    keep = p[:, 2] > cfg.min_height_m
    p, links, plate_t_m = p[keep], links[keep], plate_t_m[keep]
    merged = np.where(links >= 2, links - 1, links)
    read = L._measure_reading(p, merged, merged.astype(np.float64), PRINT_SCALE, cfg, None, merged * PITCH_M)
    assert read.n_links == 2  # the layers alone: their plate centres whole layers, no step to go by
    m = L._measure_reading(p, merged, merged.astype(np.float64), PRINT_SCALE, cfg, None, plate_t_m)
    assert m.n_links == 3, m.points_per_layer
    right = L._measure_reading(p, links, links.astype(np.float64), PRINT_SCALE, cfg, None, plate_t_m)
    assert right.n_links == 3 and np.allclose(m.lengths_pu, right.lengths_pu, atol=0.002 / PRINT_SCALE)
    assert np.allclose(m.lengths_pu, np.array([0.07, 0.04, 0.035, 0.03]) / PRINT_SCALE, atol=0.004 / PRINT_SCALE)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_chain_measured_at_a_count_it_did_not_read_is_split_where_its_plate_centres_step_the_likeliest(seed):
    """Links 1 and 2 of a straight run in one layer, their plate centres stepping by 0.4 of a pitch (a
    Kinect's smoothing and joint play flatten a joint's step: bench seed 31468, 5 links read as 4)
    and no thickness read: the layers count 2, as no step reaches `steps.MIN_STEP_LAYERS`. Measured at
    the 3 a network is sure of (`_at_count`), the layer is split where the centres step, and the
    lengths are the print's within 4 mm (the network's own were 8-20 mm off on such captures). A
    chain with no layer long enough to hold a step gets no count, with the reason."""
    p, links, _ = _straight_run(seed=seed)
    cfg = L.LayersConfig()
    keep = p[:, 2] > cfg.min_height_m
    p, links = p[keep], links[keep]
    merged = np.where(links >= 2, links - 1, links)
    rng = np.random.default_rng(seed)
    plate_t_m = PITCH_M * (merged + 0.4 * (links == 2)) + rng.normal(0.0, 0.0003, len(p))
    m = L._measure_reading(p, merged, merged.astype(np.float64), PRINT_SCALE, cfg, None, plate_t_m)
    assert m.n_links == 2, m.points_per_layer
    at = L._at_count(p, [(merged, plate_t_m / PITCH_M)], m, 3, PRINT_SCALE, cfg, 0)
    assert at.n_links == 3 and at.reason is None
    assert np.allclose(at.lengths_pu, np.array([0.07, 0.04, 0.035, 0.03]) / PRINT_SCALE, atol=0.004 / PRINT_SCALE)
    assert np.mean(at.labels == links) > 0.95  # each point back in its own link's layer, but by the joint
    short = p[:, 2] < 0.07 + 0.02  # the base and a stub of link 1: no plate long enough to step along
    stub = L._measure_reading(
        p[short], merged[short], merged[short].astype(np.float64), PRINT_SCALE, cfg, None, plate_t_m[short]
    )
    none = L._at_count(
        p[short], [(merged[short], plate_t_m[short] / PITCH_M)], stub, stub.n_links + 1, PRINT_SCALE, cfg, 0
    )
    assert none.n_links is None and "steps up where a link" in none.reason
