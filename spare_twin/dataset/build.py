"""Generate, resume and extend a dataset folder in parallel.

    DATA_DIR/dataset.json        the generation settings (seed, GenConfig): fixed at creation
    DATA_DIR/manifest.json       per sequence: index, file, n_links, link_lengths_pu, chain_seed, split
    DATA_DIR/sequences/seq-NNNNNN.h5   one sequence each (schema in store.py)

Every sequence is a pure function of (seed, index, settings), each file is written under a temporary
name and renamed, and the manifest is rebuilt from the finished files at the end of every run. So a
run killed at any moment (kill -9 included) is finished by running the same command again, and a
larger --instances on the same folder only adds the missing sequences.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from spare_twin.dataset.generate import SPLITS, GenConfig, _seeds, n_links_of, render_sequence, sequence_spec, split_of
from spare_twin.dataset.store import sequence_filename, write_sequence
from spare_twin.errors import SpareTwinError
from spare_twin.io import read_json, write_json_atomic

DATASET_FORMAT = "spare-twin-dataset/1"


@dataclass(frozen=True)
class Preset:
    """A named dataset size and seed."""

    instances: int
    seed: int = 0
    frames: int = 100


#: paper: 324 sequences x 8 cameras x 100 frames = 259,200 images (153,600 / 28,800 / 76,800).
PRESETS = {"paper": Preset(instances=324), "small": Preset(instances=36), "tiny": Preset(instances=6, frames=20)}


# -- worker side -----------------------------------------------------------------------------
_W: dict = {}


def _init_worker(cfg_dict: dict, seed: int, seq_dir: str) -> None:
    import cv2  # noqa: F401  (imported here so the first sequence does not pay for it)
    import h5py  # noqa: F401

    from spare_twin.sim.twin import Twin

    _W["cfg"] = GenConfig.from_dict(cfg_dict)
    _W["seed"] = seed
    _W["seq_dir"] = Path(seq_dir)
    _W["twin"] = Twin()
    _W["work"] = Path(tempfile.mkdtemp(prefix="spare-twin-gen-"))


def _work(index: int) -> int:
    seq = render_sequence(_W["cfg"], _W["seed"], index, _W["twin"], _W["work"])
    write_sequence(_W["seq_dir"] / sequence_filename(index), seq, fps=_W["cfg"].fps)
    return index


def _close_worker() -> None:
    if "twin" in _W:
        _W.pop("twin").close()
        shutil.rmtree(_W.pop("work"), ignore_errors=True)


# -- driver side -----------------------------------------------------------------------------
class _Lock:
    """DATA_DIR/.lock holding the writer's pid; a lock whose process is gone (killed) is taken over."""

    def __init__(self, root: Path):
        self.path = root / ".lock"

    def __enter__(self):
        if self.path.exists():
            try:
                pid = int(self.path.read_text().strip() or 0)
            except ValueError:
                pid = 0
            if pid and pid != os.getpid() and _alive(pid):
                raise SpareTwinError(f"{self.path.parent}: another spare-twin dataset (pid {pid}) is writing it")
        self.path.write_text(str(os.getpid()))
        return self

    def __exit__(self, *exc):
        self.path.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:  # a zombie (killed, not yet reaped) is not a writer
        return " Z " not in Path(f"/proc/{pid}/stat").read_text().split(")", 1)[1][:4]
    except OSError:
        return True


def _check_settings(root: Path, seed: int, cfg: GenConfig) -> None:
    path = root / "dataset.json"
    want = {"format": DATASET_FORMAT, "seed": int(seed), "generator": cfg.to_dict()}
    if not path.exists():
        write_json_atomic(path, want)
        return
    have = read_json(path)
    if have.get("format") != DATASET_FORMAT:
        raise SpareTwinError(f"{path}: not a {DATASET_FORMAT} folder")
    if have.get("seed") != want["seed"]:
        raise SpareTwinError(
            f"{root} was generated with --seed {have.get('seed')}; use it to resume or extend, or a new --out"
        )
    if have.get("generator") != json.loads(json.dumps(want["generator"])):
        diff = sorted(
            k
            for k in want["generator"]
            if have.get("generator", {}).get(k) != json.loads(json.dumps(want["generator"][k]))
        )
        raise SpareTwinError(
            f"{root} was generated with other settings ({', '.join(diff)}); use the same options or a new --out"
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
        if not f.is_file():
            continue
        spec = sequence_spec(seed, i)
        rows.append(
            {
                "index": i,
                "file": f"sequences/{f.name}",
                "n_links": spec.n_links,
                "link_lengths_m": list(spec.link_lengths_pu),
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
    workers: int = 1,
    cfg: GenConfig = GenConfig(),
    progress: bool = True,
) -> dict:
    """Generate (or resume, or extend) the dataset at `root`; returns a summary with timings."""
    from tqdm import tqdm

    root = Path(root)
    if instances < 1:
        raise SpareTwinError("--instances must be at least 1")
    if workers < 1:
        raise SpareTwinError("--workers must be at least 1")
    if root.exists() and not root.is_dir():
        raise SpareTwinError(f"{root}: exists and is not a folder")
    if root.is_dir() and any(root.iterdir()) and not (root / "dataset.json").exists():
        raise SpareTwinError(f"{root}: not empty and not a dataset folder (no dataset.json)")
    seq_dir = root / "sequences"
    seq_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with _Lock(root):
        _check_settings(root, seed, cfg)
        for stale in seq_dir.glob(".seq-*.tmp-*"):  # left by a killed run
            stale.unlink(missing_ok=True)
        todo = [i for i in range(instances) if not (seq_dir / sequence_filename(i)).is_file()]
        done_before = instances - len(todo)
        images_per_seq = cfg.rig.n_cameras * cfg.frames
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
            if workers == 1 or len(todo) <= 1:
                _init_worker(cfg.to_dict(), seed, str(seq_dir))
                try:
                    for i in todo:
                        _work(i)
                        bar.update(1)
                        bar.set_postfix(img_s=f"{bar.n * images_per_seq / (time.perf_counter() - t_gen):.0f}")
                finally:
                    _close_worker()
            else:
                ctx = mp.get_context("spawn")  # pybullet clients must not be forked
                with ctx.Pool(workers, initializer=_init_worker, initargs=(cfg.to_dict(), seed, str(seq_dir))) as pool:
                    for _ in pool.imap_unordered(_work, todo, chunksize=1):
                        bar.update(1)
                        bar.set_postfix(img_s=f"{bar.n * images_per_seq / (time.perf_counter() - t_gen):.0f}")
        finally:
            bar.close()
            gen_s = time.perf_counter() - t_gen
            manifest = build_manifest(root, instances)
            write_json_atomic(root / "manifest.json", manifest)
    return {
        "root": str(root),
        "instances": instances,
        "generated": len(todo),
        "already_present": done_before,
        "images": manifest["images"],
        "generated_images": len(todo) * images_per_seq,
        "generate_s": gen_s,
        "wall_s": time.perf_counter() - t0,
        "splits": manifest["splits"],
        "complete": manifest["complete"],
    }


def load_manifest(root: str | Path) -> dict:
    root = Path(root)
    m = read_json(root / "manifest.json")
    if m.get("format") != DATASET_FORMAT:
        raise SpareTwinError(f"{root / 'manifest.json'}: not a {DATASET_FORMAT} manifest")
    return m


def n_links_balance(instances: int) -> dict[int, int]:
    out: dict[int, int] = {}
    for i in range(instances):
        out[n_links_of(i)] = out.get(n_links_of(i), 0) + 1
    return out
