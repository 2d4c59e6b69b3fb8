"""Where each architecture's samples come from, for training and evaluation (`nets.train`,
`nets.evaluate`): the data side of `nets.registry`, kept apart from it because it imports the dataset
stage (trimesh, networkx, rtree: about 1 s of a new process), which loading a network for `predict`
does not need."""

from __future__ import annotations

from collections.abc import Callable

from spare_twin.nets.data import stored_samples
from spare_twin.nets.presets import NetConfig
from spare_twin.nets.profile_train import profile_samples
from spare_twin.nets.registry import architecture

#: By architecture name, `(data_dirs, split, net, train, run_dir, progress) -> Dataset` of
#: docs/design.md samples: `train` (a TrainConfig) when training (its read-time augmentation on the
#: train split), None when evaluating; `run_dir`: the run folder, for sources that observe their
#: samples once into it (`Architecture.observed_samples`).
SAMPLE_SOURCES: dict[str, Callable] = {
    "conv3d": stored_samples,
    "cnn_lstm": stored_samples,
    "conv3d_per_n": stored_samples,
    "naive": stored_samples,
    "geo_voxel": stored_samples,
    "grey_lift": stored_samples,
    "profile": profile_samples,
}


def samples_of(net: NetConfig | str) -> Callable:
    """The sample source of `net`'s architecture (a NetConfig or an architecture name); an unknown
    architecture is the registry's one-line error."""
    return SAMPLE_SOURCES[architecture(net).name]
