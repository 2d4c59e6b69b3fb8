"""Training the yaw-free profile network (`spare-twin train --preset profile-depth-multitask`).

The samples (`nets.profile_samples`) cost a full observation each (~0.1 s), far more than a training
step, so each split is observed once into a cache in the run folder (`samples-<split>.npz`, written
atomically; an interrupted run observes again only what is missing from a complete cache) and the
network then trains for many epochs on the cached profiles. Training samples get `variants`
different hand-held-like captures per rig time step; validation and test samples are the rig's
views as they are.

Several datasets can be given (e.g. a plain one and a `--sim2real` one with clutter); their splits
are concatenated.
"""

from __future__ import annotations

import json
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import h5py
import numpy as np
import torch
from torch import nn

from spare_twin.errors import SpareTwinError
from spare_twin.io import read_json, write_bytes_atomic, write_json_atomic
from spare_twin.nets import checkpoint as ckpt
from spare_twin.nets import metrics
from spare_twin.nets.models import build_model, decode
from spare_twin.nets.presets import Preset
from spare_twin.nets.profile_samples import CaptureAugment, stored_sample
from spare_twin.output import writing
from spare_twin.recording import npz_bytes


def _sequence_samples(job: tuple) -> dict:
    """Every sample of one sequence (runs in a worker process)."""
    path, seed, dataset_seed, index, times, variants, augment = job
    out = {"x": [], "n": [], "lengths": [], "angles": [], "rejected": 0}
    aug = CaptureAugment() if augment else None
    with h5py.File(path, "r") as f:
        for t in times:
            for v in range(variants):
                s = stored_sample(f, t, aug, np.random.default_rng([seed, dataset_seed, index, t, v]))
                if s.profile.reason is not None:
                    out["rejected"] += 1
                    continue
                out["x"].append(s.profile.image.astype(np.float16))
                out["n"].append(s.n_links)
                out["lengths"].append(s.lengths_pu)
                out["angles"].append(s.angles_rad)
    return out


def observe_split(
    data_dirs: list[Path],
    split: str,
    seed: int,
    variants: int,
    augment: bool,
    frame_stride: int = 1,
    workers: int = 1,
    progress: bool = True,
) -> dict[str, np.ndarray]:
    """Profiles and labels of one split of every dataset, in a fixed order (any `workers`)."""
    from tqdm import tqdm

    jobs = []
    for d in data_dirs:
        manifest = read_json(d / "manifest.json")
        frames = int(manifest["frames"])
        for row in manifest["sequences"]:
            if row["split"] == split:
                times = list(range(0, frames, frame_stride))
                jobs.append(
                    (str(d / row["file"]), seed, int(manifest.get("seed", 0)), row["index"], times, variants, augment)
                )
    if not jobs:
        raise SpareTwinError(f"data: no {split} sequences in {', '.join(map(str, data_dirs))}")
    parts = []
    bar = tqdm(total=len(jobs), desc=f"observe {split}", unit="seq", file=sys.stderr, disable=not progress)
    if workers > 1:
        with ProcessPoolExecutor(workers) as pool:
            for part in pool.map(_sequence_samples, jobs, chunksize=4):
                parts.append(part)
                bar.update()
    else:
        for job in jobs:
            parts.append(_sequence_samples(job))
            bar.update()
    bar.close()
    cat = {
        "x": np.stack([x for p in parts for x in p["x"]]),
        "n": np.array([n for p in parts for n in p["n"]], np.int64),
        "lengths": np.stack([x for p in parts for x in p["lengths"]]).astype(np.float32),
        "angles": np.stack([x for p in parts for x in p["angles"]]).astype(np.float32),
        "rejected": np.array(sum(p["rejected"] for p in parts), np.int64),
    }
    return cat


def cached_split(out_dir: Path, split: str, **kw) -> dict[str, np.ndarray]:
    path = out_dir / f"samples-{split}.npz"
    if path.is_file():
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    arrays = observe_split(split=split, **kw)
    write_bytes_atomic(path, npz_bytes(arrays))
    return arrays


def loss_of(out: dict, n: torch.Tensor, lengths: torch.Tensor, angles: torch.Tensor, tr) -> torch.Tensor:
    """Cross-entropy of the count + length_weight * squared error of the 7-slot lengths +
    angle_weight * squared error of (sin, cos) of the joints that exist."""
    loss = tr.count_weight * nn.functional.cross_entropy(out["count_logits"], n - 1)
    loss = loss + tr.length_weight * ((out["lengths"] - lengths) ** 2).sum(1).mean()
    if "angles_sincos" in out:
        target = torch.stack([torch.sin(angles), torch.cos(angles)], -1)
        exists = (torch.arange(angles.shape[1])[None] < n[:, None]).float()
        err = ((out["angles_sincos"] - target) ** 2).sum(-1) * exists
        loss = loss + tr.angle_weight * err.sum(1).mean()
    return loss


def scores(model, net, data: dict, batch_size: int = 256) -> dict:
    """Count accuracy, end-to-end E_L (paper units) and joint-angle error (deg, right counts) on cached samples."""
    model.eval()
    pred_n, pred_len, pred_ang = [], [], []
    with torch.no_grad():
        for i in range(0, len(data["n"]), batch_size):
            x = torch.from_numpy(data["x"][i : i + batch_size].astype(np.float32))
            res = decode(model, net, {"x": x})
            pred_n.append(res["pred_n"].numpy())
            pred_len.append(res["lengths_e2e"].numpy())
            pred_ang.append(res["angles"].numpy())
    pn, pl, pa = np.concatenate(pred_n), np.concatenate(pred_len), np.concatenate(pred_ang)
    n = data["n"]
    right = pn == n
    diff = np.abs((pa - data["angles"] + math.pi) % (2 * math.pi) - math.pi)
    exists = np.arange(6)[None] < n[:, None]
    ang = float(np.degrees(diff[right[:, None] & exists].mean())) if right.any() else float("nan")
    return {
        "count_accuracy": metrics.count_accuracy(n, pn),
        "E_L": float(metrics.length_errors(data["lengths"], pl, n, pn).mean()),
        "angle_error_deg": ang,
        "instances": int(len(n)),
    }


def train_profile(
    preset: Preset,
    data_dirs: list[str | Path],
    out_dir: str | Path,
    variants: int = 1,
    workers: int = 1,
    command: str = "",
    progress: bool = True,
    force: bool = False,
) -> dict:
    """Observe the splits once (cached), train, keep the best epoch by validation; writes model.pt and
    history.json into `out_dir` (the output rule of `spare_twin.output`: an interrupted run keeps its
    sample caches, and the next run starts from them) and returns the summary."""
    data_dirs = [Path(d) for d in data_dirs]
    for d in data_dirs:
        if not (d / "manifest.json").is_file():
            raise SpareTwinError(f"data_dir {d}: not a dataset (no manifest.json; make one with spare-twin dataset)")
    with writing(out_dir, "train", inputs=data_dirs, force=force, resumable=True) as run_dir:
        summary = _train_profile(preset, data_dirs, Path(run_dir), variants, workers, command, progress)
    return {k: v.replace(str(run_dir), str(out_dir)) if isinstance(v, str) else v for k, v in summary.items()}


def _train_profile(preset, data_dirs, out_dir: Path, variants, workers, command, progress) -> dict:
    from tqdm import tqdm

    net, tr = preset.net, preset.train
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    common = dict(out_dir=out_dir, data_dirs=data_dirs, seed=tr.seed, workers=workers, progress=progress)
    train = cached_split(split="train", variants=variants, augment=True, **common)
    val = cached_split(split="val", variants=1, augment=False, frame_stride=4, **common)
    observe_s = time.perf_counter() - t0
    torch.manual_seed(tr.seed)
    if tr.threads:
        torch.set_num_threads(tr.threads)
    model = build_model(net)
    opt = torch.optim.AdamW(model.parameters(), lr=tr.lr, weight_decay=tr.weight_decay)
    steps = tr.epochs * math.ceil(len(train["n"]) / tr.batch_size)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, tr.lr, total_steps=steps, pct_start=0.15)
    x_all = torch.from_numpy(train["x"].astype(np.float32))
    n_all, len_all = torch.from_numpy(train["n"]), torch.from_numpy(train["lengths"])
    ang_all = torch.from_numpy(train["angles"])
    history, best, best_score, best_epoch = [], None, -math.inf, 0
    t1 = time.perf_counter()
    gen = torch.Generator().manual_seed(tr.seed)
    for epoch in range(tr.epochs):
        model.train()
        order = torch.randperm(len(n_all), generator=gen)
        total = 0.0
        bar = tqdm(
            range(0, len(order), tr.batch_size),
            desc=f"epoch {epoch + 1}/{tr.epochs}",
            leave=False,
            file=sys.stderr,
            disable=not progress,
        )
        for i in bar:
            idx = order[i : i + tr.batch_size]
            out = model(x_all[idx])
            loss = loss_of(out, n_all[idx], len_all[idx], ang_all[idx], tr)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += loss.item() * len(idx)
        row = {
            "epoch": epoch + 1,
            "loss": total / len(n_all),
            **{f"val_{k}": v for k, v in scores(model, net, val).items()},
        }
        history.append(row)
        score = row["val_count_accuracy"] - row["val_E_L"]
        if score > best_score:
            best_score, best_epoch = score, epoch + 1
            best = {k: v.detach().clone() for k, v in model.state_dict().items()}
        print(json.dumps(row), file=sys.stderr)
    model.load_state_dict(best)
    train_s = time.perf_counter() - t1
    meta = ckpt.new_meta(",".join(map(str, data_dirs)), None, tr.seed, command)
    meta.update(
        {
            "input": "profile",
            "training_samples": int(len(n_all)),
            "rejected_samples": int(train["rejected"]),
            "observe_s": round(observe_s, 1),
            "train_time_s": round(train_s, 1),
            "variants": variants,
            "epochs_trained": tr.epochs,
            "parameters": sum(p.numel() for p in model.parameters()),
        }
    )
    ckpt.save(out_dir / "model.pt", ckpt.model_record(preset.name, net, tr, model, meta))
    write_json_atomic(out_dir / "history.json", {"history": history, "meta": meta})
    return {
        "model": str(out_dir / "model.pt"),
        "best_epoch": best_epoch,
        "train_time_s": train_s,
        "learning_curve": str(out_dir / "history.json"),
        "history": history,
        **meta,
    }
