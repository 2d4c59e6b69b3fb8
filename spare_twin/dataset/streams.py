"""Which sequences each data-loader stream renders, for the datasets rendered on the fly
(`dataset.torch_data`, `dataset.synthetic`); apart from both so that the synthetic rig's description
(`observe.canonical` reads it) does not import the renderer."""

from __future__ import annotations


def stream_indices(rank: int, world_size: int, worker: int, workers: int, sequences: int | None):
    """The sequence numbers (0-based) that data-loader `worker` of `workers` in process `rank` of `world_size`
    renders: stream s = rank + world_size * worker of S = world_size * workers takes s, s + S, s + 2S, ...
    below `sequences` (None: endless). The streams are disjoint and cover 0 .. sequences - 1."""
    k, step = rank + world_size * worker, world_size * workers
    while sequences is None or k < sequences:
        yield k
        k += step
