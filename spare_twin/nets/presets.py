"""Network and training configurations, and the named presets (one per row of the paper's Table 1,
plus the geometry-aware networks of this project).

A preset is a (NetConfig, TrainConfig) pair with a name. A training configuration (`resolve`) is
a JSON object ``{"preset": NAME, "net": {...overrides}, "train": {...overrides}}``, so any field
below can be changed without code.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

from spare_twin.errors import SpareTwinError

ARCHS = ("conv3d", "cnn_lstm", "conv3d_per_n", "naive", "geo_voxel", "grey_lift", "profile")
#: The networks that fuse views through the cameras' poses (they read K, T_world_camera, print_scale).
POSED_ARCHS = ("geo_voxel", "grey_lift")
TASKS = ("count", "lengths", "e2e", "multitask")
INPUTS = ("depth", "grey")
MODES = ("mv", "tmp", "profile")
LR_SCHEDULES = ("cosine", "one_cycle")


@dataclass(frozen=True)
class GridConfig:
    """The world-frame voxel grid the geometry-aware network fuses depth views into.

    Extents are in paper units (world metres / print_scale), so the grid follows the object's scale
    and a length read off it is already in the unit E_L is measured in. World frame: z up, table at
    z = 0, the base's joint axes along +y (docs/design.md), so the planar chain moves in x-z.
    """

    x_range: tuple[float, float] = (-1.9, 1.9)
    """Horizontal reach of the chain: moving links sum to at most 3 - 1.3 = 1.7, plus the plate width."""
    y_range: tuple[float, float] = (-0.8, 0.8)
    """Across the plane of motion: the links' layers (6.4 mm pitch) and the foot."""
    z_range: tuple[float, float] = (0.0, 3.2)
    """Table to the highest tip: the whole chain is at most 3 long, plus the plate's half-width."""
    cells: tuple[int, int, int] = (38, 32, 32)
    """Voxels along x, y, z (0.1 / 0.05 / 0.1 paper units at the defaults)."""
    table_clearance_m: float = 0.003
    """World points below this height are the table, not the object (physical metres)."""
    time_bins: int = 10
    """Temporal input only: frames picked evenly from the sequence, one grid channel each, so motion
    (which parts move together) is visible to the network."""


@dataclass(frozen=True)
class NetConfig:
    """What network, for which task, on which input.

    task: ``count`` (6-way classifier, class = n - 1), ``lengths`` (n known, 7-slot lengths),
    ``e2e`` (7-slot lengths, the count read from the slots), ``multitask`` (count + 7-slot lengths
    (+ joint angles) from one trunk; the lengths past the predicted count are zeroed).
    """

    arch: str
    task: str
    input: str = "depth"
    mode: str = "mv"
    frames: int = 8
    """Stack depth: V = 8 views (mv) or T = 100 frames (tmp)."""
    height: int = 96
    width: int = 128
    channels: tuple[int, ...] = (16, 32, 64, 64)
    """Conv channels per block (image CNNs and the voxel CNN alike)."""
    fc_hidden: int = 512
    """The paper's heads: FC 512 ReLU, FC 512 linear, then the outputs."""
    lstm_hidden: int = 64
    frame_features: int = 128
    """cnn_lstm: per-frame CNN embedding size fed to the LSTM."""
    dropout: float = 0.3
    predict_angles: bool = False
    """multitask: also regress the joint angles (rad) of the time step (mv only)."""
    lift_features: int = 8
    """grey_lift: features per view lifted into the grid (the last is the grey value itself)."""
    lift_extremes: bool = False
    """grey_lift, mv: besides the mean and variance over the views, their minimum and maximum."""
    layer_bins: int = 0
    """profile: besides the convolutions, a histogram of the image's layer channel (its cells' mean
    t, in layers) in this many bins over +-`models.LAYER_RANGE` (0: none). Where the plates lie
    across the plane says the count wherever they lie in the image, and convolutions of a few cells
    read that poorly (0.6.2's network counted 0.75 of 5-link chains even in the rig)."""
    e2e_slot_threshold: float = 0.05
    """e2e: a slot predicted shorter than this (paper units) ends the chain. Sampled moving links are
    never shorter than 0.3 * 3/8 = 0.11 after the paper's rescaling."""
    grid: GridConfig = field(default_factory=GridConfig)

    @property
    def posed(self) -> bool:
        """The network fuses views through their poses."""
        return self.arch in POSED_ARCHS

    def __post_init__(self):
        for name, allowed in (("arch", ARCHS), ("task", TASKS), ("input", INPUTS), ("mode", MODES)):
            if getattr(self, name) not in allowed:
                raise SpareTwinError(f"net.{name}: {getattr(self, name)!r} is not one of {', '.join(allowed)}")
        if self.arch == "geo_voxel" and self.input != "depth":
            raise SpareTwinError("net.input: geo_voxel back-projects depth; for grey views use grey_lift")
        if self.arch == "grey_lift" and self.input != "grey":
            raise SpareTwinError("net.input: grey_lift lifts grey views; for depth use geo_voxel")
        if self.arch == "grey_lift" and (self.mode not in ("mv", "tmp") or self.lift_features < 2):
            raise SpareTwinError("net.lift_features: grey_lift needs at least 2 (mode mv or tmp)")
        if self.lift_extremes and not (self.arch == "grey_lift" and self.mode == "mv"):
            raise SpareTwinError("net.lift_extremes: only grey_lift with mode mv has views to take extremes over")
        if self.arch in ("conv3d_per_n",) and self.task != "lengths":
            raise SpareTwinError("net.task: conv3d_per_n regresses lengths with n known (task lengths)")
        if self.arch == "naive" and self.task != "e2e":
            raise SpareTwinError("net.task: the naive counter + regressor combination is an e2e model")
        if self.layer_bins and self.arch != "profile":
            raise SpareTwinError("net.layer_bins: only the profile network reads a layer channel")
        if self.layer_bins == 1:
            raise SpareTwinError("net.layer_bins: 1: a histogram needs at least 2 bins (0: none)")
        if (self.arch == "profile") != (self.mode == "profile"):
            raise SpareTwinError(
                "net.mode: the profile network reads the chain's profile (mode profile), and only it does"
            )
        for name, (lo, hi) in _NET_INT_BOUNDS.items():
            _check_whole(f"net.{name}", getattr(self, name), lo, hi)
        if not isinstance(self.channels, tuple) or not 1 <= len(self.channels) <= 8:
            raise SpareTwinError(f"net.channels: {self.channels!r} must list 1..8 block widths")
        for c in self.channels:
            _check_whole("net.channels", c, 1, 1024)
        if not _finite_number(self.dropout) or not 0.0 <= self.dropout < 1.0:
            raise SpareTwinError(f"net.dropout: {self.dropout!r} must be a number in [0, 1)")
        if not _finite_number(self.e2e_slot_threshold) or self.e2e_slot_threshold < 0:
            raise SpareTwinError(f"net.e2e_slot_threshold: {self.e2e_slot_threshold!r} must be a number, 0 or more")
        cells = self.grid.cells
        if not isinstance(cells, tuple) or len(cells) != 3:
            raise SpareTwinError(f"net.grid.cells: {cells!r} must be three voxel counts")
        for c in cells:
            _check_whole("net.grid.cells", c, 4, 256)
        _check_whole("net.grid.time_bins", self.grid.time_bins, 1, 1000)
        for name in ("x_range", "y_range", "z_range"):
            r = getattr(self.grid, name)
            if not (isinstance(r, tuple) and len(r) == 2 and all(_finite_number(v) for v in r) and r[0] < r[1]):
                raise SpareTwinError(f"net.grid.{name}: {r!r} must be two finite numbers, low < high")


#: Whole-number fields of a network configuration and their bounds: a checkpoint or configuration file
#: outside them would build no network, or one too large for any machine (checked before torch sees them).
_NET_INT_BOUNDS = {
    "frames": (1, 1000),
    "height": (16, 4096),
    "width": (16, 4096),
    "fc_hidden": (1, 65536),
    "lstm_hidden": (1, 65536),
    "frame_features": (1, 65536),
    "lift_features": (1, 1024),
    "layer_bins": (0, 256),
}


def _finite_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _check_whole(name: str, v, lo: int, hi: int) -> None:
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise SpareTwinError(f"{name}: {v!r} must be a whole number in {lo}..{hi}")


@dataclass(frozen=True)
class TrainConfig:
    """How to train: optimiser, schedule, data budget, loss weights."""

    epochs: int = 20
    batch_size: int = 16
    lr: float = 1e-3
    weight_decay: float = 1e-4
    seed: int = 0
    samples_per_epoch: int | None = None
    """Draw this many training samples per epoch (random, seeded by epoch); None = the whole split."""
    val_samples: int | None = 2000
    """Validate on at most this many validation samples (a fixed, seeded subset)."""
    bn_recalibration_samples: int | None = None
    """Before every validation, recompute BatchNorm's running statistics over this many training
    samples (a fixed, seeded subset) with the epoch's final weights; the weights are untouched. For
    networks whose statistics move faster than the running averages follow (the grey lifting
    network counted 0.26 of validation samples right with the running averages, 0.84 with the
    same weights recalibrated)."""
    patience: int | None = None
    """Stop early once validation has not improved for this many epochs (None: run all `epochs`)."""
    lr_schedule: str = "cosine"
    """"cosine": the rate falls from `lr` to 0 over the epochs (set per epoch); "one_cycle": torch's
    OneCycleLR, up to `lr` in the first 15 % of the steps and down again (set per batch)."""
    count_weight: float = 1.0
    length_weight: float = 10.0
    """Lengths are squared paper units (~0.01..1); this puts their loss on the count loss's scale."""
    angle_weight: float = 1.0
    label_smoothing: float = 0.0
    augment_flip_views: bool = False
    """mv image nets: randomly roll the view order (the rig is a ring), a cheap view augmentation."""
    depth_noise: str | None = None
    """Sim-to-real: the depth-sensor noise model (capture/rigs/noise_NAME.json, e.g. realsense_sr300)
    applied to training depth images at read time."""
    grey_jitter: bool = False
    """Grey input: random gain, offset and gamma per sample (exposure and lighting)."""
    pose_yaw_jitter_deg: float = 0.0
    """Sim-to-real: the camera poses of a training sample turned about the table normal by up to this
    much (the yaw error of a real recording's estimated object frame)."""
    pose_xy_jitter_m: float = 0.0
    """Sim-to-real: and shifted along the table by this std per axis (its base error)."""
    handheld_repeat: int = 1
    """Profile network: each training sample of a hand-held sample folder (`spare-twin dataset
    --handheld`) and its mirror image are in the training split this many times each (a few hundred
    captures beside tens of thousands of rig samples)."""
    init_from: str | None = None
    """Fine-tune: start from this checkpoint's weights (same network configuration) instead of random ones."""
    workers: int = 0
    """DataLoader worker processes (0: load in the training process); for a network that observes its
    samples once (the profile network), the processes that observe them."""
    threads: int = 0
    """torch intra-op threads (0: leave torch's default)."""
    channels_last: bool = False
    """Convolutions in channels-last layout (NHWC / NDHWC); the same results, at another speed
    (`spare-twin bench training` measures which)."""

    def __post_init__(self):
        # Errors name the field as a configuration file spells it (train.<field>).
        def whole(name: str, least: int, optional: bool = False) -> None:
            v = getattr(self, name)
            if optional and v is None:
                return
            if not isinstance(v, int) or isinstance(v, bool) or v < least:
                raise SpareTwinError(f"train.{name} {v!r}: must be a whole number, at least {least}")

        def number(name: str, positive: bool = False, below: float = math.inf) -> None:
            v = getattr(self, name)
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            if not (ok and (v > 0 if positive else v >= 0) and v < below):
                bound = "positive" if positive else "zero or more"
                raise SpareTwinError(
                    f"train.{name} {v!r}: must be {bound}" + (f" and below {below}" if below < math.inf else "")
                )

        for name in ("epochs", "batch_size"):
            whole(name, 1)
        if self.lr_schedule not in LR_SCHEDULES:
            raise SpareTwinError(f"train.lr_schedule {self.lr_schedule!r}: must be one of {', '.join(LR_SCHEDULES)}")
        for name in ("grey_jitter", "channels_last"):
            if not isinstance(getattr(self, name), bool):
                raise SpareTwinError(f"train.{name} {getattr(self, name)!r}: must be true or false")
        for name in ("seed", "workers", "threads"):
            whole(name, 0)
        whole("handheld_repeat", 1)
        for name in ("samples_per_epoch", "val_samples", "patience", "bn_recalibration_samples"):
            whole(name, 1, optional=True)
        number("lr", positive=True)
        for name in ("weight_decay", "count_weight", "length_weight", "angle_weight"):
            number(name)
        for name in ("pose_yaw_jitter_deg", "pose_xy_jitter_m"):
            number(name)
        number("label_smoothing", below=1.0)


@dataclass(frozen=True)
class Preset:
    """A named, documented training recipe."""

    name: str
    net: NetConfig
    train: TrainConfig
    description: str
    paper_row: str | None = None
    """The Table 1 row this reproduces (network / task / input), or None for this project's nets."""
    paper_result: float | None = None
    paper_metric: str | None = None
    """``count_accuracy`` or ``E_L``."""


def _p(name, net, train=None, description="", row=None, result=None, metric=None) -> Preset:
    return Preset(name, net, train or TrainConfig(), description, row, result, metric)


_TMP = dict(mode="tmp", frames=100)
#: The temporal grey network's grid: half as many cells across the plane of motion (0.1 paper units,
#: as along x and z). One camera's rays cannot place anything across that plane, and lifting costs
#: per voxel. (Multi-view keeps 0.05: a link is 6 mm thick, and a voxel centre 4 mm off its
#: mid-plane falls outside it in some views, which thins the links out of the views' agreement.)
GREY_GRID = GridConfig(cells=(38, 16, 32))
#: The voxel networks' 3D CNN and head sizes.
_VOXEL_CNN = dict(channels=(16, 32, 64, 96), fc_hidden=256, dropout=0.1)
_GREY_TRAIN = TrainConfig(epochs=12, batch_size=16, lr=2e-3, samples_per_epoch=4000, grey_jitter=True)
_TMP_TRAIN = TrainConfig(epochs=15, batch_size=8)

PRESETS: dict[str, Preset] = {
    p.name: p
    for p in [
        # --- the paper's Table 1 ------------------------------------------------------------
        _p(
            "conv3d-depth-tmp-count",
            NetConfig("conv3d", "count", "depth", **_TMP),
            _TMP_TRAIN,
            "Conv3D link counter on 100 depth frames of one camera",
            "CONV3D-Depth-TMP / count",
            0.682,
            "count_accuracy",
        ),
        _p(
            "lstm-depth-tmp-count",
            NetConfig("cnn_lstm", "count", "depth", **_TMP),
            _TMP_TRAIN,
            "shared per-frame CNN + LSTM(64) link counter, 100 depth frames",
            "LSTM-Depth-TMP / count",
            0.638,
            "count_accuracy",
        ),
        _p(
            "conv3d-depth-mv-count",
            NetConfig("conv3d", "count", "depth"),
            None,
            "Conv3D link counter on the 8 depth views of one time step",
            "CONV3D-Depth-MV / count",
            0.949,
            "count_accuracy",
        ),
        _p(
            "lstm-depth-mv-count",
            NetConfig("cnn_lstm", "count", "depth"),
            None,
            "shared per-view CNN + LSTM(64) link counter, 8 depth views",
            "LSTM-Depth-MV / count",
            0.956,
            "count_accuracy",
        ),
        _p(
            "conv3d-grey-tmp-count",
            NetConfig("conv3d", "count", "grey", **_TMP),
            _TMP_TRAIN,
            "Conv3D link counter on 100 grey frames",
            "CONV3D-Grey-TMP / count",
            0.559,
            "count_accuracy",
        ),
        _p(
            "lstm-grey-mv-count",
            NetConfig("cnn_lstm", "count", "grey"),
            None,
            "shared per-view CNN + LSTM(64) link counter, 8 grey views",
            "LSTM-Grey-MV / count",
            0.891,
            "count_accuracy",
        ),
        _p(
            "conv3d-depth-tmp-lengths",
            NetConfig("conv3d_per_n", "lengths", "depth", **_TMP),
            _TMP_TRAIN,
            "six Conv3D length regressors, one per link count (n known), 100 depth frames",
            "CONV3D-Depth-TMP / lengths, n known",
            6.64,
            "E_L",
        ),
        _p(
            "conv3d-depth-mv-lengths",
            NetConfig("conv3d_per_n", "lengths", "depth"),
            None,
            "six Conv3D length regressors, one per link count (n known), 8 depth views",
            "CONV3D-Depth-MV / lengths, n known",
            0.543,
            "E_L",
        ),
        _p(
            "conv3d-depth-tmp-e2e",
            NetConfig("conv3d", "e2e", "depth", **_TMP),
            _TMP_TRAIN,
            "Conv3D end-to-end: the 7-slot length label directly, 100 depth frames",
            "CONV3D-Depth-TMP / end-to-end",
            14.8,
            "E_L",
        ),
        _p(
            "conv3d-depth-mv-e2e",
            NetConfig("conv3d", "e2e", "depth"),
            None,
            "Conv3D end-to-end: the 7-slot length label directly, 8 depth views",
            "CONV3D-Depth-MV / end-to-end",
            0.415,
            "E_L",
        ),
        _p(
            "conv3d-depth-mv-naive",
            NetConfig("naive", "e2e", "depth"),
            None,
            "the paper's naive combination: the Conv3D counter picks which per-n regressor measures",
        ),
        _p(
            "conv3d-depth-tmp-naive",
            NetConfig("naive", "e2e", "depth", **_TMP),
            _TMP_TRAIN,
            "naive combination (counter + per-n regressors), 100 depth frames",
        ),
        # --- this project's geometry-aware networks -----------------------------------------
        _p(
            "geo-depth-mv-multitask",
            NetConfig(
                "geo_voxel",
                "multitask",
                "depth",
                channels=(16, 32, 64, 96),
                fc_hidden=256,
                dropout=0.1,
                predict_angles=True,
            ),
            TrainConfig(epochs=15, batch_size=16, lr=2e-3, samples_per_epoch=4000),
            "the 8 depth views back-projected through the rig's poses into one world-frame voxel grid "
            "(paper units); a small 3D CNN predicts count, 7-slot lengths and joint angles",
        ),
        _p(
            "profile-depth-multitask",
            NetConfig(
                "profile",
                "multitask",
                "depth",
                mode="profile",
                frames=3,
                height=64,
                width=80,
                channels=(24, 32, 48, 64, 64),
                fc_hidden=256,
                dropout=0.1,
                predict_angles=True,
                layer_bins=31,
            ),
            TrainConfig(
                epochs=20, batch_size=32, lr=2e-3, angle_weight=2.0, threads=1, workers=2, lr_schedule="one_cycle"
            ),
            "yaw-free: any recording's object points (`observe.points`) drawn in the chain's own plane "
            "(`observe.profile`, 3 channels); a small 2D CNN predicts count, 7-slot lengths and joint angles. "
            "Trained on rig renders with hand-held-like arcs, fitted sensor noise, registration error, "
            "clutter and the whole circle of yaw (`nets.profile_train`)",
        ),
        _p(
            "geo-grey-mv-multitask",
            NetConfig("grey_lift", "multitask", "grey", predict_angles=True, **_VOXEL_CNN),
            _GREY_TRAIN,
            "grey cameras with known poses: each of the 8 views through a small 2D CNN, the features lifted "
            "along the camera rays into the world voxel grid (paper units), their mean and variance over the "
            "views (depth shows where the views agree); a 3D CNN predicts count, 7-slot lengths and joint angles",
        ),
        _p(
            "geo-grey-tmp-multitask",
            NetConfig("grey_lift", "multitask", "grey", lift_features=4, grid=GREY_GRID, **_VOXEL_CNN, **_TMP),
            _GREY_TRAIN,
            "one grey camera's 100 frames: 10 evenly spaced frames' features lifted along its rays into the "
            "world grid as separate channels (the chain's plane shows it to scale, the channels show what "
            "moves together); count + 7-slot lengths",
        ),
        _p(
            "geo-depth-mv-count",
            NetConfig("geo_voxel", "count", "depth", channels=(16, 32, 64, 96), fc_hidden=256, dropout=0.1),
            TrainConfig(epochs=15, batch_size=16, lr=2e-3, samples_per_epoch=4000),
            "voxel-fusion counter (8 depth views)",
        ),
        _p(
            "geo-depth-tmp-multitask",
            NetConfig("geo_voxel", "multitask", "depth", channels=(16, 32, 64, 96), fc_hidden=256, dropout=0.1, **_TMP),
            TrainConfig(epochs=15, batch_size=16, lr=2e-3),
            "one camera's 100 frames back-projected into the world grid, 10 evenly spaced frames as "
            "channels (motion shows which parts move together); count + 7-slot lengths",
        ),
    ]
}


def get_preset(name: str) -> Preset:
    if name not in PRESETS:
        raise SpareTwinError(f"preset {name!r}: unknown (choose from {', '.join(PRESETS)})")
    return PRESETS[name]


def _replace(obj, overrides: dict, where: str):
    if not isinstance(overrides, dict):
        raise SpareTwinError(f"{where}: expected a JSON object")
    fields = {f.name: f for f in dataclasses.fields(obj)}
    kwargs = {}
    for k, v in overrides.items():
        if k not in fields:
            raise SpareTwinError(f"{where}: unknown key {k!r}")
        cur = getattr(obj, k)
        if dataclasses.is_dataclass(cur):
            v = _replace(cur, v, f"{where}.{k}")
        elif isinstance(cur, tuple) and isinstance(v, list):
            v = tuple(tuple(x) if isinstance(x, list) else x for x in v)
        kwargs[k] = v
    try:
        return dataclasses.replace(obj, **kwargs)
    except TypeError as exc:
        raise SpareTwinError(f"{where}: {exc}") from None


def net_from_dict(d: dict, where: str = "net") -> NetConfig:
    """Rebuild a NetConfig from its asdict() form (checkpoints)."""
    d = dict(d)
    grid = GridConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.pop("grid", {}).items()})
    d = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
    try:
        return NetConfig(grid=grid, **d)
    except TypeError as exc:
        raise SpareTwinError(f"{where}: {exc}") from None


def resolve(preset: str | None, config: dict | None, source: str = "configuration") -> Preset:
    """A preset, with the overrides of a configuration object (`source` names it in errors) applied:
    ``{"preset": NAME, "net": {...}, "train": {...}}``; its "preset" wins over `preset`."""
    config = dict(config or {})
    name = config.pop("preset", None) or preset
    if name is None:
        raise SpareTwinError(f'preset: none given, and {source} names none (a "preset" key)')
    base = get_preset(name)
    net = _replace(base.net, config.pop("net", {}), f"{source}: net")
    train = _replace(base.train, config.pop("train", {}), f"{source}: train")
    if config:
        raise SpareTwinError(f"{source}: unknown key(s) {', '.join(sorted(config))} (expected preset, net, train)")
    return dataclasses.replace(base, net=net, train=train)
