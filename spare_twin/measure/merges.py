"""Layers that are no link of their own, merged into the layer below (`measure.layers`, step 4): its
parent's points read a layer up (`top_layer_is_stray`), the far end of its parent's plate cut off by
the joint's lean (`is_cut`, `cut_plate`), and a link between joints too short to print
(`unprintable_link`). Each reads one layer and its parent, in the chain's plane (s, z) and across it
(plate centres in layers)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from spare_twin.measure.fit import distance_to_segment, plate_segments
from spare_twin.measure.joints import MIN_JOINT_EXCESS_LAYERS, Thickness
from spare_twin.measure.layers_config import LayersConfig


def unprintable_link(x: np.ndarray, n: int, cfg: LayersConfig) -> int | None:
    """The first link (1..n) that the fit `x` makes shorter than any printable one, or None: between
    two joints `LayersConfig.min_middle_link_m`, the last `LayersConfig.min_last_link_m`. Joint play
    tilts each plate 1-4 degrees about its joint and the tilts add up along the chain: where the
    plates have climbed past half a layer, one plate is cut in two at the half-way mark, and the piece
    read a layer up fits as a link a few mm long (bench seed 30022: 5 links counted 6, a 6 mm link
    between links 1 and 2; 32451: 4 counted 5, a 5 mm last link on the tip of the fourth)."""
    for k in range(1, n):
        if x[1 + k] < cfg.min_middle_link_m:
            return k
    if n > 1 and x[1 + n] < cfg.min_last_link_m:
        return n
    return None


def top_layer_is_stray(x: np.ndarray, layers: list[np.ndarray], centres: np.ndarray, n: int, cfg: LayersConfig) -> bool:
    """Whether the top layer is its parent's points read a layer too high (noise, a pin head), not
    a link: they lie on the parent's plate, and their plate centres (in layers) sit just past the
    half-way mark between the two layers, where the tail of the parent's noise ends, not at n. A
    real link folded back onto a parent of its length lies on its outline too, centred on n."""
    if float(np.median(centres)) >= n - cfg.max_stray_offset:
        return False
    starts, ends = plate_segments(x, n, cfg)
    return bool(share_on_plate(layers[n], starts[n - 1], ends[n - 1], cfg) >= cfg.max_top_inside_parent)


def share_on_plate(sz_m: np.ndarray, start: np.ndarray, end: np.ndarray, cfg: LayersConfig) -> float:
    """The share of points (N, 2) in the plane that lie on the plate from `start` to `end`: within its
    half width and the coverage tolerance of its centre line."""
    return float(np.mean(distance_to_segment(sz_m, start, end) <= cfg.half_width_m + cfg.coverage_tolerance_m))


#: Where a layer's points meet its parent's (within this, in the plane), plate centres that step up
#: by less than this many layers run on from the parent's: one plate tilted out of its layer.
MAX_TILT_STEP_LAYERS = 0.35
TILT_CONTACT_M = 0.009
#: Where a joint reads no thicker than a plate but its layer's plate centres sit this many layers or
#: more above its parent's (median against median), and the layer is at least half a plate wide, the
#: thickness is read again where the two layers meet (their points within `MEETING_M` of each
#: other), not at the fitted joint, and the layer is a link where the chain stands
#: `MIN_MEETING_EXCESS_LAYERS` thicker than a plate there (`is_cut`, `_measure_reading_both`). A fit
#: that puts a joint off its pin reads a plate's thickness there: bench seed 31437's rig view (a 21 mm
#: link before it; the layer 0.99 up, 0.93 layers thicker where the layers meet) merged a link as a
#: cut, 4 links read as 3, and 31427's real capture (1.08 up, 3.3 thicker) 6 as 5. A cut plate's far
#: end can sit most of a layer up where leans add up along the chain, but where it meets its near end
#: it is one plate thick (31424 real: 0.82-0.86 up, -0.04 to -0.06 there, kept as a cut). A sliver is
#: no layer to read (31414's clean render: 38 points, 2.8 mm across, a whole layer above the last
#: link). 0.5 where the layers meet, a joint's own bar, was too low: a fold lays other plates over the
#: meeting places (the stored rig view of 30485, `tests/data/bench_points`: 0.52-0.60, 5 links for 6).
MIN_LINK_RISE_LAYERS = 0.75
MEETING_M = 0.002
MIN_MEETING_EXCESS_LAYERS = 0.75


def is_cut(
    layers: list[np.ndarray],
    centres: list[np.ndarray],
    joint_excess: np.ndarray,
    k: int,
    thickness: Thickness | None,
    half_width_m: float,
    kept: list[int] | None = None,
) -> bool:
    """Whether layer k is its parent's plate cut in two, not a link: where joint k was seen from both
    sides, by its thickness (`measure.joints`: a pin's overlap is a layer thicker than a plate, a cut
    none), and with `kept` (a list) read again where the two layers meet if the layer sits a whole
    layer up (`MIN_LINK_RISE_LAYERS`), a layer kept so added to `kept`; elsewhere by the plate
    centres' step where the two layers meet (`cut_plate`)."""
    excess = joint_excess[k - 1]
    if not np.isfinite(excess) or thickness is None:
        return cut_plate(layers, centres, k)
    if (
        kept is not None
        and excess < MIN_JOINT_EXCESS_LAYERS
        and rise_layers(centres, k) >= MIN_LINK_RISE_LAYERS
        and width_m(layers[k]) >= half_width_m
        and meeting_excess_layers(thickness, layers[k - 1], layers[k], excess) >= MIN_MEETING_EXCESS_LAYERS
    ):
        kept.append(k)
        return False
    return bool(excess < MIN_JOINT_EXCESS_LAYERS)


def rise_layers(centres: list[np.ndarray], k: int) -> float:
    """How far (in layers) layer k's plate centres sit above its parent's, median against median."""
    if min(len(centres[k]), len(centres[k - 1])) == 0:
        return 0.0
    return float(np.median(centres[k]) - np.median(centres[k - 1]))


def width_m(sz_m: np.ndarray) -> float:
    """The extent of points (N, 2) in the plane across their main direction: a plate's width or more
    where a plate was seen, a sliver's thickness where a sliver was."""
    if len(sz_m) < 3:
        return 0.0
    centred = sz_m - sz_m.mean(0)
    across = np.linalg.svd(centred, full_matrices=False)[2][1]
    return float(np.ptp(centred @ across))


def meeting_excess_layers(thickness: Thickness, parent: np.ndarray, top: np.ndarray, otherwise: float) -> float:
    """The chain's excess thickness (layers, `Thickness.excess_layers`) where `top`'s points meet
    `parent`'s, their median; `otherwise` where they do not meet or it is unseen there."""
    if len(parent) == 0:
        return otherwise
    places = top[cKDTree(parent).query(top, distance_upper_bound=MEETING_M)[0] < MEETING_M]
    excess = thickness.excess_layers(places) if len(places) else np.zeros(0)
    excess = excess[np.isfinite(excess)]
    return float(np.median(excess)) if len(excess) else otherwise


def cut_plate(layers: list[np.ndarray], centres: list[np.ndarray], k: int) -> bool:
    """Whether layer k (above layer 1) is the far end of its parent's plate, tilted out of its layer by
    the joint's play, not a link. A printed pin joint lets a link lean 1-4 deg out of the chain's
    plane about its own joint: a 54 mm link's tip ends 3-4 mm (half a layer or more) off its layer,
    and the rounding cuts the plate in two (bench seed 30009, 4 links counted 5, at the top; seed
    30057, 4 counted 5, the second link cut). A real link meets its parent at a joint a whole layer
    up: where the two layers' points meet, their plate centres step by about one layer; a tilted
    plate's run on across the half-way mark, a step of a fraction."""
    top, parent = layers[k], layers[k - 1]
    if min(len(top), len(parent)) < 5:
        return False
    near_parent = cKDTree(parent).query(top, distance_upper_bound=TILT_CONTACT_M)[0] < TILT_CONTACT_M
    near_top = cKDTree(top).query(parent, distance_upper_bound=TILT_CONTACT_M)[0] < TILT_CONTACT_M
    if min(near_parent.sum(), near_top.sum()) < 5:
        return False
    step = float(np.median(centres[k][near_parent]) - np.median(centres[k - 1][near_top]))
    return step < MAX_TILT_STEP_LAYERS
