"""A layer's stray fragments given to the layer around them (step 1 of `measure.layers`).

A link is one plate, so its layer is one piece in the chain's plane. A structured-light sensor's
noise of several millimetres across the plane leaves a few of one plate's points read a layer off
where the neighbourhood medians (`layers.layer_readings`) hold too few points to outvote it: a thin
column seen mostly from one side, a plate's edge. They lie apart from their layer's own plate, in
small pieces among another layer's points, and the fit holds every point to its own layer's plate:
on bench seed 30601 (2 links, Kinect v1) 34 of the base column's points read as link 1, in pieces of
16 and 18 points 5-10 cm below link 1's plate, and the fit laid link 1 down along the base (0.93
paper units for 0.53, E_L 0.40).

`adopt_fragments` gives such a piece to the layer its neighbours are in: a piece of a layer that
is not the layer's largest, too small to count as a piece of its own (what `layers.split_layers`
counts apart), at least `MIN_FRAGMENT_CLEARANCE_M` from the layer's largest piece, whose neighbours
in the plane (within `radius_m`, outside the piece) mostly lie in one layer next to its own, or,
where a plate crosses in front of another layers apart, between the two (`_crossing_layer`).
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

#: A layer's piece counts apart from this many of its points, or this share of them
#: (`layers.split_layers`); a smaller one that is not the layer's largest is a fragment.
MIN_PIECE_POINTS = 15
MIN_PIECE_SHARE = 0.1
#: A fragment joins the layer next to its own that holds more than this share of its neighbours.
MIN_NEIGHBOUR_SHARE = 0.5
#: ... where it lies at least this far from its layer's largest piece: nearer, where two plates
#: overlap at a joint, either layer may hold a point (`layers.layer_readings`), and the fit holds it.
MIN_FRAGMENT_CLEARANCE_M = 0.012
#: ... or, where it lies among neither its own layer nor mostly one next to it, to the nearer (in its
#: plate centre) of a lower and a higher layer that each hold at least this share of its neighbours:
#: where a plate crosses in front of another layers apart, readings that mix the two faces put plate
#: centres between them, in the layers between (`_crossing_layer`). Rig view of bench seed 31004 (3
#: links, the last crossing in front of the base): 20 points at t = 14 mm between the base (0) and
#: link 3 (19.2 mm) read as link 2's layer, 5 cm from link 2's plate; the fit stretched link 2 to 76
#: mm (34 mm) to hold them, and the checks went on to 1 link at 12 mm RMS: no answer.
MIN_CROSSING_SHARE = 0.25


def pieces(sz_m: np.ndarray, radius_m: float) -> np.ndarray:
    """(M,) int64: which piece each of the (M, 2) in-plane points is in, pieces joined within `radius_m`."""
    if len(sz_m) < 2:
        return np.zeros(len(sz_m), np.int64)
    pairs = cKDTree(sz_m).query_pairs(radius_m, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(sz_m), len(sz_m)))
    return connected_components(graph, directed=False)[1].astype(np.int64)


def counted_pieces(sizes: np.ndarray, layer_points: int) -> int:
    """How many of a layer's pieces (their `sizes`) are large enough to count apart."""
    return int((sizes >= max(MIN_PIECE_POINTS, MIN_PIECE_SHARE * layer_points)).sum())


def adopt_fragments(
    sz_m: np.ndarray, labels: np.ndarray, centre_layers: np.ndarray, radius_m: float, min_points: int
) -> tuple[np.ndarray, np.ndarray]:
    """(labels, centre_layers) with each layer's fragments moved to the layer next to theirs that
    most of their neighbours are in (see the module doc); a moved point's plate centre moves by
    the same whole layers. `sz_m` (N, 2) in the plane, `labels` (N,) int64, `centre_layers` (N,);
    fragments of fewer than `min_points` are noise, not a plate's piece (`LayersConfig.min_layer_points`),
    and stay: the fit's robust loss bounds what a stray point pulls, and such a point given to a plate
    stretches it to hold it (bench seed 30530: two points near the table moved into the last link's layer
    lengthened it by 5 mm)."""
    labels, centre_layers = labels.copy(), centre_layers.astype(np.float64).copy()
    tree = cKDTree(sz_m)
    moves: list[tuple[np.ndarray, int]] = []
    for k in np.unique(labels):
        mine = np.flatnonzero(labels == k)
        piece = pieces(sz_m[mine], radius_m)
        sizes = np.bincount(piece)
        small = max(MIN_PIECE_POINTS, MIN_PIECE_SHARE * len(mine))
        largest = cKDTree(sz_m[mine[piece == int(sizes.argmax())]])
        for f in np.flatnonzero((sizes < small) & (sizes >= min_points)):
            if f == int(sizes.argmax()):
                continue
            members = mine[piece == f]
            if largest.query(sz_m[members])[0].min() < MIN_FRAGMENT_CLEARANCE_M:
                continue
            near = np.unique(np.concatenate(tree.query_ball_point(sz_m[members], radius_m)))
            others = labels[np.setdiff1d(near, members)]
            if len(others) == 0:
                continue
            values, counts = np.unique(others, return_counts=True)
            j = int(values[counts.argmax()])
            if abs(j - int(k)) == 1 and counts.max() > MIN_NEIGHBOUR_SHARE * len(others):
                moves.append((members, j))
                continue
            j = _crossing_layer(values, counts, int(k), float(np.median(centre_layers[members])))
            if j is not None:
                moves.append((members, j))
    for members, j in moves:  # all read off the labels as they came
        centre_layers[members] += j - labels[members]
        labels[members] = j
    return labels, centre_layers


def _crossing_layer(values: np.ndarray, counts: np.ndarray, k: int, centre_layer: float) -> int | None:
    """Where a fragment of layer `k` (its median plate centre `centre_layer`, in layers) lies where
    plates of a lower and a higher layer cross in the plane (its neighbours' layers `values`, each
    holding `counts` of them: none of its own, a lower and a higher one each at least
    `MIN_CROSSING_SHARE`), the one of those nearer its plate centre; else None."""
    if k in values:
        return None
    crossing = values[counts >= MIN_CROSSING_SHARE * counts.sum()]
    if not ((crossing < k).any() and (crossing > k).any()):
        return None
    return int(crossing[np.argmin(np.abs(crossing - centre_layer))])
