"""Generate, resume and extend a dataset folder in parallel, on local processes or a Ray cluster.

    DATA_DIR/dataset.json        the generation settings (seed, GenConfig): fixed at creation
    DATA_DIR/manifest.json       per sequence: index, file, n_links, link_lengths_pu, chain_seed, split
    DATA_DIR/sequences/seq-NNNNNN.h5   one sequence each (schema in store.py)

Every sequence is a pure function of (seed, index, settings), each file is written under a temporary
name and renamed, and the manifest is rebuilt from the finished files at the end of every run. So a
run killed at any moment (kill -9 included) is finished by running the same command again, and a
larger `instances` on the same folder only adds the missing sequences. The driver (this module) holds
the folder's lock, picks the missing sequences, counts them on a progress bar and writes the manifest;
a backend (backends.py, ray_backend.py) renders them, with the same bytes wherever it runs.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from spare_twin.dataset.backends import BACKENDS, check_workers, run_local
from spare_twin.dataset.generate import SPLITS, GenConfig, _seeds, sequence_spec, split_of
from spare_twin.dataset.ray_backend import SHARDS, RaySession, run_ray
from spare_twin.dataset.store import sequence_filename, shard_problem
from spare_twin.errors import SpareTwinError
from spare_twin.io import read_json, write_json_atomic
from spare_twin.output import OutputRefused, process_token, token_alive, token_pid, writing
from spare_twin.validate import cap_workers, check_count, check_fits_memory, usable_cores

DATASET_FORMAT = "spare-twin-dataset/1"
#: Most sequences in a dataset: the files are numbered with 6 digits (the paper's dataset has 324).
MAX_INSTANCES = 999_999
#: Most frames in a sequence (the paper's have 100).
MAX_SEQUENCE_FRAMES = 10_000


@dataclass(frozen=True)
class Preset:
    """A named dataset size and seed."""

    instances: int
    seed: int = 0
    frames: int = 100


#: paper: 324 sequences x 8 cameras x 100 frames = 259,200 images (153,600 / 28,800 / 76,800).
PRESETS = {"paper": Preset(instances=324), "small": Preset(instances=36), "tiny": Preset(instances=6, frames=20)}


# -- driver side -----------------------------------------------------------------------------
def _lock_owner(path: Path) -> str | None:
    """The process token (`spare_twin.output.process_token`; an older lock's bare pid) a `_Lock` file
    holds, "" for an empty one (a run killed as it wrote it); None where the path is no such file
    (absent, or the user's)."""
    if not path.is_file() or path.is_symlink():
        return None
    try:
        text = path.read_text(errors="replace").strip()
    except OSError:
        return None
    return text if not text or token_pid(text) is not None else None


class _Lock:
    """DATA_DIR/.lock holding the writer's process token; a lock whose process is gone (killed, or a
    reboot since: its pid may now be another process's) is taken over."""

    def __init__(self, root: Path):
        self.path = root / ".lock"

    def __enter__(self):
        owner = _lock_owner(self.path)
        if owner is None and os.path.lexists(self.path):  # taking it over would overwrite it, then delete it
            raise SpareTwinError(f"{self.path}: not a spare-twin lock (a file of yours?); move it out of the folder")
        written_s = None
        with contextlib.suppress(OSError):
            written_s = self.path.stat().st_mtime
        if owner and owner != process_token() and token_alive(owner, written_s):
            raise SpareTwinError(
                f"{self.path.parent}: another spare-twin dataset (pid {token_pid(owner)}) is writing it"
            )
        # written in place, not renamed in: a run killed meanwhile leaves an empty lock, not a temporary file
        self.path.write_text(process_token())
        return self

    def __exit__(self, *exc):
        self.path.unlink(missing_ok=True)


#: What `write_json_atomic` leaves of the folder's own JSON files when a run is killed as it writes them.
_OWN_TEMPORARIES = re.compile(r"\.(dataset|manifest)\.json\.[A-Za-z0-9_]+\.tmp")


def _ours_or_empty(root: Path) -> bool:
    """The folder is a dataset, empty, or holds only what a run killed before its dataset.json was in
    place leaves (a file named .lock holding a process token, a temporary dataset.json): those resume;
    anything else is the user's."""
    if (root / "dataset.json").exists():
        return True
    entries = list(root.iterdir())
    return all(
        (p.name == ".lock" and _lock_owner(p) is not None) or (_OWN_TEMPORARIES.fullmatch(p.name) and p.is_file())
        for p in entries
    )


def _check_settings(root: Path, seed: int, cfg: GenConfig, create: bool = True) -> None:
    """The folder's dataset.json must hold these settings; an absent one is written (with `create`)."""
    path = root / "dataset.json"
    want = {"format": DATASET_FORMAT, "seed": int(seed), "generator": cfg.to_dict()}
    if not path.exists():
        if create:
            write_json_atomic(path, want)
        return
    have = read_json(path)
    if have.get("format") != DATASET_FORMAT:
        raise SpareTwinError(f"{path}: not a {DATASET_FORMAT} folder")
    if have.get("seed") != want["seed"]:
        raise SpareTwinError(
            f"seed {seed}: {root} was generated with seed {have.get('seed')}; use that one to resume or extend it, "
            "or another folder"
        )
    if have.get("generator") != json.loads(json.dumps(want["generator"])):
        diff = sorted(
            k
            for k in want["generator"]
            if have.get("generator", {}).get(k) != json.loads(json.dumps(want["generator"][k]))
        )
        raise SpareTwinError(
            f"{root} was generated with other settings ({', '.join(diff)}); use the same ones or another folder"
        )


def build_manifest(root: Path, instances: int) -> dict:
    """The manifest of the finished sequences with index < instances (labels are pure functions of
    (seed, index), so they are recomputed, not read back from the files)."""
    settings = read_json(root / "dataset.json")
    cfg = GenConfig.from_dict(settings["generator"])
    seed = settings["seed"]
    seq_dir = root / "sequences"
    rows, counts = [], {s: 0 for s in SPLITS}
    images_per_seq = cfg.rig.n_cameras * cfg.frames
    for i in range(instances):
        f = seq_dir / sequence_filename(i)
        if not _shard_ok(seq_dir, i, cfg):
            continue
        spec = sequence_spec(seed, i)
        rows.append(
            {
                "index": i,
                "file": f"sequences/{f.name}",
                "n_links": spec.n_links,
                "link_lengths_pu": list(spec.link_lengths_pu),
                "print_scale": spec.print_scale,
                "colors": list(spec.colors),
                "chain_seed": _seeds(seed, i)["chain"],
                "split": split_of(i),
            }
        )
        counts[split_of(i)] += 1
    extra = (
        sorted(p.name for p in seq_dir.glob("seq-*.h5") if int(p.stem.split("-")[1]) >= instances)
        if seq_dir.is_dir()
        else []
    )
    return {
        "format": DATASET_FORMAT,
        "seed": seed,
        "instances": instances,
        "complete": len(rows) == instances,
        "cameras": cfg.rig.n_cameras,
        "frames": cfg.frames,
        "image_size_hw": [cfg.rig.height, cfg.rig.width],
        "images": len(rows) * images_per_seq,
        "splits": {s: {"sequences": c, "images": c * images_per_seq} for s, c in counts.items()},
        "unlisted_files": len(extra),
        "generator": settings["generator"],
        "sequences": rows,
    }


def generate_dataset(
    root: str | Path,
    instances: int,
    seed: int = 0,
    workers: int | None = 1,
    cfg: GenConfig = GenConfig(),
    progress: bool = True,
    backend: str = "local",
    ray_address: str | None = None,
    shards: str = "driver",
    force: bool = False,
) -> dict:
    """Generate (or resume, or extend) the dataset at `root`; returns a summary with timings.

    A folder that is neither empty nor a dataset of this seed and these settings is refused; with `force`
    a new dataset is generated beside it and replaces it once complete (an interrupted forced run leaves
    the old folder as it was).

    backend "local": `workers` processes on this machine (None: 1). "ray": one Ray task per sequence on the
    cluster at `ray_address` (None: a Ray instance of `workers` CPUs started here), at most `workers`
    at a time (None: every CPU of the cluster); `shards` says who writes the files (ray_backend.py).
    The files are the same bytes whatever the backend and the number of workers."""
    root = Path(root)
    if backend not in BACKENDS:
        raise SpareTwinError(f"backend {backend!r}: choose {' or '.join(BACKENDS)}")
    check_workers(workers)
    check_count("instances", instances, MAX_INSTANCES, "sequence files are numbered with 6 digits")
    check_count("frames", cfg.frames, MAX_SEQUENCE_FRAMES, "the paper's sequences have 100")
    rig = cfg.rig
    # a worker holds its whole sequence in memory: depth (2 bytes), grey and labels (1 each) per pixel
    at_once = min(workers or 1, usable_cores()) if backend == "local" else 1
    check_fits_memory("frames", cfg.frames, rig.n_cameras * rig.height * rig.width * 4, copies=at_once)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise SpareTwinError(f"seed {seed}: must be a whole number, 0 or more")
    if ray_address is not None and backend != "ray":
        raise SpareTwinError("ray_address: only with backend ray")
    if shards not in SHARDS:
        raise SpareTwinError(f"shards {shards!r}: choose {' or '.join(SHARDS)}")
    here = Path.cwd().resolve()
    if root.resolve() == here or root.resolve() in here.parents:
        raise SpareTwinError(f"{root}: the current folder, or one around it, is no place for a dataset; name a new one")
    try:  # refuse before writing anything
        if root.exists() and not root.is_dir():
            raise OutputRefused(root, "exists and is not a folder", replaceable=True)
        if root.is_dir() and not _ours_or_empty(root):
            raise OutputRefused(root, "not empty and not a dataset folder (no dataset.json)", replaceable=True)
        _check_settings(root, seed, cfg, create=False)
    except SpareTwinError as exc:
        if not force:
            raise
        if isinstance(exc, OutputRefused) and not exc.replaceable:
            raise
        with writing(root, "dataset", force=True) as fresh:
            summary = generate_dataset(fresh, instances, seed, workers, cfg, progress, backend, ray_address, shards)
        return {**summary, "root": str(root), "replaced": True}
    seq_dir = root / "sequences"
    t0 = time.perf_counter()
    # Ray first: a cluster that cannot be reached leaves no folder behind
    ray = backend == "ray" and bool(_missing(seq_dir, instances, cfg))
    with RaySession(ray_address, workers) if ray else contextlib.nullcontext() as session:
        try:
            root.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise SpareTwinError(f"{root}: cannot create the dataset folder ({exc.strerror or exc})") from None
        todo, gen_s, manifest = _generate(root, instances, seed, workers, cfg, progress, backend, shards)
    images_per_seq = cfg.rig.n_cameras * cfg.frames
    return {
        "root": str(root),
        "instances": instances,
        "generated": len(todo),
        "already_present": instances - len(todo),
        "images": manifest["images"],
        "generated_images": len(todo) * images_per_seq,
        "generate_s": gen_s,
        "wall_s": time.perf_counter() - t0,
        "splits": manifest["splits"],
        "complete": manifest["complete"],
        "backend": backend,
        "connect_s": session.connect_s if ray else 0.0,
    }


def _shard_ok(seq_dir: Path, index: int, cfg: GenConfig, say: bool = False) -> bool:
    """Sequence `index`'s file exists and reads back (a truncated or garbled one does not count as done)."""
    path = seq_dir / sequence_filename(index)
    if not path.is_file():
        return False
    rig = cfg.rig
    problem = shard_problem(path, index, rig.n_cameras, cfg.frames, rig.height, rig.width, cfg.segmentation)
    if problem and say:
        print(f"note: {path}: does not read back ({problem}); rendering it again", file=sys.stderr)
    return problem is None


def _missing(seq_dir: Path, instances: int, cfg: GenConfig, say: bool = False) -> list[int]:
    return [i for i in range(instances) if not _shard_ok(seq_dir, i, cfg, say)]


def _generate(root: Path, instances, seed, workers, cfg: GenConfig, progress, backend, shards):
    """Under the folder's lock: render the missing sequences, then rebuild the manifest (also when cut short)."""
    from tqdm import tqdm

    seq_dir = root / "sequences"
    images_per_seq = cfg.rig.n_cameras * cfg.frames
    with _Lock(root):
        _check_settings(root, seed, cfg)  # dataset.json first: whatever else is here, the folder is a dataset
        seq_dir.mkdir(exist_ok=True)
        stale = [p for p in root.iterdir() if _OWN_TEMPORARIES.fullmatch(p.name) and p.is_file()]
        for path in [*stale, *seq_dir.glob(".seq-*.tmp*")]:  # left by a killed run
            path.unlink(missing_ok=True)
        todo = _missing(seq_dir, instances, cfg, say=True)
        if backend == "local":  # more processes than cores or than sequences only cost memory and start-up
            workers = cap_workers(workers or 1, max(1, len(todo)))
        bar = tqdm(
            total=len(todo),
            unit="seq",
            file=sys.stderr,
            disable=not progress or not todo,
            desc=f"dataset {root.name}",
            dynamic_ncols=True,
            smoothing=0.1,
        )
        t_gen = time.perf_counter()
        try:
            if backend == "local":
                done = run_local(todo, cfg, seed, seq_dir, workers or 1)
            else:
                done = run_ray(todo, cfg, seed, seq_dir, workers, shards)
            for _ in done if todo else ():
                bar.update(1)
                bar.set_postfix(img_s=f"{bar.n * images_per_seq / (time.perf_counter() - t_gen):.0f}")
        finally:
            bar.close()
            gen_s = time.perf_counter() - t_gen
            manifest = build_manifest(root, instances)
            write_json_atomic(root / "manifest.json", manifest)
    return todo, gen_s, manifest


def load_manifest(root: str | Path) -> dict:
    root = Path(root)
    m = read_json(root / "manifest.json")
    if m.get("format") != DATASET_FORMAT:
        raise SpareTwinError(f"{root / 'manifest.json'}: not a {DATASET_FORMAT} manifest")
    return m
