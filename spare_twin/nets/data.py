"""Where the image and voxel networks get their samples: the project's dataset (spare_twin.dataset)
or a synthetic folder (synthetic.json, see dataset/synthetic.py). Both yield the docs/design.md
sample dict. (The profile network's samples are observed: `nets.profile_train`; which network takes
which is the registry's, `nets.registry`.)

Stored data: ``spare_twin.dataset.torch_data.SpareDataset`` (manifest.json + HDF5 sequences).
On the fly: ``spare_twin.dataset.torch_data.OnTheFlyDataset`` with the stored dataset's generator
settings (so fresh samples come from the same rig and randomisation) and a seed of its own; under
torchrun each process draws its own sequences (`rank`, `world_size`).
"""

from __future__ import annotations

from pathlib import Path

from spare_twin.dataset.build import load_manifest
from spare_twin.dataset.generate import GenConfig
from spare_twin.dataset.synthetic import RIG_NAME, SyntheticDataset, SyntheticOnTheFly, read_spec
from spare_twin.dataset.torch_data import OnTheFlyDataset, PoseJitter, SpareDataset
from spare_twin.errors import SpareTwinError
from spare_twin.nets.presets import NetConfig, TrainConfig
from spare_twin.sim.noise import load_noise


def _is_synthetic(data_dir: Path) -> bool:
    return (data_dir / "synthetic.json").is_file()


def _manifest(data_dir: Path) -> dict:
    return load_manifest(data_dir)


def _check_dir(data_dir) -> Path:
    data_dir = Path(data_dir)
    if not data_dir.is_dir():
        raise SpareTwinError(f"data_dir {data_dir}: no such folder")
    return data_dir


def augmentation(tr: TrainConfig | None) -> dict:
    """The read-time sim-to-real augmentation keyword arguments of the torch datasets for `tr`."""
    if tr is None:
        return {}
    out = {}
    if tr.depth_noise:
        out["depth_noise"] = load_noise(tr.depth_noise, flag="train.depth_noise")
    if tr.grey_jitter:
        out["jitter_grey"] = True
    if tr.pose_yaw_jitter_deg or tr.pose_xy_jitter_m:
        out["pose_jitter"] = PoseJitter(tr.pose_yaw_jitter_deg, tr.pose_xy_jitter_m)
    return out


def open_split(data_dir, split: str, net: NetConfig, augment: TrainConfig | None = None):
    """The map Dataset of one split ("train", "val", "test") for this network's mode and input, with
    the sim-to-real augmentation of `augment` (a TrainConfig) applied at read time."""
    data_dir = _check_dir(data_dir)
    if _is_synthetic(data_dir):
        spec = read_spec(data_dir)
        if (spec.mode, spec.input) != (net.mode, net.input):
            raise SpareTwinError(
                f"data_dir {data_dir}: synthetic {spec.mode}/{spec.input} data, "
                f"but the network wants {net.mode}/{net.input}"
            )
        if augmentation(augment):
            raise SpareTwinError(
                f"data_dir {data_dir}: sim-to-real augmentation needs a spare-twin dataset, not synthetic data"
            )
        return SyntheticDataset(spec, split)
    if not (data_dir / "manifest.json").is_file():
        raise SpareTwinError(f"data_dir {data_dir}: not a dataset (no manifest.json; make one with spare-twin dataset)")

    ds = SpareDataset(
        data_dir,
        split=split,
        mode=net.mode,
        modality=net.input,
        seed=augment.seed if augment else 0,
        **augmentation(augment),
    )
    if len(ds) == 0:
        raise SpareTwinError(f"data_dir {data_dir}: the {split} split is empty")
    return ds


def stored_samples(
    data_dirs, split: str, net: NetConfig, train: TrainConfig | None = None, run_dir=None, progress=True
):
    """`open_split` of the one dataset folder in `data_dirs`, with `train`'s read-time augmentation on
    the train split (the registry's sample source of the image and voxel networks; `run_dir` and
    `progress` are unused: nothing is observed ahead)."""
    if len(data_dirs) != 1:
        raise SpareTwinError(f"data_dir {','.join(map(str, data_dirs))}: this network trains on one dataset folder")
    return open_split(data_dirs[0], split, net, augment=train if split == "train" else None)


def open_on_the_fly(
    data_dir,
    net: NetConfig,
    seed: int,
    samples: int | None = None,
    augment: TrainConfig | None = None,
    rank: int = 0,
    world_size: int = 1,
):
    """An IterableDataset of freshly rendered samples (on the fly), same generator as the stored data;
    `samples` per epoch over all `world_size` processes, of which this is `rank` (disjoint sequences)."""
    data_dir = _check_dir(data_dir)
    if _is_synthetic(data_dir):
        if augmentation(augment):
            raise SpareTwinError(
                f"data_dir {data_dir}: sim-to-real augmentation needs a spare-twin dataset, not synthetic data"
            )
        return SyntheticOnTheFly(read_spec(data_dir), seed, rank, world_size)
    m = _manifest(data_dir)
    per_seq = 8
    sequences = None if samples is None else -(-samples // per_seq)
    # a seed far from the stored dataset's, so fresh sequences never repeat stored (test!) ones
    return OnTheFlyDataset(
        net.mode,
        net.input,
        GenConfig.from_dict(m["generator"]),
        seed=10_000 + seed,
        sequences=sequences,
        samples_per_sequence=per_seq,
        rank=rank,
        world_size=world_size,
        **augmentation(augment),
    )


def dataset_rig(data_dir) -> str | None:
    """The rig name the data was rendered with (predict compares it with a recording's rig)."""
    data_dir = Path(data_dir)
    if _is_synthetic(data_dir):
        return RIG_NAME
    try:
        return _manifest(data_dir)["generator"]["rig"].get("name")
    except (SpareTwinError, KeyError, AttributeError):
        return None
