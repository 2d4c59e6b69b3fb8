"""The networks: the paper's Conv3D and CNN-LSTM baselines, the per-count length regressors and their
naive combination, the end-to-end regressor, the geometry-aware voxel-fusion network (depth), the
yaw-free profile network; the grey lifting network lives in grey_lift.py.

Every network takes the docs/design.md sample fields as keyword tensors and returns a dict with any of
``count_logits`` (B, 6), ``lengths`` (B, 7, paper units) and ``angles`` (B, 6, rad). `decode` turns
those into predictions with the paper's rules (see metrics.py). Which network an architecture name
builds, and which decoder reads it, is the registry's (`spare_twin.nets.registry`).
"""

from __future__ import annotations

import torch
from torch import nn

from spare_twin.nets.blocks import (
    N_CLASSES,
    SLOTS,
    TYPICAL_LENGTHS_PU,
    InputNorm,
    task_heads,
    time_bin_frames,
    voxel_cnn,
    voxel_fc,
)
from spare_twin.nets.geometry import voxelize
from spare_twin.nets.presets import NetConfig

#: ProfileNet's convolutions that halve the resolution (64 x 80 -> 8 x 10 with the preset's five).
PROFILE_STRIDES = (0, 1, 3)
#: The profile network's layer histogram spans t = -LAYER_RANGE..LAYER_RANGE layers (`NetConfig.layer_bins`):
#: links 1..6 lie at 1..6, or at -1..-6 where the profile could not tell the chain's sign.
LAYER_RANGE = 7.5


def paper_head(in_features: int, out: int, hidden: int, dropout: float) -> nn.Sequential:
    """FC `hidden` ReLU, FC `hidden` linear, then `out` linear outputs (the paper's heads)."""
    return nn.Sequential(
        nn.Linear(in_features, hidden),
        nn.ReLU(inplace=True),
        nn.Dropout(dropout),
        nn.Linear(hidden, hidden),
        nn.Linear(hidden, out),
    )


class Conv3DTrunk(nn.Module):
    """Conv3d blocks over (stack, H, W). The first block strides 2 in space (and in time for 100-frame
    stacks) to keep CPU cost sane; depth-wise pooling stops once the stack is collapsed."""

    def __init__(self, cfg: NetConfig):
        super().__init__()
        layers, cin, d = [], 1, cfg.frames
        for i, c in enumerate(cfg.channels):
            st = ((2 if (cfg.mode == "tmp" and d >= 4) else 1), 2, 2) if i == 0 else 1
            layers += [nn.Conv3d(cin, c, 3, stride=st, padding=1, bias=False), nn.BatchNorm3d(c), nn.ReLU(inplace=True)]
            if i == 0:
                d = (d + 1) // 2 if st[0] == 2 else d
            if i < len(cfg.channels) - 1:
                pd = 2 if d >= 2 and i > 0 else 1
                layers.append(nn.MaxPool3d((pd, 2, 2), ceil_mode=True))
                d = -(-d // pd)
            cin = c
        layers.append(nn.AdaptiveAvgPool3d((1, 3, 4)))
        self.net = nn.Sequential(*layers)
        self.out_features = cfg.channels[-1] * 12

    def forward(self, x):  # x (B, F, H, W)
        return self.net(x.unsqueeze(1)).flatten(1)


class FrameCNN(nn.Module):
    """2D CNN shared by every view / frame -> a `frame_features` embedding."""

    def __init__(self, cfg: NetConfig):
        super().__init__()
        layers, cin = [], 1
        for i, c in enumerate(cfg.channels):
            layers += [
                nn.Conv2d(cin, c, 3, stride=2 if i == 0 else 1, padding=1, bias=False),
                nn.BatchNorm2d(c),
                nn.ReLU(inplace=True),
            ]
            if i < len(cfg.channels) - 1:
                layers.append(nn.MaxPool2d(2, ceil_mode=True))
            cin = c
        layers += [
            nn.AdaptiveAvgPool2d((3, 4)),
            nn.Flatten(),
            nn.Linear(cfg.channels[-1] * 12, cfg.frame_features),
            nn.ReLU(inplace=True),
        ]
        self.net = nn.Sequential(*layers)

    def forward(self, x):  # (N, H, W)
        return self.net(x.unsqueeze(1))


class Conv3DNet(nn.Module):
    """The paper's Conv3D network: counter (6 logits) or end-to-end / length regressor (`out` slots)."""

    def __init__(self, cfg: NetConfig, out: int, key: str):
        super().__init__()
        self.norm = InputNorm()
        self.trunk = Conv3DTrunk(cfg)
        self.head = paper_head(self.trunk.out_features, out, cfg.fc_hidden, cfg.dropout)
        self.key = key

    def forward(self, x, **_):
        return {self.key: self.head(self.trunk(self.norm(x)))}


class CNNLSTMNet(nn.Module):
    """The paper's CNN-LSTM counter: a shared CNN per view / frame, an LSTM (64 hidden units) over the
    sequence, the last hidden state to the count logits."""

    def __init__(self, cfg: NetConfig, out: int = N_CLASSES, key: str = "count_logits"):
        super().__init__()
        self.norm = InputNorm()
        self.cnn = FrameCNN(cfg)
        self.lstm = nn.LSTM(cfg.frame_features, cfg.lstm_hidden, batch_first=True)
        self.head = nn.Sequential(nn.Dropout(cfg.dropout), nn.Linear(cfg.lstm_hidden, out))
        self.key = key

    def forward(self, x, **_):
        B, F, H, W = x.shape
        f = self.cnn(self.norm(x).reshape(B * F, H, W)).reshape(B, F, -1)
        _, (h, _) = self.lstm(f)
        return {self.key: self.head(h[-1])}


def _pad_slots(y: torch.Tensor) -> torch.Tensor:
    return torch.nn.functional.pad(y, (0, SLOTS - y.shape[1]))


class PerCountRegressors(nn.Module):
    """The paper's length regressors: one Conv3D network per link count n, each with n + 1 outputs.
    A sample goes through the network of its (known or predicted) count only."""

    def __init__(self, cfg: NetConfig):
        super().__init__()
        self.nets = nn.ModuleList(Conv3DNet(cfg, n + 1, "lengths") for n in range(1, N_CLASSES + 1))

    def forward(self, x, n_links=None, **_):
        if n_links is None:
            raise ValueError("per-count regressors need n_links (known or predicted)")
        out = x.new_zeros(x.shape[0], SLOTS)
        for n in torch.unique(n_links).tolist():
            sel = n_links == n
            out[sel] = _pad_slots(self.nets[n - 1](x[sel])["lengths"])
        return {"lengths": out}


class NaiveCombination(nn.Module):
    """The paper's naive end-to-end system: the counter decides n, that n's regressor measures.
    Trained jointly here (both losses), the regressors routed by the true n during training."""

    def __init__(self, cfg: NetConfig):
        super().__init__()
        self.counter = Conv3DNet(cfg, N_CLASSES, "count_logits")
        self.regressors = PerCountRegressors(cfg)

    def forward(self, x, n_links=None, **_):
        out = self.counter(x)
        route = n_links if n_links is not None else out["count_logits"].argmax(1) + 1
        out.update(self.regressors(x, n_links=route))
        return out


class GeoVoxelNet(nn.Module):
    """This project's network: depth views fused into a world-frame voxel grid (paper units) through
    the known camera geometry, then a small 3D CNN and multi-task heads.

    Because links sit in their own layers along the joint axes, the grid shows each link as a separate
    slab; counting becomes counting slabs and a length becomes a slab's extent, both in the unit E_L
    uses. Temporal input puts `grid.time_bins` evenly spaced frames in separate channels.
    """

    def __init__(self, cfg: NetConfig):
        super().__init__()
        self.cfg = cfg
        self.grid = cfg.grid
        cin = cfg.grid.time_bins if cfg.mode == "tmp" else 1
        self.cnn = voxel_cnn(cin, cfg.channels)
        self.fc = voxel_fc(cfg.grid.cells, len(cfg.channels) - 1, cfg.fc_hidden, cfg.dropout)
        self.heads = task_heads(cfg, angles=cfg.predict_angles and cfg.mode == "mv")

    def grid_of(self, x, K, T_world_camera, print_scale):
        if self.cfg.mode == "tmp":
            bins = self.grid.time_bins
            x = x[:, time_bin_frames(x.shape[1], bins)]
            return voxelize(x, K, T_world_camera, print_scale, self.grid, torch.arange(bins), bins)
        return voxelize(x, K, T_world_camera, print_scale, self.grid)

    def forward(self, x, K=None, T_world_camera=None, print_scale=None, **_):
        if K is None or T_world_camera is None or print_scale is None:
            raise ValueError("geo_voxel needs K, T_world_camera and print_scale")
        with torch.no_grad():
            g = self.grid_of(x, K, T_world_camera, print_scale)
        h = self.fc(self.cnn(g))
        return {k: head(h) for k, head in self.heads.items()}


class ProfileNet(nn.Module):
    """The yaw-free network: the chain's profile image (`spare_twin.observe.profile`, channels x H x W)
    through a small 2D CNN, then count, 7-slot lengths and joint angles (as sin/cos pairs, so angles
    near +-pi are not a discontinuity). Position in the image is height and reach in paper units, so
    the features are flattened, not pooled. One 3x3 convolution per entry of `channels`, halving the
    resolution at `PROFILE_STRIDES`: about 13 M multiply-adds, a few ms on one CPU thread."""

    def __init__(self, cfg: NetConfig):
        super().__init__()
        self.cfg = cfg
        layers, cin = [], cfg.frames
        h, w = cfg.height, cfg.width
        for i, c in enumerate(cfg.channels):
            stride = 2 if i in PROFILE_STRIDES else 1
            layers += [
                nn.Conv2d(cin, c, 3, stride=stride, padding=1, bias=False),
                nn.BatchNorm2d(c),
                nn.ReLU(inplace=True),
            ]
            cin = c
            if stride == 2:
                h, w = (h + 1) // 2, (w + 1) // 2
        layers += [nn.Conv2d(cin, 32, 1), nn.ReLU(inplace=True)]
        self.cnn = nn.Sequential(*layers)
        if cfg.layer_bins:
            self.register_buffer("layer_centres", torch.linspace(-LAYER_RANGE, LAYER_RANGE, cfg.layer_bins))
            self.layer_sigma = LAYER_RANGE / (cfg.layer_bins - 1)  # half the bins' spacing
            self.layer_norm = nn.BatchNorm1d(cfg.layer_bins)
        self.fc = nn.Sequential(
            nn.Flatten(),
            nn.Linear(32 * h * w + cfg.layer_bins, cfg.fc_hidden),
            nn.ReLU(inplace=True),
            nn.Dropout(cfg.dropout),
        )
        self.heads = nn.ModuleDict(
            {"count_logits": nn.Linear(cfg.fc_hidden, N_CLASSES), "lengths": nn.Linear(cfg.fc_hidden, SLOTS)}
        )
        with torch.no_grad():
            self.heads["lengths"].bias.copy_(torch.tensor(TYPICAL_LENGTHS_PU))
        if cfg.predict_angles:
            self.heads["angles_sincos"] = nn.Linear(cfg.fc_hidden, 2 * N_CLASSES)

    def layer_histogram(self, x: torch.Tensor) -> torch.Tensor:
        """(B, layer_bins): the share of the profile's occupied cells (channel 0) whose mean t
        (channel 1, layers) lies near each bin's centre, soft (a Gaussian half a bin spacing wide)
        so that a plate's cells between two centres count for both."""
        occupied, t = x[:, 0].flatten(1), x[:, 1].flatten(1)
        near = torch.exp(-0.5 * ((t[:, None, :] - self.layer_centres[None, :, None]) / self.layer_sigma) ** 2)
        return (near * occupied[:, None, :]).sum(2) / occupied.sum(1, keepdim=True).clamp(min=1.0)

    def forward(self, x, **_):
        features = self.cnn(x).flatten(1)
        if self.cfg.layer_bins:
            features = torch.cat([features, self.layer_norm(self.layer_histogram(x))], 1)
        h = self.fc(features)
        out = {k: head(h) for k, head in self.heads.items()}
        if "angles_sincos" in out:
            sc = out.pop("angles_sincos").view(-1, N_CLASSES, 2)
            out["angles_sincos"] = sc
            out["angles"] = torch.atan2(sc[..., 0], sc[..., 1])
        return out


def input_norms(model: nn.Module) -> list[InputNorm]:
    return [m for m in model.modules() if isinstance(m, InputNorm)]


def model_inputs(batch: dict, device) -> dict:
    """The tensors a network reads from a docs/design.md batch, on `device`."""
    out = {"x": batch["x"].to(device, torch.float32)}
    for k in ("K", "T_world_camera", "print_scale"):
        if k in batch:
            out[k] = batch[k].to(device, torch.float32)
    return out


def slots_to_count(lengths: torch.Tensor, threshold: float) -> torch.Tensor:
    """e2e rule: the chain ends at the first moving-link slot shorter than `threshold` (n in 1..6)."""
    short = lengths[:, 1:] < threshold
    first_short = torch.where(short.any(1), short.float().argmax(1), torch.full_like(short[:, 0], 6, dtype=torch.long))
    return first_short.clamp(1, N_CLASSES)


def mask_after(lengths: torch.Tensor, n: torch.Tensor) -> torch.Tensor:
    keep = torch.arange(SLOTS, device=lengths.device)[None, :] <= n[:, None]
    return torch.where(keep, lengths, torch.zeros_like(lengths)).clamp_min(0.0)


@torch.no_grad()
def decode_heads(model: nn.Module, cfg: NetConfig, inputs: dict, true_n: torch.Tensor | None = None) -> dict:
    """Predictions for one batch of a network with count and / or length heads.

    Returns ``pred_n`` (B,) and ``probabilities`` (B, 6) when the model counts (a pure e2e regressor:
    the count read off its slots); ``lengths_e2e`` (masked by the predicted count) when it regresses
    lengths; ``lengths_known`` (masked by the true count) when lengths exist and `true_n` is given;
    ``angles`` when predicted.
    """
    out = model(**inputs)
    return _decode(cfg, out, true_n, lambda: out["lengths"])


@torch.no_grad()
def decode_mirrored(model: nn.Module, cfg: NetConfig, inputs: dict, true_n: torch.Tensor | None = None) -> dict:
    """`decode_heads` of the profile network, its outputs averaged over the image and its mirror image.

    The mirror is a symmetry of the task (the chain whose joint angles are the negatives, the same count
    and lengths: `profile_train.mirrored`) and the network was trained on both, so each reading is as
    good as the other; averaging them removes what either owes to one side's look. Count probabilities
    and lengths are averaged; angles through their sin / cos pairs, the mirror's sines negated."""
    out = model(**inputs)
    seen = model(**{**inputs, "x": inputs["x"].flip(-1)})
    probabilities = (torch.softmax(out["count_logits"], 1) + torch.softmax(seen["count_logits"], 1)) / 2
    both = {"count_logits": probabilities.log(), "lengths": (out["lengths"] + seen["lengths"]) / 2}
    if "angles_sincos" in out:
        sincos = (out["angles_sincos"] + seen["angles_sincos"] * seen["angles_sincos"].new_tensor([-1.0, 1.0])) / 2
        both["angles"] = torch.atan2(sincos[..., 0], sincos[..., 1])
    return _decode(cfg, both, true_n, lambda: both["lengths"])


@torch.no_grad()
def decode_routed(model: nn.Module, cfg: NetConfig, inputs: dict, true_n: torch.Tensor | None = None) -> dict:
    """`decode_heads` of a network whose lengths are routed by a count (the naive combination): its
    own predicted count end to end, the true count for ``lengths_known``."""
    out = model(**inputs)  # routed by its own predicted count
    return _decode(cfg, out, true_n, lambda: model(**inputs, n_links=true_n)["lengths"])


@torch.no_grad()
def decode_known_count(model: nn.Module, cfg: NetConfig, inputs: dict, true_n: torch.Tensor | None = None) -> dict:
    """The per-count length regressors: ``lengths_known`` for the given count (nothing without one)."""
    if true_n is None:
        return {}
    return {"lengths_known": mask_after(model(**inputs, n_links=true_n)["lengths"], true_n)}


def _decode(cfg: NetConfig, out: dict, true_n, known_lengths) -> dict:
    res: dict = {}
    if "count_logits" in out:
        res["probabilities"] = torch.softmax(out["count_logits"], 1)
        res["pred_n"] = out["count_logits"].argmax(1) + 1
    elif "lengths" in out:  # pure e2e regressor: the count is read off the slots
        res["pred_n"] = slots_to_count(out["lengths"], cfg.e2e_slot_threshold)
        res["probabilities"] = torch.nn.functional.one_hot(res["pred_n"] - 1, N_CLASSES).float()
    if "lengths" in out:
        res["lengths_e2e"] = mask_after(out["lengths"], res["pred_n"])
        if true_n is not None:
            res["lengths_known"] = mask_after(known_lengths(), true_n)
    if "angles" in out:
        res["angles"] = out["angles"]
    return res
