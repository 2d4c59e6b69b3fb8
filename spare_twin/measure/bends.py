"""Where the last layer's points bend in the chain's plane: two links the layers' rounding ran into one.

A link is a straight plate, so a layer whose points two straight plates meeting at a point hold
far closer than its one plate holds two links, whatever their plate centres across the plane say.
Where the layers do not part two links (their step across the plane flattened by a sensor's
smoothing and joint play, a dark last link returning few points of its own) and the chain bends
at the joint between them, the one plate fitted to both leaves the bent part outside it.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from spare_twin.measure.fit import distance_to_segment

#: A layer whose points lie outside its plate by at most this (RMS) is straight enough: on
#: well-fitted layers 0.2-0.45 mm.
MIN_BENT_RMS_M = 0.0005
#: Two plates hold its points at most this share of one plate's RMS ...
MAX_TWO_PLATES_SHARE = 0.5
#: ... the bend at least this far from either end of the layer's plate: the points of a joint's
#: overlap with its parent's or child's plate, a layer's noise there, bent a 2 mm noisy synthetic
#: chain's link 1 10 mm from its joint (`test_noise_shear_and_sides_out_of_register`) ...
END_CLEARANCE_M = 0.015
#: ... turning the chain by at least this (degrees) and at most this: a child folded back over its
#: parent overlaps it in the plane a layer up, where the layers part them (bench seed 31560's clean
#: render, a 1-link chain whose plane was read a few degrees off, its layer 28 mm wide: two plates
#: folded 160 deg held it at 0.5 mm against one plate's 2.2) ...
MIN_BEND_DEG = 10.0
MAX_BEND_DEG = 90.0
#: ... with at least this many of the layer's points on each side of it, and at least this share on
#: the near side: the layer is its own link first, its child's the bent far part (31626, a 1-link
#: chain: 15 points of 204 by its joint, off the plate, read as a bend; 31622 likewise with 61 of 674).
MIN_SIDE_POINTS = 15
MIN_NEAR_SHARE = 0.25


def _outside(q: np.ndarray, segments: list[tuple[np.ndarray, np.ndarray]], hw: float) -> np.ndarray:
    """(M,) each point's distance outside the nearest of the plates (half width `hw`) on `segments`."""
    d = np.min([distance_to_segment(q, a, b) for a, b in segments], axis=0)
    return np.maximum(d - hw, 0.0)


def beyond_bend(sz_m: np.ndarray, start: np.ndarray, bend: np.ndarray, far: np.ndarray) -> np.ndarray:
    """(N,) bool: the points nearer the plate from `bend` to `far` than the one from `start` to `bend`."""
    return distance_to_segment(sz_m, bend, far) < distance_to_segment(sz_m, start, bend)


def bent_layer(
    layers_sz_m: list[np.ndarray], starts: np.ndarray, ends: np.ndarray, half_width_m: float
) -> tuple[int, np.ndarray, np.ndarray] | None:
    """(layer n, the bend (2,) in the plane, the far end (2,) of the plate beyond it) where the last
    layer's points two plates meeting at a bend hold at most `MAX_TWO_PLATES_SHARE` as loosely (RMS
    outside) as one plate, and one plate leaves them more than `MIN_BENT_RMS_M` out; else None. Both
    are fitted to the layer's points alone, from its plate in the chain (`starts[n]` to `ends[n]`,
    `measure.fit.plate_segments`), their ends free: a chain fitted with two links in one layer puts
    the joints either side of it off their pins. The last layer only: the measurement's own failure
    there is a short or dark last link with no layer of its own, and read on every layer, the bends
    the noise and the joints' overlaps put in a layer between two others split synthetic chains
    read right (tests `test_layers`, `test_fragments`)."""
    j = len(layers_sz_m) - 1
    q, a, b = layers_sz_m[j], starts[j], ends[j]
    if j < 1 or len(q) < 2 * MIN_SIDE_POINTS or float(np.linalg.norm(b - a)) < 2 * END_CLEARANCE_M:
        return None
    one = _plates(q, [a, b], half_width_m)
    if one is None or one[1] <= MIN_BENT_RMS_M:
        return None
    a, b = one[0]
    bends = [_plates(q, [a, a + u * (b - a), b], half_width_m) for u in (0.25, 0.5, 0.75)]
    bends = [bend for bend in bends if bend is not None]
    if not bends:
        return None
    (_, c, far), two = min(bends, key=lambda bend: bend[1])
    return (j, c, far) if two <= MAX_TWO_PLATES_SHARE * one[1] else None


def _plates(q: np.ndarray, corners: list[np.ndarray], hw: float):
    """(corners, RMS outside) of the plates along the polyline through `corners` (2 or 3 points)
    holding `q` closest, every corner free among the points; None where a plate comes out shorter
    than `END_CLEARANCE_M`, a bend turns by less than `MIN_BEND_DEG` or more than `MAX_BEND_DEG`, or
    leaves fewer than `MIN_SIDE_POINTS` on a side or `MIN_NEAR_SHARE` on its near side."""
    k = len(corners)

    def residuals(x):
        c = x.reshape(k, 2)
        return _outside(q, [(c[i], c[i + 1]) for i in range(k - 1)], hw)

    # the corners stay among the layer's points: a bend run off along the plate leaves two plates
    # over one, as close as one
    lo, hi = np.tile(q.min(0) - hw, k), np.tile(q.max(0) + hw, k)
    x0 = np.clip(np.concatenate(corners), lo + 1e-6, hi - 1e-6)
    res = least_squares(residuals, x0, bounds=(lo, hi), x_scale=0.01, loss="soft_l1", f_scale=0.002, max_nfev=200)
    c = res.x.reshape(k, 2)
    pieces = np.diff(c, axis=0)
    if np.linalg.norm(pieces, axis=1).min() < END_CLEARANCE_M:
        return None
    if k == 3:
        first, second = pieces
        cos = first @ second / (np.linalg.norm(first) * np.linalg.norm(second))
        if not MIN_BEND_DEG <= np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))) <= MAX_BEND_DEG:
            return None
        beyond = beyond_bend(q, *c)
        if min(beyond.sum(), (~beyond).sum()) < MIN_SIDE_POINTS or (~beyond).sum() < MIN_NEAR_SHARE * len(q):
            return None
    return list(c), float(np.sqrt(np.mean(res.fun**2)))
