"""The layers' comb followed along the chain: links that lean out of their layers.

A printed pin joint lets its link lean 1-4 deg out of the chain's plane, and a link carries its
parent's lean on, so the leans add up along the chain: link k's plate lies millimetres off k layer
pitches and slants across them, and the chain's layers no longer sit on one 6.4 mm comb (bench seed
30052: five links whose plates lay 0.8 pitch apart were read as three). What holds is local: near
any point, the plates there (a link, and its parent and child where they meet) are whole pitches
apart.

So the comb's zero is read locally and followed from the base: each point's local phase is that of
the plate centres within `LOCAL_COMB_RADIUS_M` in the plane (`layers.layer_readings`' neighbourhood
medians, t across the plane), and it is unwrapped outwards from the base's column, neighbour to
neighbour, nearest first; a point's layer is its plate centre over the pitch from that zero, rounded.
A lean or the plane's direction a little off move the zero smoothly, a joint moves it by a whole pitch,
which the rounding counts. Across a gap in the points (a link the sensor missed) the zero goes on
from the nearest point reached.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

#: The plane neighbourhood whose plate centres give a point's local comb phase.
LOCAL_COMB_RADIUS_M = 0.012


def _wrapped(x: np.ndarray | float, pitch_m: float):
    """`x` (metres across the plane) moved by whole pitches into [-pitch / 2, pitch / 2)."""
    return (x + pitch_m / 2) % pitch_m - pitch_m / 2


def local_comb_layers(
    sz_m: np.ndarray, centre_t_m: np.ndarray, column: np.ndarray, pitch_m: float, step_m: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """(labels, centre_layers) of N points from their (N, 2) positions in the plane, their (N,) plate
    centres across it and the (N,) mask of the base's column: each point's integer layer
    and its plate centre in layers from the local zero. None where the column holds no point."""
    n = len(centre_t_m)
    if not column.any():
        return None
    wave = 2 * np.pi / pitch_m
    phasor = np.exp(1j * wave * centre_t_m)
    tree = cKDTree(sz_m)
    near = tree.query_pairs(LOCAL_COMB_RADIUS_M, output_type="ndarray")
    rows = np.concatenate([near[:, 0], near[:, 1], np.arange(n)])
    cols = np.concatenate([near[:, 1], near[:, 0], np.arange(n)])
    local = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)).tocsr() @ phasor
    local_zero = np.angle(local) / wave  # the comb's phase near each point, in [-pitch / 2, pitch / 2)
    # the base link is layer 0 by definition: the column's phase, moved to the pitch its points sit at
    column_zero = float(np.angle(phasor[column].sum())) / wave
    column_zero += pitch_m * np.rint((np.median(centre_t_m[column]) - column_zero) / pitch_m)
    # Dijkstra outwards over the points within a step of each other (scipy's, in C: a heap in Python
    # took a quarter of `measure_layers`): each point's zero unwrapped against the point it is reached
    # from. A tiny weight on every pair keeps coincident points joined (a sparse matrix may drop a zero).
    pairs = tree.sparse_distance_matrix(tree, step_m, output_type="coo_matrix").tocsr()
    pairs.data += 1e-12
    zero = np.full(n, np.nan)
    sources, ref = np.flatnonzero(column), None
    while True:
        dist, parent, _ = dijkstra(pairs, indices=sources, min_only=True, return_predecessors=True)
        for i in np.argsort(dist, kind="stable")[: int(np.isfinite(dist).sum())]:
            if not np.isnan(zero[i]):
                continue
            base = (column_zero if ref is None else zero[ref]) if parent[i] < 0 else zero[parent[i]]
            zero[i] = base + _wrapped(local_zero[i] - base, pitch_m)
        waiting = np.flatnonzero(np.isnan(zero))
        if not len(waiting):
            break
        # a gap in the points (a link the sensor missed, its shadow): on across it from the nearest
        # point reached, as if the gap were a step
        reached = np.flatnonzero(~np.isnan(zero))
        gap, nearest = cKDTree(sz_m[reached]).query(sz_m[waiting])
        k = int(np.argmin(gap))
        sources, ref = np.array([waiting[k]]), int(reached[nearest[k]])
    centres = (centre_t_m - zero) / pitch_m
    labels = np.rint(centres).astype(np.int64)
    return labels, centres
