"""The yaw-free profile network's samples (`nets.registry` names this its sample source).

A sample costs a full observation (~0.1 s) and as much again for the layer measurement, whose
layers' comb levels the network's input (`measure.level`), far more
than a training step, so a split is observed once, in several processes, and kept:

- training (`spare-twin train`, the one loop of `nets.train`): into the run folder
  (`samples-<split>.npz`, written atomically; an interrupted or resumed run reads them again).
  Training samples get `TRAIN_VARIANTS` hand-held-like captures per rig time step; validation takes
  every `VAL_FRAME_STRIDE`-th time step, the rig's views as they are.
- evaluation (`spare-twin evaluate`): every time step, the rig's views as they are, measured as
  `predict` measures them (`spare_twin.measure`), into the user's cache, keyed by the dataset's
  manifest and the source of the code that observes and measures: a second evaluation of the same
  split reads it in seconds, and any change to that code observes again.

Several datasets can be given (e.g. a plain one and a `--sim2real` one with clutter); their splits
are concatenated. A folder of hand-held profile samples (`spare-twin dataset --handheld`: captures
drawn with every effect and observed as `predict` observes them, `bench.handheld_samples`) is read as
it is, its training samples and their mirror images each `train.handheld_repeat` times (they are few
beside the rig's).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import sys
from pathlib import Path

import h5py
import numpy as np
import torch
from torch.utils.data import Dataset

from spare_twin.dataset.backends import start_pool
from spare_twin.errors import SpareTwinError
from spare_twin.io import read_json, write_bytes_atomic
from spare_twin.measure.slots import measurement_slots
from spare_twin.nets.presets import NetConfig, TrainConfig
from spare_twin.nets.profile_samples import CaptureAugment, stored_sample
from spare_twin.nets.sample_folders import HANDHELD_FORMAT, SPLIT_CODES
from spare_twin.recording import npz_bytes
from spare_twin.validate import usable_cores

#: Hand-held-like captures per training time step.
TRAIN_VARIANTS = 2
#: Validation observes every this many time steps of each sequence.
VAL_FRAME_STRIDE = 4
#: The code a cached evaluation split depends on: its source is part of the cache key.
_OBSERVING_CODE = ("observe", "measure", "nets/profile_samples.py", "nets/profile_train.py")
_PACKAGE = Path(__file__).resolve().parents[1]


def _sequence_samples(job: tuple) -> dict:
    """Every sample of one sequence (runs in a worker process). A time step where no chain is found is
    dropped, or with `keep_rejected` kept with the observation's (empty) image, as a test counts it."""
    path, seed, dataset_seed, index, times, variants, augment, measure, keep_rejected = job
    out: dict = {"x": [], "n": [], "lengths": [], "angles": [], "rejected": 0}
    aug = CaptureAugment() if augment else None
    with h5py.File(path, "r") as f:
        for t in times:
            for v in range(variants):
                rng = np.random.default_rng([seed, dataset_seed, index, t, v])
                s = stored_sample(f, t, aug, rng)
                if s.profile.reason is not None:
                    out["rejected"] += 1
                    if not keep_rejected:
                        continue
                out["x"].append(s.image.astype(np.float16))
                out["n"].append(s.n_links)
                out["lengths"].append(s.lengths_pu)
                out["angles"].append(s.angles_rad)
                if measure:
                    for k, val in measurement_slots(s.measurement).items():
                        out.setdefault(k, []).append(val)
    return out


_BLAS_THREADS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@contextlib.contextmanager
def _single_threaded_blas():
    """Worker processes started inside (spawned, not forked: they read the environment afresh) get one
    BLAS thread each: the measurement's least-squares fits
    take many small SVDs, which threads only slow down once every core runs a worker (measured: 1.6 s
    against 4.5 s per sample on a busy 2-core machine)."""
    saved = {k: os.environ.get(k) for k in _BLAS_THREADS}
    os.environ.update(dict.fromkeys(_BLAS_THREADS, "1"))
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _jobs(data_dirs: list[Path], split: str, seed: int, variants: int, augment: bool, stride: int, measure, keep):
    jobs = []
    for d in data_dirs:
        manifest = read_json(d / "manifest.json")
        times = list(range(0, int(manifest["frames"]), stride))
        for row in manifest["sequences"]:
            if row["split"] == split:
                job = (str(d / row["file"]), seed, int(manifest.get("seed", 0)), row["index"], times, variants)
                jobs.append((*job, augment, measure, keep))
    return jobs


def observe_split(
    data_dirs: list[Path],
    split: str,
    seed: int,
    variants: int,
    augment: bool,
    frame_stride: int = 1,
    workers: int = 1,
    progress: bool = True,
    measure: bool = False,
    keep_rejected: bool = False,
) -> dict[str, np.ndarray]:
    """Profiles and labels of one split of every dataset, in a fixed order (any `workers`); with
    `measure`, the layer measurement of each as `measurement_slots` arrays too."""
    from tqdm import tqdm

    jobs = _jobs([Path(d) for d in data_dirs], split, seed, variants, augment, frame_stride, measure, keep_rejected)
    if not jobs:
        raise SpareTwinError(f"data: no {split} sequences in {', '.join(map(str, data_dirs))}")
    parts = []
    # closed on the way out of an interrupt too, so that the command's last line is not glued to the bar's
    with tqdm(total=len(jobs), desc=f"observe {split}", unit="seq", file=sys.stderr, disable=not progress) as bar:
        if workers > 1:
            # the dataset's pool: quiet on Ctrl-C (the driver alone answers it, and the pool is terminated);
            # imap keeps the jobs' order, so the split's order does not depend on `workers`
            with _single_threaded_blas(), start_pool(min(workers, len(jobs))) as pool:
                for part in pool.imap(_sequence_samples, jobs):
                    parts.append(part)
                    bar.update()
        else:
            for job in jobs:
                parts.append(_sequence_samples(job))
                bar.update()
    if not any(p["n"] for p in parts):
        raise SpareTwinError(f"data: no chain observed in any {split} sample of {', '.join(map(str, data_dirs))}")
    out = {
        "x": np.stack([x for p in parts for x in p["x"]]),
        "n": np.array([n for p in parts for n in p["n"]], np.int64),
        "lengths": np.stack([x for p in parts for x in p["lengths"]]).astype(np.float32),
        "angles": np.stack([x for p in parts for x in p["angles"]]).astype(np.float32),
        "rejected": np.array(sum(p["rejected"] for p in parts), np.int64),
    }
    for k in [k for k in parts[0] if k.startswith("measured_")]:
        out[k] = np.stack([x for p in parts for x in p[k]])
    return out


class ObservedProfiles(Dataset):
    """One split's observed profile samples in docs/design.md's layout (x = the profile image, C x H x W),
    observed on first use (`prepare`) or read from `cache` (an .npz; None: kept in memory only)."""

    def __init__(
        self,
        data_dirs: list[Path],
        split: str,
        cache: Path | None,
        progress: bool = True,
        handheld_dirs: tuple[Path, ...] = (),
        handheld_repeat: int | None = None,
        **observe,
    ):
        self.data_dirs, self.split, self.cache, self.progress, self.observe = data_dirs, split, cache, progress, observe
        self.handheld_dirs, self.handheld_repeat = tuple(handheld_dirs), handheld_repeat
        self._arrays: dict[str, np.ndarray] | None = None

    def _rig_arrays(self) -> dict[str, np.ndarray] | None:
        """The rig datasets' samples of the split: the cache's, else observed now (and cached); None
        where only hand-held sample folders were given."""
        if not self.data_dirs:
            return None
        if self.cache is not None and self.cache.is_file():
            with np.load(self.cache) as z:
                return {k: z[k] for k in z.files}
        arrays = observe_split(self.data_dirs, self.split, progress=self.progress, **self.observe)
        if self.cache is not None:
            try:
                write_bytes_atomic(self.cache, npz_bytes(arrays))
            except OSError as exc:  # an unwritable cache costs the next run time, not this one its result
                print(f"note: could not keep the observed samples in {self.cache} ({exc.strerror})", file=sys.stderr)
        return arrays

    def prepare(self) -> dict[str, np.ndarray]:
        """The split's arrays: the rig datasets' (`_rig_arrays`), then each hand-held folder's; for
        training (`handheld_repeat` given) each sample and its mirror image (`mirrored`), that many times."""
        if self._arrays is None:
            parts = [handheld_split(d, self.split) for d in self.handheld_dirs]
            if self.handheld_repeat is not None:  # training: each sample and its mirror image, repeated
                parts = [q for p in parts for q in (p, mirrored(p)) for _ in range(self.handheld_repeat)]
            parts = [p for p in parts if len(p["n"])]
            rig = self._rig_arrays()
            if rig is None and not parts:
                raise SpareTwinError(f"data: no {self.split} samples in {', '.join(map(str, self.handheld_dirs))}")
            arrays = dict(rig) if rig is not None else {"rejected": np.array(0, np.int64)}
            for k in ("x", "n", "lengths", "angles"):
                arrays[k] = np.concatenate(([rig[k]] if rig is not None else []) + [p[k] for p in parts])
            self._arrays = arrays
        return self._arrays

    @property
    def rejected(self) -> int:
        """Time steps (or captures) in which the observation found no chain."""
        return int(self.prepare()["rejected"])

    def __len__(self) -> int:
        return len(self.prepare()["n"])

    def __getitem__(self, i: int) -> dict:
        a = self.prepare()
        item = {
            "x": torch.from_numpy(a["x"][i].astype(np.float32)),
            "n_links": torch.tensor(int(a["n"][i]), dtype=torch.int64),
            "lengths_pu": torch.from_numpy(a["lengths"][i]),
            "joint_angles_rad": torch.from_numpy(a["angles"][i]),
        }
        item.update({k: torch.as_tensor(a[k][i]) for k in a if k.startswith("measured_")})
        return item


def is_handheld(d: Path) -> bool:
    """Whether dataset folder `d` holds hand-held profile samples rather than rig sequences."""
    try:
        return read_json(d / "manifest.json").get("format") == HANDHELD_FORMAT
    except (SpareTwinError, AttributeError):
        return False


def handheld_split(d: Path, split: str) -> dict[str, np.ndarray]:
    """The samples of `split` in hand-held sample folder `d` (`x`, `n`, `lengths`, `angles`)."""
    code = SPLIT_CODES.get(split)
    try:
        with np.load(d / read_json(d / "manifest.json")["file"]) as z:
            keep = z["split"] == code
            return {k: z[k][keep] for k in ("x", "n", "lengths", "angles")}
    except (OSError, KeyError, ValueError) as exc:
        raise SpareTwinError(f"data_dir {d}: its hand-held samples do not read ({exc})") from None


def mirrored(samples: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The same samples seen in a mirror across the chain's plane's vertical axis: the chain whose joint
    angles are the negatives, with the same links in the same layers. Its profile is the image flipped
    left to right (the profile's s range is symmetric about the base axis); its count and lengths are
    the same."""
    out = dict(samples)
    out["x"] = np.ascontiguousarray(samples["x"][..., ::-1])
    out["angles"] = -samples["angles"]
    return out


def _check_datasets(data_dirs: list[Path]) -> None:
    for d in data_dirs:
        if not d.is_dir():
            raise SpareTwinError(f"data_dir {d}: no such folder")
        if not (d / "manifest.json").is_file():
            raise SpareTwinError(
                f"data_dir {d}: the profile network needs a spare-twin dataset of depth views (no manifest.json)"
            )


def evaluation_cache(data_dirs: list[Path], split: str) -> Path:
    """Where an evaluated split's observation is kept: the user's cache ($XDG_CACHE_HOME, else
    ~/.cache), named by a hash of the datasets' manifests, the split and the observing code."""
    h = hashlib.sha256(split.encode())
    for d in data_dirs:
        h.update((d / "manifest.json").read_bytes())
    for part in _OBSERVING_CODE:
        path = _PACKAGE / part
        for f in sorted(path.rglob("*.py")) if path.is_dir() else [path]:
            h.update(f.relative_to(_PACKAGE).as_posix().encode() + f.read_bytes())
    root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "spare-twin" / "observed"
    return root / f"{split}-{h.hexdigest()[:20]}.npz"


def _evaluation_workers() -> int:
    return usable_cores()


def profile_samples(
    data_dirs, split: str, net: NetConfig, train: TrainConfig | None = None, run_dir=None, progress: bool = True
) -> ObservedProfiles:
    """The registry's sample source of the profile network (see the module doc): with `train`, the
    training run's (observed into `run_dir` by `train.workers` processes); without, the evaluation's
    (every time step, measured, cached for the user, observed by every core)."""
    data_dirs = [Path(d) for d in data_dirs]
    _check_datasets(data_dirs)
    handheld = tuple(d for d in data_dirs if is_handheld(d))
    data_dirs = [d for d in data_dirs if d not in handheld]
    if train is None:
        if handheld:
            raise SpareTwinError(
                f"data_dir {handheld[0]}: hand-held profile samples are for training; evaluate reads a dataset "
                "of the rig's views (`spare-twin bench sim2real` scores hand-held captures)"
            )
        cache = evaluation_cache(data_dirs, split)
        observe = dict(variants=1, augment=False, measure=True, keep_rejected=True, workers=_evaluation_workers())
        return ObservedProfiles(data_dirs, split, cache, progress, seed=0, **observe)
    cache = None if run_dir is None else Path(run_dir) / f"samples-{split}.npz"
    augment = split == "train"
    observe = dict(
        seed=train.seed,
        variants=TRAIN_VARIANTS if augment else 1,
        augment=augment,
        frame_stride=1 if augment else VAL_FRAME_STRIDE,
        workers=max(train.workers, 1),
    )
    repeat = train.handheld_repeat if augment else None
    return ObservedProfiles(data_dirs, split, cache, progress, handheld, repeat, **observe)
