"""Torch datasets for every input mode of the paper, from a stored dataset or rendered on the fly.

Each item is the dict of docs/design.md ("Network sample"):
    x                 float32 (V, 96, 128) multi-view (8 views at one time step) or (T, 96, 128)
                      temporal (T frames of one camera); depth in metres (0 = no reading) or grey in [0, 1]
    n_links           int64 scalar, 1..6 (class index = n_links - 1)
    lengths_m         float32 (7,) paper units, base first, zeros past the last link
    joint_angles_rad  float32 (6,) (multi-view, at that time step) or (T, 6) (temporal), zero-padded
    K                 float32 (V, 3, 3) multi-view or (1, 3, 3) temporal
    T_world_camera    float32 (V, 4, 4) or (1, 4, 4), camera-to-world, metres, OpenCV axes
    print_scale       float32 scalar, physical metres per paper metre

HDF5 files are opened lazily in each data-loader worker (h5py handles must not cross a fork).
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset, IterableDataset, get_worker_info

from spare_twin.config import LABEL_SLOTS, MAX_MOVING_LINKS
from spare_twin.dataset.build import load_manifest
from spare_twin.dataset.generate import GenConfig, render_sequence
from spare_twin.dataset.store import lengths_label_pu
from spare_twin.dataset.streams import stream_indices
from spare_twin.errors import SpareTwinError
from spare_twin.sim.noise import DepthNoise
from spare_twin.sim.twin import Twin

MODES = ("mv", "tmp")
MODALITIES = ("depth", "grey")


def _check(mode: str, modality: str) -> None:
    if mode not in MODES:
        raise SpareTwinError(f"mode {mode!r}: choose mv (multi-view) or tmp (temporal)")
    if modality not in MODALITIES:
        raise SpareTwinError(f"modality {modality!r}: choose depth or grey")


def grey_jitter(x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Random gain, offset and gamma of grey images in [0, 1] (exposure and lighting variation)."""
    gain, offset, gamma = rng.uniform(0.7, 1.3), rng.uniform(-0.1, 0.1), math.exp(rng.uniform(-0.3, 0.3))
    return np.clip(np.clip(x * gain + offset, 0, 1) ** gamma, 0, 1).astype(np.float32)


@dataclass(frozen=True)
class PoseJitter:
    """A random error of the frame the camera poses are given in, one per sample (all its views).

    A real recording reaches the network through an estimated object frame: the base from the foot's
    socket boss (1.6-5 mm off) and the yaw from the links' layers (up to 20 deg off on long chains,
    docs/canonical.md). Training with this error teaches the pose-aware networks to count and measure
    through it."""

    yaw_deg: float = 0.0
    """Rotation about the table normal, uniform in +-yaw_deg."""
    xy_m: float = 0.0
    """Shift along the table, normal with this std per axis."""

    def apply(self, T_world_camera: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        a = math.radians(rng.uniform(-self.yaw_deg, self.yaw_deg))
        J = np.eye(4)
        J[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
        J[:2, 3] = rng.normal(0.0, self.xy_m, 2)
        return J @ np.asarray(T_world_camera, np.float64)


def make_sample(
    images,
    depth_scale,
    modality,
    n_links,
    lengths_label,
    joints,
    K,
    T_wc,
    print_scale,
    noise: DepthNoise | None = None,
    jitter_grey: bool = False,
    rng=None,
    pose_jitter: PoseJitter | None = None,
) -> dict:
    """The contract dict from raw stored arrays (images uint16 depth units or uint8 grey)."""
    if pose_jitter is not None:
        T_wc = pose_jitter.apply(T_wc, rng)
    if modality == "depth":
        x = images.astype(np.float32) * np.float32(depth_scale)
        if noise is not None:
            x = noise.apply(x, rng)
    else:
        x = images.astype(np.float32) * np.float32(1.0 / 255.0)
        if jitter_grey:
            x = grey_jitter(x, rng)
    ja = np.zeros(joints.shape[:-1] + (MAX_MOVING_LINKS,), np.float32)
    ja[..., : joints.shape[-1]] = joints
    return {
        "x": torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32)),
        "n_links": torch.tensor(int(n_links), dtype=torch.int64),
        "lengths_pu": torch.from_numpy(np.asarray(lengths_label, np.float32).reshape(LABEL_SLOTS)),
        "joint_angles_rad": torch.from_numpy(ja),
        "K": torch.from_numpy(np.asarray(K, np.float32)),
        "T_world_camera": torch.from_numpy(np.asarray(T_wc, np.float32)),
        "print_scale": torch.tensor(float(print_scale), dtype=torch.float32),
    }


class SpareDataset(Dataset):
    """A stored dataset split in one input mode.

    mode "mv": one item per (sequence, time step), x = the V views; "tmp": one item per (sequence,
    camera), x = the T frames. `frames` limits the temporal window (first `frames` frames) or, for
    mv, the time steps used (every `frame_stride`-th).
    """

    def __init__(
        self,
        root: str | Path,
        split: str = "train",
        mode: str = "mv",
        modality: str = "depth",
        frame_stride: int = 1,
        depth_noise: DepthNoise | None = None,
        jitter_grey: bool = False,
        seed: int = 0,
        pose_jitter: PoseJitter | None = None,
    ):
        _check(mode, modality)
        self.root = Path(root)
        self.manifest = load_manifest(self.root)
        if split not in ("train", "val", "test", "all"):
            raise SpareTwinError(f"split {split!r}: choose train, val, test or all")
        self.rows = [r for r in self.manifest["sequences"] if split == "all" or r["split"] == split]
        self.mode, self.modality = mode, modality
        self.V, self.T = self.manifest["cameras"], self.manifest["frames"]
        self.times = list(range(0, self.T, frame_stride))
        self.noise, self.jitter_grey, self.seed = depth_noise, jitter_grey, seed
        self.pose_jitter = pose_jitter
        self._files: dict = {}
        self._pid = None

    def __len__(self) -> int:
        per = len(self.times) if self.mode == "mv" else self.V
        return len(self.rows) * per

    def _file(self, row):
        import h5py

        if self._pid != os.getpid():  # a new worker process: never reuse the parent's handles
            self._files, self._pid = {}, os.getpid()
        f = self._files.get(row["index"])
        if f is None:
            path = self.root / row["file"]
            try:
                f = h5py.File(path, "r")
            except OSError as exc:
                raise SpareTwinError(f"{path}: unreadable ({exc})") from None
            self._files[row["index"]] = f
        return f

    def __getitem__(self, i: int) -> dict:
        if not 0 <= i < len(self):
            raise IndexError(i)
        per = len(self.times) if self.mode == "mv" else self.V
        row = self.rows[i // per]
        j = i % per
        f = self._file(row)
        try:  # h5py's own messages name no file
            r = self._read(f, j)
        except (OSError, KeyError, ValueError, RuntimeError) as exc:
            why = " ".join(str(exc).split())[:120]
            raise SpareTwinError(f"{self.root / row['file']}: unreadable sequence file ({why})") from None
        augmented = self.noise or self.jitter_grey or self.pose_jitter
        rng = np.random.default_rng([self.seed, i, torch.initial_seed() % (2**32)]) if augmented else None
        return make_sample(
            r["imgs"],
            r["depth_scale"],
            self.modality,
            r["n"],
            r["lengths"],
            r["joints"],
            r["K"],
            r["T_wc"],
            r["print_scale"],
            self.noise,
            self.jitter_grey,
            rng,
            self.pose_jitter,
        )

    def _read(self, f, j: int) -> dict:
        """Item `j`'s arrays and attributes from the open sequence file `f`."""
        if self.mode == "mv":
            t = self.times[j]
            imgs = f[self.modality][:, t]
            joints, K, T_wc = f["joint_angles_rad"][t], f["K"][()], f["T_world_camera"][()]
        else:
            imgs = f[self.modality][j]
            joints, K, T_wc = f["joint_angles_rad"][()], f["K"][j : j + 1], f["T_world_camera"][j : j + 1]
        return {
            "imgs": imgs,
            "joints": joints,
            "K": K,
            "T_wc": T_wc,
            "n": int(f.attrs["n_links"]),
            "depth_scale": f.attrs["depth_scale"],
            "print_scale": f.attrs["print_scale"],
            "lengths": lengths_label_pu(f),
        }


def MultiViewDataset(root, split="train", modality="depth", **kw) -> SpareDataset:
    """The 8 views at one time step (the paper's MV input)."""
    return SpareDataset(root, split, "mv", modality, **kw)


def TemporalDataset(root, split="train", modality="depth", **kw) -> SpareDataset:
    """100 frames of one camera (the paper's TMP input)."""
    return SpareDataset(root, split, "tmp", modality, **kw)


class OnTheFlyDataset(IterableDataset):
    """Unlimited fresh sequences rendered inside the data-loader workers; nothing is stored.

    Data-loader worker w of W in training process `rank` of `world_size` (torchrun) is stream
    s = rank + world_size * w of S = world_size * W, and renders sequence indices first_index + s, + S,
    + 2S, ... of the dataset with `seed`: items are reproducible and no two workers or processes repeat a
    sequence. Each sequence yields `samples_per_sequence` items (random time steps for mv, random cameras
    for tmp). `sequences` bounds an epoch over all processes (None: endless); every process gets the same
    number of them (rounded up), so data-parallel processes take the same number of steps. Call
    `set_epoch(e)` to draw new sequences each epoch.
    """

    def __init__(
        self,
        mode: str = "mv",
        modality: str = "depth",
        cfg: GenConfig = GenConfig(),
        seed: int = 1,
        sequences: int | None = None,
        samples_per_sequence: int = 8,
        first_index: int = 0,
        depth_noise: DepthNoise | None = None,
        jitter_grey: bool = False,
        pose_jitter: PoseJitter | None = None,
        rank: int = 0,
        world_size: int = 1,
    ):
        _check(mode, modality)
        if not 0 <= rank < world_size:
            raise SpareTwinError(f"rank {rank}: must be within 0..{world_size - 1} (world_size {world_size})")
        self.mode, self.modality, self.cfg, self.seed = mode, modality, cfg, seed
        if sequences is not None:
            sequences = world_size * -(-sequences // world_size)
        self.sequences, self.per_seq, self.first_index = sequences, samples_per_sequence, first_index
        self.rank, self.world_size = rank, world_size
        self.noise, self.jitter_grey, self.pose_jitter = depth_noise, jitter_grey, pose_jitter
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __iter__(self):
        info = get_worker_info()
        wid, nw = (info.id, info.num_workers) if info is not None else (0, 1)
        seed = int(np.random.SeedSequence([self.seed, self.epoch]).generate_state(1)[0])
        twin = Twin()
        work = Path(tempfile.mkdtemp(prefix="spare-twin-otf-"))
        try:
            for k in stream_indices(self.rank, self.world_size, wid, nw, self.sequences):
                index = self.first_index + k
                seq = render_sequence(self.cfg, seed, index, twin, work)
                rng = np.random.default_rng([seed, index, 7])
                V, T = seq.depth.shape[:2]
                images = seq.depth if self.modality == "depth" else seq.grey
                count = T if self.mode == "mv" else V
                picks = rng.choice(count, size=min(self.per_seq, count), replace=False)
                for j in picks:
                    if self.mode == "mv":
                        imgs, joints, K, T_wc = images[:, j], seq.joint_angles_rad[j], seq.K, seq.T_world_camera
                    else:
                        imgs, joints, K, T_wc = (
                            images[j],
                            seq.joint_angles_rad,
                            seq.K[j : j + 1],
                            seq.T_world_camera[j : j + 1],
                        )
                    yield make_sample(
                        imgs,
                        seq.depth_scale,
                        self.modality,
                        seq.spec.n_links,
                        seq.spec.label_lengths(),
                        joints,
                        K,
                        T_wc,
                        seq.spec.print_scale,
                        self.noise,
                        self.jitter_grey,
                        rng,
                        self.pose_jitter,
                    )
        finally:
            twin.close()
            shutil.rmtree(work, ignore_errors=True)
