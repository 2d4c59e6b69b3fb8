"""The one registry of network architectures: for every `NetConfig.arch`, how its network is built,
what it reads and how its outputs become predictions. Where its training samples come from is the
data side's entry in `nets.sample_sources`, kept apart so that loading a network (`predict`) does not
import the dataset stage.

Code in nets asks `architecture(net)` instead of testing architecture names; a new architecture is
one entry here and one in `nets.sample_sources` (`tests/test_nets_registry.py` checks that every
preset resolves through both).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import nn

from spare_twin.errors import SpareTwinError
from spare_twin.nets.blocks import N_CLASSES, SLOTS
from spare_twin.nets.grey_lift import GreyLiftNet
from spare_twin.nets.models import (
    CNNLSTMNet,
    Conv3DNet,
    GeoVoxelNet,
    NaiveCombination,
    PerCountRegressors,
    ProfileNet,
    decode_heads,
    decode_known_count,
    decode_mirrored,
    decode_routed,
)
from spare_twin.nets.presets import NetConfig

#: What a network reads (`Architecture.reads`).
READS = ("views", "posed views", "profile")


@dataclass(frozen=True)
class Architecture:
    """One network architecture and everything the training, evaluation and prediction code needs of it."""

    name: str
    build: Callable[[NetConfig], nn.Module]
    reads: str
    """"views": a stack of images (the rig's 8 views at one time step, or one camera's frames);
    "posed views": the same with their intrinsics, camera-to-world poses and the print scale (the
    network fuses the views through the cameras' geometry); "profile": the chain's profile image,
    which `spare_twin.observe.chain` draws from any posed views."""
    decode: Callable[[nn.Module, NetConfig, dict, torch.Tensor | None], dict]
    """`(model, net, inputs, true_n) -> predictions` (see `models.decode_heads`)."""
    takes_count: bool = False
    """The forward pass reads `n_links`: in training the true count routes the length regressors."""
    needs_count: bool = False
    """It measures lengths for a given count only (the count is an input, not an output)."""
    regresses_padded_slots: bool = False
    """The length loss covers all 7 slots, zero past the count (as the paper's plain regressor), not
    only the slots the true count uses."""
    observed_samples: bool = False
    """Its samples are observed once into the run folder and then held in memory: `train.workers`
    are the observing processes, the loader needs none, and nothing is rendered on the fly."""
    several_datasets: bool = False
    """It trains on several dataset folders at once (their splits concatenated)."""

    def __post_init__(self):
        if self.reads not in READS:
            raise ValueError(f"{self.name}: reads {self.reads!r} is not one of {READS}")


def _paper_net(network: type[nn.Module]) -> Callable[[NetConfig], nn.Module]:
    """A builder of the paper's counter or end-to-end regressor (Conv3D or CNN-LSTM), by task."""

    def build(cfg: NetConfig) -> nn.Module:
        if cfg.task not in ("count", "e2e"):
            raise SpareTwinError(f"net.task: {cfg.arch} supports tasks count and e2e (got {cfg.task})")
        out, key = (N_CLASSES, "count_logits") if cfg.task == "count" else (SLOTS, "lengths")
        return network(cfg, out, key)

    return build


ARCHITECTURES: dict[str, Architecture] = {
    a.name: a
    for a in [
        Architecture("conv3d", _paper_net(Conv3DNet), "views", decode_heads, regresses_padded_slots=True),
        Architecture("cnn_lstm", _paper_net(CNNLSTMNet), "views", decode_heads, regresses_padded_slots=True),
        Architecture(
            "conv3d_per_n",
            PerCountRegressors,
            "views",
            decode_known_count,
            takes_count=True,
            needs_count=True,
        ),
        Architecture("naive", NaiveCombination, "views", decode_routed, takes_count=True),
        Architecture("geo_voxel", GeoVoxelNet, "posed views", decode_heads),
        Architecture("grey_lift", GreyLiftNet, "posed views", decode_heads),
        Architecture(
            "profile",
            ProfileNet,
            "profile",
            decode_mirrored,
            regresses_padded_slots=True,
            observed_samples=True,
            several_datasets=True,
        ),
    ]
}


def architecture(net: NetConfig | str) -> Architecture:
    """The registry entry of `net` (a NetConfig or an architecture name)."""
    name = net if isinstance(net, str) else net.arch
    if name not in ARCHITECTURES:
        raise SpareTwinError(f"net.arch: {name!r} is not one of {', '.join(ARCHITECTURES)}")
    return ARCHITECTURES[name]


def build_model(net: NetConfig) -> nn.Module:
    """A freshly initialised network of `net` (torch's global RNG draws its weights)."""
    return architecture(net).build(net)


def decode(model: nn.Module, net: NetConfig, inputs: dict, true_n: torch.Tensor | None = None) -> dict:
    """Predictions for one batch (see `models.decode_heads` for the keys); `true_n` gives the lengths
    with the count known (``lengths_known``) where the network has lengths."""
    return architecture(net).decode(model, net, inputs, true_n)
