"""Training: seeded, checkpointed every epoch (atomically), resumable, with a learning curve; in one
process or data-parallel under torchrun (DistributedDataParallel, see distributed.py).

RUN_DIR gets ``last.pt`` (full state: model, optimiser, epoch, history, RNG), ``best.pt`` /
``model.pt`` (the best epoch on validation, lean, with metadata), ``history.json``,
``learning_curve.png`` and ``MODEL_CARD.md``, all written by rank 0 alone.

Determinism: the model is initialised from ``torch.manual_seed(seed)`` (on every rank, so all start
equal); each epoch's sample order comes from a generator seeded with (seed, epoch), so a resumed run
sees the same batches as an uninterrupted one; the global RNG (dropout) is restored from ``last.pt``.
Data-parallel: a DistributedSampler deals that epoch order out to the N processes (rank r takes
items r, r + N, ...), the batch size is per process, and ranks other than 0 reseed their RNG from
(seed, epoch, rank) every epoch, so a resumed run repeats them too. With N = 1 the order, the RNG
stream and so the weights are those of a single process.
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.utils.data import DataLoader, DistributedSampler, Subset

from spare_twin.errors import SpareTwinError
from spare_twin.io import write_json_atomic
from spare_twin.nets import checkpoint as ckpt
from spare_twin.nets import metrics
from spare_twin.nets.data import dataset_rig, open_on_the_fly
from spare_twin.nets.distributed import Group, session
from spare_twin.nets.models import input_norms, model_inputs
from spare_twin.nets.presets import NetConfig, Preset, TrainConfig, net_from_dict
from spare_twin.nets.registry import architecture, build_model, decode
from spare_twin.nets.run_folder import replaceable, run_folder_problem
from spare_twin.nets.sample_sources import samples_of
from spare_twin.output import writing


def compute_loss(net: NetConfig, tr: TrainConfig, out: dict, batch: dict, device) -> torch.Tensor:
    """The task's loss. Lengths: squared error summed over the slots the true count uses (E_L's
    shape), or over all 7 zero-padded slots for the networks that regress them so (the registry's
    `regresses_padded_slots`). Joint angles: squared error of the angles, or of their (sin, cos)
    where the network predicts those (no jump at +-pi), over the joints that exist."""
    n = batch["n_links"].to(device)
    loss = torch.zeros((), device=device)
    if "count_logits" in out:
        loss = loss + tr.count_weight * nn.functional.cross_entropy(
            out["count_logits"], n - 1, label_smoothing=tr.label_smoothing
        )
    if "lengths" in out:
        target = batch["lengths_pu"].to(device, torch.float32)
        err = (out["lengths"] - target) ** 2
        if not architecture(net).regresses_padded_slots:
            err = err * (torch.arange(7, device=device)[None] <= n[:, None])
        loss = loss + tr.length_weight * err.sum(1).mean()
    if "angles" in out and "joint_angles_rad" in batch:
        ang = batch["joint_angles_rad"].to(device, torch.float32)
        if ang.dim() == 2:
            exists = torch.arange(6, device=device)[None] < n[:, None]
            if "angles_sincos" in out:
                err = ((out["angles_sincos"] - torch.stack([torch.sin(ang), torch.cos(ang)], -1)) ** 2).sum(-1)
            else:
                err = (out["angles"] - ang) ** 2
            loss = loss + tr.angle_weight * (err * exists).sum(1).mean()
    return loss


def to_channels_last(model: nn.Module) -> nn.Module:
    """`model` with its convolutions' weights in channels-last layout (activations follow them)."""
    for m in model.modules():
        if isinstance(m, nn.Conv2d):
            m.to(memory_format=torch.channels_last)
        elif isinstance(m, nn.Conv3d):
            m.to(memory_format=torch.channels_last_3d)
    return model


#: Gradients are clipped to this global norm before every step.
MAX_GRAD_NORM = 5.0


def train_step(model, net: NetConfig, tr: TrainConfig, opt, batch: dict, device, schedule=None) -> torch.Tensor:
    """One optimiser step on `batch` (forward, loss, backward, clipping, step, and the learning-rate
    `schedule`'s step where it moves per batch); returns the loss."""
    loss = compute_loss(net, tr, forward_train(model, net, batch, device), batch, device)
    opt.zero_grad(set_to_none=True)
    loss.backward()
    nn.utils.clip_grad_norm_(model.parameters(), MAX_GRAD_NORM)
    opt.step()
    if schedule is not None:
        schedule.step()
    return loss


def forward_train(model, net: NetConfig, batch: dict, device) -> dict:
    inputs = model_inputs(batch, device)
    if architecture(net).takes_count:  # regressors are routed by the true count in training
        return model(**inputs, n_links=batch["n_links"].to(device))
    return model(**inputs)


@torch.no_grad()
def measure_normalization(model, ds, seed: int, samples: int = 64) -> None:
    """Input mean / std over a few training samples, stored in the model's InputNorm buffers."""
    norms = input_norms(model)
    if not norms:
        return
    idx = torch.randperm(len(ds), generator=torch.Generator().manual_seed(seed))[:samples].tolist()
    xs = torch.stack([ds[i]["x"].float() for i in idx])
    mean, std = xs.mean(), xs.std().clamp_min(1e-6)
    for m in norms:
        m.mean.fill_(mean)
        m.std.fill_(std)


@torch.no_grad()
def run_inference(
    model, net: NetConfig, ds, device, batch_size: int, indices=None, desc: str = "eval", progress=True, carry=()
) -> dict:
    """Predictions and labels over (a subset of) a dataset: numpy arrays for metrics.py, with the
    samples' fields named in `carry` beside them (e.g. the measurement a sample holds)."""
    from tqdm import tqdm

    model.eval()
    sub = ds if indices is None else Subset(ds, indices)
    loader = DataLoader(sub, batch_size=batch_size, shuffle=False)
    acc: dict[str, list] = {}
    for batch in tqdm(loader, desc=desc, leave=False, file=sys.stderr, disable=not progress):
        n = batch["n_links"].to(device)
        res = decode(model, net, model_inputs(batch, device), true_n=n)
        res.update({k: batch[k] for k in carry})
        res["true_n"] = n
        res["true_lengths"] = batch["lengths_pu"]
        for k, v in res.items():
            acc.setdefault(k, []).append(v.detach().cpu().numpy())
    return {k: np.concatenate(v) for k, v in acc.items()}


def summarize(pred: dict) -> dict:
    """The paper's metrics from run_inference output (None where the model does not predict it)."""
    out: dict = {"instances": int(len(pred["true_n"]))}
    out["count_accuracy"] = metrics.count_accuracy(pred["true_n"], pred["pred_n"]) if "pred_n" in pred else None
    e2e = known = None
    if "lengths_e2e" in pred:
        e2e = metrics.length_errors(pred["true_lengths"], pred["lengths_e2e"], pred["true_n"], pred["pred_n"])
    if "lengths_known" in pred:
        known = metrics.length_errors(pred["true_lengths"], pred["lengths_known"], pred["true_n"])
    # E_L: the end-to-end number where the model can give one, else the n-known one.
    main = e2e if e2e is not None else known
    out["E_L"] = float(main.mean()) if main is not None else None
    out["E_L_end_to_end"] = float(e2e.mean()) if e2e is not None else None
    out["E_L_n_known"] = float(known.mean()) if known is not None else None
    out["per_n"] = metrics.per_n_breakdown(pred["true_n"], pred.get("pred_n"), main)
    return out


@torch.no_grad()
def recalibrate_batchnorm(model: nn.Module, net: NetConfig, ds, samples: int, batch_size: int, seed: int, dev) -> None:
    """Recompute every BatchNorm's running mean and variance as the plain average over `samples` items
    of `ds` (a fixed subset seeded by `seed`), the model in training mode. Only buffers change, and the
    global RNG is restored afterwards, so the training that follows is the same as without this."""
    bns = [m for m in model.modules() if isinstance(m, nn.modules.batchnorm._BatchNorm)]
    if not bns:
        return
    momenta = [m.momentum for m in bns]
    for m in bns:
        m.reset_running_stats()
        m.momentum = None  # a cumulative average over the batches below
    idx = torch.randperm(len(ds), generator=torch.Generator().manual_seed(seed))[:samples].tolist()
    was_training = model.training
    model.train()
    with torch.random.fork_rng():
        for batch in DataLoader(Subset(ds, idx), batch_size=batch_size):
            if batch["x"].shape[0] > 1:
                forward_train(model, net, batch, dev)
    for m, momentum in zip(bns, momenta):
        m.momentum = momentum
    model.train(was_training)


def _score(m: dict) -> float:
    s = 0.0
    if m.get("count_accuracy") is not None:
        s += m["count_accuracy"]
    if m.get("E_L") is not None:
        s -= m["E_L"]
    return s


def _row_score(row: dict) -> float:
    """An epoch's score from its history row: `_score` of its validation metrics, or minus the
    training loss where there was no validation (the same rule that picks best.pt)."""
    val = {k[4:]: v for k, v in row.items() if k.startswith("val_")}
    return _score(val) if val else -(row["train_loss"] or 0.0)


def epochs_since_best(history: list[dict]) -> int:
    """Epochs run since the best one (0: the last epoch is the best so far)."""
    scores = [_row_score(r) for r in history]
    return len(scores) - 1 - int(np.argmax(scores)) if scores else 0


def _epoch_indices(n_data: int, tr: TrainConfig, epoch: int) -> list[int]:
    g = torch.Generator().manual_seed(tr.seed * 100_003 + epoch)
    if tr.samples_per_epoch is None:
        return torch.randperm(n_data, generator=g).tolist()
    k = tr.samples_per_epoch
    if k <= n_data:
        return torch.randperm(n_data, generator=g)[:k].tolist()
    return torch.randint(0, n_data, (k,), generator=g).tolist()


def _has_batchnorm(model) -> bool:
    return any(isinstance(m, nn.modules.batchnorm._BatchNorm) for m in model.modules())


def _epoch_loader(train_src, data_dir, net, tr: TrainConfig, epoch: int, on_the_fly: bool, group: Group):
    """This process's share of epoch `epoch`: (loader, batches to take). Every rank takes the same number
    of batches of the same sizes, so no rank waits in a gradient all-reduce that another skipped."""
    # observed samples are in memory already: loader processes would only copy them
    workers = 0 if architecture(net).observed_samples else tr.workers
    if on_the_fly:
        n_ep = tr.samples_per_epoch or len(train_src)
        src = open_on_the_fly(
            data_dir, net, tr.seed * 100_003 + epoch, n_ep, augment=tr, rank=group.rank, world_size=group.world_size
        )
        per_rank = -(-n_ep // group.world_size)
        return DataLoader(src, batch_size=tr.batch_size, num_workers=tr.workers), math.ceil(per_rank / tr.batch_size)
    subset = Subset(train_src, _epoch_indices(len(train_src), tr, epoch))
    # shuffle=False: the order is the seeded epoch order above; rank r takes items r, r + N, ...
    sampler = DistributedSampler(subset, num_replicas=group.world_size, rank=group.rank, shuffle=False)
    loader = DataLoader(
        subset,
        batch_size=tr.batch_size,
        sampler=sampler,
        num_workers=workers,
        drop_last=len(sampler) > tr.batch_size,
    )
    return loader, len(loader)


def _start(data_dirs: list[Path], out_dir: Path, resume: bool, group: Group) -> dict | None:
    """Rank 0 checks the run folder, creates it or reads last.pt (on resume); every rank gets the state or
    the error."""
    error, state = None, None
    if group.is_main:
        error = run_folder_problem(out_dir, data_dirs, resume)
        if error is None and resume:
            try:
                state = ckpt.load(out_dir / "last.pt", "cpu")
            except SpareTwinError as exc:
                error = str(exc)
        elif error is None:
            try:
                out_dir.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                error = f"out_dir {out_dir}: cannot create it ({exc.strerror or exc})"
    group.raise_together(error)
    return group.broadcast(state)


def train(
    preset: Preset,
    data_dir,
    out_dir,
    device: str = "auto",
    on_the_fly: bool = False,
    resume: bool = False,
    command: str = "",
    progress: bool = True,
    force: bool = False,
) -> dict:
    """Train `preset` on `data_dir` (a dataset folder, or a list of them for a network that takes
    several) into `out_dir`: in this process, or as one rank of a torchrun group (every rank returns
    rank 0's summary). Every architecture trains through this one loop (`nets.registry` says where
    its samples come from).

    `out_dir` must be absent, empty or (with `resume`) a run to continue; with `force`, a folder that is
    none of these (another run, a folder of yours) is replaced by the new run once it is complete: rank 0
    trains in a hidden sibling folder and swaps it in at the end, so an interrupted run leaves it whole."""
    out_dir = Path(out_dir)
    data_dirs = [Path(d) for d in (data_dir if isinstance(data_dir, (list, tuple)) else [data_dir])]
    arch = architecture(preset.net)
    if not data_dirs or (len(data_dirs) > 1 and not arch.several_datasets):
        raise SpareTwinError(f"data_dir {','.join(map(str, data_dirs))}: the {arch.name} network trains on one dataset")
    if on_the_fly and arch.observed_samples:
        raise SpareTwinError(f"on_the_fly: the {arch.name} network trains on samples it observes once, not on the fly")
    with session(device) as (group, dev):
        if force and not resume and group.is_main and replaceable(out_dir, data_dirs):
            with writing(out_dir, "train", inputs=data_dirs, force=True) as fresh:
                summary = _train(preset, data_dirs, fresh, dev, group, on_the_fly, resume, command, progress)
            return {k: v.replace(str(fresh), str(out_dir)) if isinstance(v, str) else v for k, v in summary.items()}
        return _train(preset, data_dirs, out_dir, dev, group, on_the_fly, resume, command, progress)


def _same_net(checkpoint: dict, net: NetConfig) -> bool:
    """The checkpoint's network configuration is `net` (fields it predates take their defaults)."""
    try:
        return net_from_dict(checkpoint.get("net") or {}) == net
    except SpareTwinError:
        return False


def _open_sources(net: NetConfig, tr: TrainConfig, data_dirs: list[Path], out_dir: Path, main: bool, progress: bool):
    """(training samples, validation samples or None): the architecture's sample source, before the run
    folder is touched (a bad data folder is refused first). Samples observed into the run folder are
    observed later, by `_observe_sources`."""
    samples = samples_of(net)
    train_src = samples(data_dirs, "train", net, tr, out_dir, progress)  # with on_the_fly: only its size is used
    val_ds = None
    if main:
        try:
            val_ds = samples(data_dirs, "val", net, tr, out_dir, progress)
        except SpareTwinError:
            val_ds = None  # a folder without a validation split: select on the training loss instead
    return train_src, val_ds


def _observe_sources(net: NetConfig, train_src, val_ds, group: Group):
    """Rank 0 observes (or reads back) the samples of a network that observes its own, into the run
    folder; then every other rank reads them from there. Returns the validation samples, None where
    the data holds no validation split (select on the training loss then)."""
    if not architecture(net).observed_samples:
        return val_ds
    if group.is_main:
        train_src.prepare()
        try:
            if val_ds is not None:
                val_ds.prepare()
        except SpareTwinError:
            val_ds = None
    group.barrier()
    train_src.prepare()
    return val_ds


#: The share of a one-cycle run spent raising the learning rate.
ONE_CYCLE_WARMUP = 0.15


def _one_cycle(opt, tr: TrainConfig, steps_per_epoch: int):
    """`train.lr_schedule` "one_cycle": torch's OneCycleLR over the whole run, stepped per batch (its
    state goes into last.pt, so a resumed run goes on with the same rates). The default, "cosine",
    is set per epoch in the loop."""
    total = max(tr.epochs * steps_per_epoch, 1)
    return torch.optim.lr_scheduler.OneCycleLR(opt, tr.lr, total_steps=total, pct_start=ONE_CYCLE_WARMUP)


def _train(preset, data_dirs, out_dir: Path, dev, group: Group, on_the_fly, resume, command, progress) -> dict:
    from tqdm import tqdm

    net, tr = preset.net, preset.train
    main = group.is_main
    progress = progress and main
    if tr.threads:
        torch.set_num_threads(tr.threads)
    last_path = out_dir / "last.pt"
    data_dir = data_dirs[0] if len(data_dirs) == 1 else None
    train_src, val_ds = _open_sources(net, tr, data_dirs, out_dir, main, progress)
    state = _start(data_dirs, out_dir, resume, group)
    val_ds = _observe_sources(net, train_src, val_ds, group)

    torch.manual_seed(tr.seed)
    np.random.seed(tr.seed)
    model = build_model(net).to(dev)
    opt = torch.optim.AdamW(model.parameters(), lr=tr.lr, weight_decay=tr.weight_decay)
    schedule = None
    if tr.lr_schedule == "one_cycle":
        steps_per_epoch = _epoch_loader(train_src, data_dir, net, tr, 0, on_the_fly, group)[1]
        schedule = _one_cycle(opt, tr, steps_per_epoch)
    meta = ckpt.new_meta(",".join(map(str, data_dirs)), dataset_rig(data_dir) if data_dir else None, tr.seed, command)
    meta["parameters"] = int(sum(p.numel() for p in model.parameters()))
    meta["on_the_fly"] = bool(on_the_fly)
    if architecture(net).observed_samples:
        meta.update(training_samples=len(train_src), rejected_samples=train_src.rejected)
    if group.world_size > 1:
        meta["data_parallel_processes"] = group.world_size
    history: list[dict] = []
    start_epoch, best_score, train_time_s = 0, -math.inf, 0.0

    if state is not None:
        if state.get("preset") != preset.name or not _same_net(state, net):
            raise SpareTwinError(f"resume: {last_path} was trained with a different network configuration")
        model.load_state_dict(state["state_dict"])
        opt.load_state_dict(state["optimizer"])  # after the schedule is made: its rates are the run's
        if schedule is not None:
            schedule.load_state_dict(state["scheduler"])
        if main:
            torch.set_rng_state(state["rng"])
        history, start_epoch = state["history"], state["epoch"] + 1
        best_score, train_time_s = state["best_score"], state["train_time_s"]
        meta = state["meta"]
    elif tr.init_from:
        start = ckpt.load(tr.init_from, dev)
        if not _same_net(start, net):
            raise SpareTwinError(f"init_from {tr.init_from}: trained with a different network configuration")
        model.load_state_dict(start["state_dict"])  # its input normalisation comes with it
        meta["init_from"] = {
            "path": str(tr.init_from),
            "preset": start.get("preset"),
            "epochs_trained": start.get("meta", {}).get("epochs_trained"),
        }
    else:
        measure_normalization(model, train_src, tr.seed)

    if tr.channels_last:
        model = to_channels_last(model)
    core = model  # the module itself: validated and saved; `model` is what trains (DDP-wrapped in a group)
    if group.active:
        # Some heads get no gradient on some batches (per-count regressors, angles of temporal input).
        model = nn.parallel.DistributedDataParallel(
            core, device_ids=[dev.index] if dev.type == "cuda" else None, find_unused_parameters=True
        )

    val_idx = None
    if val_ds is not None and tr.val_samples is not None and tr.val_samples < len(val_ds):
        val_idx = torch.randperm(len(val_ds), generator=torch.Generator().manual_seed(tr.seed + 1))[
            : tr.val_samples
        ].tolist()

    writer = (
        _RunWriter(preset, core, opt, schedule, val_ds, val_idx, dev, out_dir, progress, train_src) if main else None
    )
    for epoch in range(start_epoch, tr.epochs):
        if tr.patience is not None and group.broadcast(epochs_since_best(history) if main else None) >= tr.patience:
            if progress:
                print(f"stopping early: validation has not improved for {tr.patience} epochs", file=sys.stderr)
            break
        t0 = time.time()
        if group.rank:
            torch.manual_seed(tr.seed * 1_000_003 + epoch * 1_009 + group.rank)
        if schedule is None:
            lr = tr.lr * 0.5 * (1 + math.cos(math.pi * epoch / tr.epochs))  # cosine, recomputed: resume-safe
            for g in opt.param_groups:
                g["lr"] = lr
        else:
            lr = opt.param_groups[0]["lr"]  # the one-cycle rate at the epoch's first step
        loader, n_batches = _epoch_loader(train_src, data_dir, net, tr, epoch, on_the_fly, group)
        model.train()
        losses = []
        bar = tqdm(
            total=n_batches, desc=f"epoch {epoch + 1}/{tr.epochs}", file=sys.stderr, disable=not progress, leave=False
        )
        for b, batch in enumerate(loader):
            if b >= n_batches:
                break
            if batch["x"].shape[0] < 2 and _has_batchnorm(core):
                continue  # BatchNorm cannot train on a batch of one (the same batch on every rank)
            loss = train_step(model, net, tr, opt, batch, dev, schedule)
            losses.append(float(loss.detach()))
            bar.update(1)
            bar.set_postfix(loss=f"{np.mean(losses[-20:]):.4f}")
        bar.close()
        if group.world_size > 1:
            total, count = group.sum(sum(losses), len(losses))
            train_loss = total / count if count else None
        else:
            train_loss = float(np.mean(losses)) if losses else None
        train_time_s += time.time() - t0
        if main:
            row = {"epoch": epoch + 1, "lr": lr, "train_loss": train_loss, "time_s": time.time() - t0}
            best_score = writer.end_epoch(row, history, meta, best_score, train_time_s)
        group.barrier()  # rank 0 has written this epoch's checkpoint

    summary = _finish(preset, out_dir, history, train_time_s) if main else None
    return group.broadcast(summary)


class _RunWriter:
    """Rank 0's side of every epoch: validate, keep the best model, write last.pt, the history and the curve."""

    def __init__(self, preset: Preset, core, opt, schedule, val_ds, val_idx, dev, out_dir: Path, progress, train_ds):
        self.preset, self.core, self.opt, self.dev, self.train_ds = preset, core, opt, dev, train_ds
        self.schedule = schedule
        self.val_ds, self.val_idx, self.out_dir, self.progress = val_ds, val_idx, out_dir, progress

    def end_epoch(self, row: dict, history: list, meta: dict, best_score: float, train_time_s: float) -> float:
        net, tr, core, out_dir = self.preset.net, self.preset.train, self.core, self.out_dir
        epoch = row["epoch"] - 1
        if tr.bn_recalibration_samples:
            recalibrate_batchnorm(
                core, net, self.train_ds, tr.bn_recalibration_samples, tr.batch_size, tr.seed + 2, self.dev
            )
        if self.val_ds is not None:
            pred = run_inference(
                core, net, self.val_ds, self.dev, tr.batch_size, self.val_idx, "validate", self.progress
            )
            m = summarize(pred)
            row.update({f"val_{k}": v for k, v in m.items() if k != "per_n" and v is not None and k != "instances"})
        score = _row_score(row)
        history.append(row)
        meta.update(epochs_trained=epoch + 1, train_time_s=train_time_s)
        name = self.preset.name
        if score > best_score:
            best_score = score
            val = {k: v for k, v in row.items() if k.startswith("val_")}
            best = ckpt.model_record(name, net, tr, core, dict(meta, best_epoch=epoch + 1, val_metrics=val))
            ckpt.save(out_dir / "best.pt", best)
        state = ckpt.model_record(name, net, tr, core, meta)
        state.update(
            optimizer=self.opt.state_dict(),
            epoch=epoch,
            history=history,
            rng=torch.get_rng_state(),
            best_score=best_score,
            train_time_s=train_time_s,
        )
        if self.schedule is not None:
            state["scheduler"] = self.schedule.state_dict()
        ckpt.save(out_dir / "last.pt", state)  # written last: a crash before here repeats this epoch on resume
        write_json_atomic(out_dir / "history.json", history)
        metrics.write_learning_curve_png(history, out_dir / "learning_curve.png", name)
        shown = {
            k: round(v, 4)
            for k, v in row.items()
            if k in ("train_loss", "val_count_accuracy", "val_E_L") and v is not None
        }
        print(f"epoch {epoch + 1}/{tr.epochs} {json.dumps(shown)} ({row['time_s']:.0f} s)", file=sys.stderr)
        return best_score


def _finish(preset, out_dir: Path, history: list, train_time_s: float) -> dict:
    """Rank 0: model.pt (the best epoch, with the final training time in its metadata) and its card."""
    best = ckpt.load(out_dir / "best.pt")
    best["meta"].update(train_time_s=train_time_s, epochs_trained=len(history))
    ckpt.save(out_dir / "model.pt", best)
    ckpt.write_card(out_dir / "model.pt", out_dir / "MODEL_CARD.md", preset.name)
    return {
        "run_dir": str(out_dir),
        "model": str(out_dir / "model.pt"),
        "preset": preset.name,
        "epochs": len(history),
        "best_epoch": best["meta"].get("best_epoch"),
        "train_time_s": round(train_time_s, 1),
        "val": best["meta"].get("val_metrics", {}),
        "learning_curve": str(out_dir / "learning_curve.png"),
    }
