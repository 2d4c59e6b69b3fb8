"""Training speed: samples/s of whole training steps (load the batch, then `train.train_step`:
forward, loss, backward, clipping, AdamW step) per preset, for several settings measured back to
back in the same run, as ratios against the first (the trainer's defaults).

A setting is what `TrainConfig` can change without changing the result of an epoch: torch's thread
count, DataLoader worker processes (loading overlaps the step), and the channels-last memory layout
of the convolutions. Batches come from a stored dataset's train split (HDF5 decompression and the
sample dict included), the same items in the same order for every setting.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass

import torch
from torch.utils.data import DataLoader, Subset

from spare_twin.errors import SpareTwinError
from spare_twin.nets.data import open_split
from spare_twin.nets.presets import PRESETS, get_preset
from spare_twin.nets.registry import build_model
from spare_twin.nets.train import measure_normalization, to_channels_last, train_step

#: Besides the multi-view presets of the paper's Table 1 (read off the presets), this project's grey network.
EXTRA_DEFAULT_PRESETS = ("geo-grey-mv-multitask",)


@dataclass(frozen=True)
class SpeedSetting:
    """One way to run the same training steps."""

    threads: int
    """torch intra-op threads."""
    workers: int
    """DataLoader worker processes (0: load in the training process, between steps)."""
    channels_last: bool
    """Convolution weights and activations in channels-last layout (NHWC / NDHWC)."""

    @property
    def label(self) -> str:
        return f"{self.threads} thr, {self.workers} workers" + (", channels-last" if self.channels_last else "")


@dataclass(frozen=True)
class PresetSpeed:
    preset: str
    batch_size: int
    steps: int
    samples_per_s: tuple[float, ...]
    """One per setting, in the order given."""

    def to_json(self, settings: Sequence[SpeedSetting]) -> dict:
        base = self.samples_per_s[0]
        return {
            "preset": self.preset,
            "batch_size": self.batch_size,
            "steps": self.steps,
            "settings": [
                {**asdict(s), "samples_per_s": round(v, 2), "vs_first": round(v / base, 3)}
                for s, v in zip(settings, self.samples_per_s)
            ],
        }


def _items(ds, need: int, seed: int) -> list[int]:
    """The `need` train items every setting reads, in order (a small split is drawn from with
    replacement: the timing needs batches, not distinct ones)."""
    g = torch.Generator().manual_seed(seed)
    pick = torch.randperm(len(ds), generator=g) if len(ds) >= need else torch.randint(0, len(ds), (need,), generator=g)
    return pick[:need].tolist()


def _read_once(preset_name: str, data_dir, steps: int, warmup: int, seed: int) -> None:
    """Read every item the settings will time, untimed: the first setting would otherwise read them
    from disk and the rest from the page cache (measured first, the default layout came out up to
    40 % slower than measured second, and every ratio against it too high)."""
    preset = get_preset(preset_name)
    ds = open_split(data_dir, "train", preset.net)
    for i in _items(ds, (steps + warmup) * preset.train.batch_size, seed):
        ds[i]


def _time_steps(preset_name: str, data_dir, setting: SpeedSetting, steps: int, warmup: int, seed: int) -> float:
    preset = get_preset(preset_name)
    net, tr = preset.net, preset.train
    torch.set_num_threads(setting.threads)
    torch.manual_seed(seed)
    ds = open_split(data_dir, "train", net)
    items = _items(ds, (steps + warmup) * tr.batch_size, seed)
    model = build_model(net)
    measure_normalization(model, ds, seed, samples=8)
    if setting.channels_last:
        model = to_channels_last(model)
    model.train()
    opt = torch.optim.AdamW(model.parameters(), lr=tr.lr, weight_decay=tr.weight_decay)
    loader = DataLoader(Subset(ds, items), batch_size=tr.batch_size, num_workers=setting.workers)
    t0 = None
    for i, batch in enumerate(loader):
        if i == warmup:
            t0 = time.perf_counter()
        train_step(model, net, tr, opt, batch, "cpu")
    return steps * tr.batch_size / (time.perf_counter() - t0)


def bench_training(
    presets: Sequence[str],
    data_dir,
    settings: Sequence[SpeedSetting],
    steps: int = 10,
    warmup: int = 2,
    seed: int = 0,
    log: Callable[[str], None] | None = None,
) -> list[PresetSpeed]:
    """Training samples/s of every preset under every setting (CPU)."""
    if not presets or not settings:
        raise SpareTwinError("presets, settings: give at least one of each")
    if steps < 1 or warmup < 0:
        raise SpareTwinError(f"steps {steps!r}: must be 1 or more (warmup 0 or more)")
    threads_before = torch.get_num_threads()
    out = []
    try:
        for name in presets:
            get_preset(name)  # an unknown name fails before anything is timed
            _read_once(name, data_dir, steps, warmup, seed)
            rates = []
            for s in settings:
                rates.append(_time_steps(name, data_dir, s, steps, warmup, seed))
                if log:
                    log(f"{name}: {s.label}: {rates[-1]:.1f} samples/s")
            out.append(PresetSpeed(name, get_preset(name).train.batch_size, steps, tuple(rates)))
    finally:
        torch.set_num_threads(threads_before)
    return out


def default_presets() -> tuple[str, ...]:
    """The multi-view presets of the paper's Table 1 and `EXTRA_DEFAULT_PRESETS`."""
    table_1_mv = tuple(name for name, p in PRESETS.items() if p.paper_row and p.net.mode == "mv")
    return table_1_mv + EXTRA_DEFAULT_PRESETS


def default_settings() -> list[SpeedSetting]:
    """The trainer's defaults (torch's thread count, no loader worker) first, then channels-last, a loader
    worker, and both."""
    n = torch.get_num_threads()
    return [SpeedSetting(n, workers, channels_last) for workers in (0, 1) for channels_last in (False, True)]
