"""Where the pins are: a pin joint is two plates thick.

At a joint the parent's rounded end and the child's overlap around the pin, the child a whole layer
past its parent: seen from one side of the chain's plane the child's face, from the other the
parent's, 6.4 mm (a layer pitch) further apart than the two faces of one plate. That holds however
far joint play leans either link about the pin, so it tells a joint from a plate that its lean cut in
two (which `measure.layers` reads from plate centres, where a lean shifts them by a fraction of a
layer), and it finds a joint where the layers' rounding ran two links into one.

On 15 development captures drawn the bench's way (chain seeds 1,001,000,000 on) the joints of the
chains counted right stood 9.1-13.1 mm thick, the plates between them 3.8-7.1 mm (docs/observe.md).

Only where the chain was seen from both sides of its plane: elsewhere a joint shows no thickness and
`Thickness.excess_layers` says nothing (NaN).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from spare_twin.measure.medians import grouped_medians

#: Points within this of a place (in the plane) say how thick the chain is there.
THICKNESS_RADIUS_M = 0.005
#: ... from at least this many points on each side of the plane.
MIN_SIDE_POINTS = 3
#: A chain whose plates look thicker or thinner than printed by more than this is not read by its
#: thickness: on the development captures the plates looked 4.5-6.9 mm thick (printed 6 mm) where
#: both sides were in register, 9.3 mm on a folded 5-link chain blurred 2.3 mm (RMS) off its fit.
MAX_PLATE_ERROR_M = 0.0025
#: A joint stands about a layer thicker than a plate; one less than this thicker is no joint (a
#: plate cut in two by its lean), and a place along a plate more than this thicker is a joint.
MIN_JOINT_EXCESS_LAYERS = 0.5
#: A layer is looked at for a joint its count missed at up to this many of its points, those farther
#: than this from every other layer's points and from its own joint (their overlaps are two plates thick).
MAX_SCAN_PLACES = 150
SCAN_CLEARANCE_M = 0.010
#: ... and found where at least this many of those places within `THICKNESS_RADIUS_M` of each other
#: stand as thick as a joint.
MIN_THICK_PLACES = 3


def chain_sides(view_t: np.ndarray, min_cosine: float) -> np.ndarray:
    """(N,) +1 / -1 for points seen squarely from the +t / -t side of the plane (the t component of
    the unit direction to their cameras beyond `min_cosine`), 0 edge-on."""
    return np.where(view_t > min_cosine, 1, np.where(view_t < -min_cosine, -1, 0))


#: A capture whose faces seen from one side of the plane are fewer than this share of all its faces
#: seen squarely was seen from the other side only (`seen_from_side`).
ONE_SIDE_SHARE = 0.05


def seen_from_side(view_t: np.ndarray, min_cosine: float) -> int:
    """-1 / +1 where the points were seen from the -t / +t side of the plane only (`ONE_SIDE_SHARE`),
    0 where from both or neither (`chain_sides`)."""
    side = chain_sides(view_t, min_cosine)
    faces = int(np.count_nonzero(side))
    if faces == 0:
        return 0
    if np.count_nonzero(side > 0) < ONE_SIDE_SHARE * faces:
        return -1
    if np.count_nonzero(side < 0) < ONE_SIDE_SHARE * faces:
        return 1
    return 0


class Thickness:
    """How thick the chain stands across its plane (t) at places in the plane (s, z), from its points
    seen from either side."""

    def __init__(self, sz_m: np.ndarray, t_m: np.ndarray, side: np.ndarray, pitch_m: float):
        self.pitch_m = pitch_m
        self.sides = [(cKDTree(sz_m[side == s]), t_m[side == s]) for s in (1, -1)]
        self.plate_m = self._typical(sz_m[side == 1])

    def holds(self, plate_thickness_m: float) -> bool:
        """Whether a plate stands as thick as it was printed, within `MAX_PLATE_ERROR_M`: two sides'
        views further out of register than that (or a chain folded over itself) make any place look
        thicker or thinner than it is, and their thickness says nothing of the joints."""
        return bool(np.isfinite(self.plate_m) and abs(self.plate_m - plate_thickness_m) <= MAX_PLATE_ERROR_M)

    def at(self, places_sz_m: np.ndarray) -> np.ndarray:
        """(K,) front-to-back thickness (metres) at K places, NaN where a side has too few points."""
        out = np.full(len(places_sz_m), np.nan)
        if len(places_sz_m) == 0 or min(len(t) for _, t in self.sides) < MIN_SIDE_POINTS:
            return out
        medians = []
        for tree, t in self.sides:
            near = tree.query_ball_point(places_sz_m, THICKNESS_RADIUS_M)
            seen = np.flatnonzero(np.fromiter(map(len, near), np.int64, len(near)) >= MIN_SIDE_POINTS)
            side = np.full(len(places_sz_m), np.nan)
            side[seen] = grouped_medians(t, [near[i] for i in seen])
            medians.append(side)
        return medians[0] - medians[1]

    def excess_layers(self, places_sz_m: np.ndarray) -> np.ndarray:
        """(K,) how much thicker than one plate (in layer pitches) the chain is at K places: about 1 at
        a joint, 0 along a plate; NaN where unseen."""
        return (self.at(places_sz_m) - self.plate_m) / self.pitch_m

    def _typical(self, front_sz_m: np.ndarray) -> float:
        """One plate's thickness as seen: the plates' mode among the thicknesses at the front points'
        places (`_lower_mode`). It holds the plates' own thickness and any offset between the two
        sides' views (a sweep's registration drifts along its arc)."""
        if len(front_sz_m) == 0:
            return np.nan
        step = max(1, len(front_sz_m) // 400)
        values = self.at(front_sz_m[::step])
        values = values[np.isfinite(values)]
        return _lower_mode(values, self.pitch_m) if len(values) else np.nan


#: The plates' mode is sought within this of a thickness: a joint's overlap stands a pitch (6.4 mm)
#: thicker, well outside it.
PLATE_MODE_WINDOW_M = 0.002


def _lower_mode(thickness_m: np.ndarray, pitch_m: float) -> float:
    """The mode of the thinner of the two kinds of place, plates and joints' overlaps a pitch thicker:
    a median window moved from the lower quartile until it rests. The median of all places is not
    it: on a chain of short links the overlaps are nearly half the places and the median falls
    between the two modes (bench seed 31697's real capture: 8.3 mm against a plate mode of 5.6 mm,
    every joint then a layer too thin and its link merged as a cut plate)."""
    window = min(PLATE_MODE_WINDOW_M, pitch_m / 3)
    centre = float(np.percentile(thickness_m, 25))
    for _ in range(20):
        near = thickness_m[np.abs(thickness_m - centre) <= window]
        moved = float(np.median(near))
        if abs(moved - centre) < 1e-5:
            break
        centre = moved
    return centre


def joint_excess_layers(thickness: Thickness, starts: np.ndarray) -> np.ndarray:
    """(n,) the excess thickness (layers) at joints 1..n of a fitted chain whose plates start at
    `starts` ((n + 1, 2), `measure.fit.plate_segments`): about one layer at a pin, where two plates
    overlap, about none where one plate was cut in two; NaN where unseen."""
    return thickness.excess_layers(starts[1:])


def hidden_joint(thickness: Thickness, layers: list[np.ndarray], starts: np.ndarray) -> tuple[int, np.ndarray] | None:
    """(layer j, place (2,)) of the first layer that stands as thick as a joint (more than
    `MIN_JOINT_EXCESS_LAYERS`) somewhere away from every other layer's points (a joint with its
    parent or child, or another plate crossing it, is two plates thick too) and from its own joint:
    two links whose layers the rounding ran into one. None where there is none."""
    trees = [cKDTree(own) if len(own) else None for own in layers]
    for j, own in enumerate(layers):
        if len(own) == 0:
            continue
        places = own[:: max(1, len(own) // MAX_SCAN_PLACES)]
        if j > 0:
            places = places[np.linalg.norm(places - starts[j], axis=1) > SCAN_CLEARANCE_M]
        for k, tree in enumerate(trees):
            if k != j and tree is not None and len(places):
                places = places[tree.query(places)[0] > SCAN_CLEARANCE_M]
        thick = places[thickness.excess_layers(places) > MIN_JOINT_EXCESS_LAYERS]
        if len(thick) < MIN_THICK_PLACES:
            continue
        # a pin's overlap is a disc of the plates' width: thick at several places around it, where
        # noise makes a single place thick
        around = cKDTree(thick).query_ball_point(thick, THICKNESS_RADIUS_M, return_length=True)
        if around.max() >= MIN_THICK_PLACES:
            centre = thick[int(np.argmax(around))]
            return j, np.median(thick[np.linalg.norm(thick - centre, axis=1) <= THICKNESS_RADIUS_M], axis=0)
    return None
