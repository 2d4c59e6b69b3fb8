"""Building blocks the networks share: the input normalisation, the 3D CNN over a world-frame grid, the flattening FC
layer and the multi-task heads (count logits, 7-slot lengths in paper units, joint angles)."""

from __future__ import annotations

import torch
from torch import nn

from spare_twin.nets.presets import NetConfig

N_CLASSES = 6
SLOTS = 7
#: A chain the label distribution makes typical (base ~1.6, links ~0.5 paper units): the lengths head
#: starts there, not at 0, else the first epoch is spent learning the mean and swamps the count loss.
TYPICAL_LENGTHS_PU = (1.6, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5)
#: Channels the voxel CNN squeezes to before flattening.
SQUEEZED_CHANNELS = 32


class InputNorm(nn.Module):
    """(x - mean) / std with constants measured on the training data, kept in the state_dict so a
    checkpoint carries its own normalisation."""

    def __init__(self):
        super().__init__()
        self.register_buffer("mean", torch.zeros(()))
        self.register_buffer("std", torch.ones(()))

    def forward(self, x):
        return (x - self.mean) / self.std


def time_bin_frames(n_frames: int, bins: int) -> torch.Tensor:
    """Indices of `bins` evenly spaced frames of `n_frames` (first and last included): the frames a
    temporal voxel network puts into its grid's channels."""
    return torch.linspace(0, n_frames - 1, bins).round().long()


def _conv_bn_relu(cin: int, cout: int, stride: int = 1) -> list[nn.Module]:
    return [nn.Conv3d(cin, cout, 3, stride=stride, padding=1, bias=False), nn.BatchNorm3d(cout), nn.ReLU(inplace=True)]


def voxel_cnn(cin: int, channels: tuple[int, ...], stem: bool = True) -> nn.Sequential:
    """Conv blocks over a (B, cin, Z, Y, X) grid: with `stem`, a full-resolution convolution to
    channels[0]; then per further entry a stride-2 block (halving every axis) and a convolution; then
    a 1x1 squeeze. Without `stem` the first stride-2 block reads the `cin` input channels directly
    (inputs that are already features, where a full-resolution layer would cost most of the net)."""
    layers: list[nn.Module] = []
    if stem:
        layers += _conv_bn_relu(cin, channels[0])
        cin = channels[0]
    for c in channels[1:]:
        layers += _conv_bn_relu(cin, c, stride=2) + _conv_bn_relu(c, c)
        cin = c
    # position matters (heights, extents), so the features are squeezed and flattened, never pooled
    layers += [nn.Conv3d(cin, SQUEEZED_CHANNELS, 1), nn.ReLU(inplace=True)]
    return nn.Sequential(*layers)


def voxel_fc(cells: tuple[int, int, int], halvings: int, fc_hidden: int, dropout: float) -> nn.Sequential:
    """Flatten the squeezed grid (`cells` x, y, z halved `halvings` times) into `fc_hidden` features."""
    nx, ny, nz = cells
    for _ in range(halvings):
        nx, ny, nz = (nx + 1) // 2, (ny + 1) // 2, (nz + 1) // 2
    return nn.Sequential(
        nn.Flatten(),
        nn.Linear(SQUEEZED_CHANNELS * nx * ny * nz, fc_hidden),
        nn.ReLU(inplace=True),
        nn.Dropout(dropout),
    )


def task_heads(cfg: NetConfig, angles: bool) -> nn.ModuleDict:
    """Linear heads on the FC features for `cfg.task`: ``count_logits`` (6), ``lengths`` (7 slots,
    paper units) and, with `angles`, ``angles`` (6, rad)."""
    heads = nn.ModuleDict()
    if cfg.task in ("count", "multitask"):
        heads["count_logits"] = nn.Linear(cfg.fc_hidden, N_CLASSES)
    if cfg.task in ("lengths", "e2e", "multitask"):
        heads["lengths"] = nn.Linear(cfg.fc_hidden, SLOTS)
        with torch.no_grad():
            heads["lengths"].bias.copy_(torch.tensor(TYPICAL_LENGTHS_PU))
    if angles:
        heads["angles"] = nn.Linear(cfg.fc_hidden, N_CLASSES)
    return heads
