"""The paper's metrics for a network on its own on a data split, and shipping an evaluated model to
models/.

`spare-twin evaluate` reports this beside the network's answer combined with the measurement, as
`predict` combines them (`spare_twin.predict.evaluate`, above nets, which ships through here).
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from spare_twin.errors import SpareTwinError
from spare_twin.io import write_json_atomic
from spare_twin.nets import checkpoint as ckpt
from spare_twin.nets import metrics
from spare_twin.nets.distributed import pick_device
from spare_twin.nets.evaluate_names import EVALUATE
from spare_twin.nets.plots import write_confusion_png
from spare_twin.nets.sample_sources import samples_of
from spare_twin.nets.train import run_inference, summarize
from spare_twin.output import writing


@dataclass(frozen=True)
class Evaluation:
    """A checkpoint's metrics on one split (E_L in paper units; the `evaluate --json` keys first)."""

    count_accuracy: float | None
    """None for a lengths-only model."""
    E_L: float | None
    """End-to-end where the model predicts the count, else with n known; None for a count-only model."""
    instances: int
    split: str
    E_L_end_to_end: float | None
    E_L_n_known: float | None
    per_n: dict
    model: str
    preset: str
    data: str
    confusion_matrix: list | None = None
    """6x6 counts, row = true n, column = predicted n (count models only)."""
    confusion_png: str | None = None
    shipped: str | None = None
    """The models/ file the evaluated checkpoint was shipped to, if it was."""
    predictions: dict = field(default_factory=dict, repr=False, compare=False)
    """Per test instance (numpy, not JSON): the predictions and labels `summarize` read, and the
    measurement (`measured_*`, `spare_twin.measure.slots`) where the samples hold one."""

    def to_json(self) -> dict:
        d = {
            "count_accuracy": self.count_accuracy,
            "E_L": self.E_L,
            "instances": self.instances,
            "split": self.split,
            "E_L_end_to_end": self.E_L_end_to_end,
            "E_L_n_known": self.E_L_n_known,
            "per_n": self.per_n,
            "model": self.model,
            "preset": self.preset,
        }
        optional = {"confusion_matrix": self.confusion_matrix, "confusion_png": self.confusion_png}
        d.update({k: v for k, v in optional.items() if v is not None})
        d["data"] = self.data
        if self.shipped is not None:
            d["shipped"] = self.shipped
        return d


def _check_count(name: str, value, optional: bool = False) -> None:
    if optional and value is None:
        return
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise SpareTwinError(f"{name} {value!r}: must be a whole number, at least 1")


def evaluation_of(pred: dict, split: str, model: str, preset: str, data: str) -> Evaluation:
    """The metrics of per-instance predictions (`run_inference`'s arrays); the confusion matrix where
    they hold a count."""
    res = summarize(pred)
    cm = metrics.confusion_matrix(pred["true_n"], pred["pred_n"]) if "pred_n" in pred else None
    return Evaluation(
        count_accuracy=res["count_accuracy"],
        E_L=res["E_L"],
        instances=res["instances"],
        split=split,
        E_L_end_to_end=res["E_L_end_to_end"],
        E_L_n_known=res["E_L_n_known"],
        per_n=res["per_n"],
        model=model,
        preset=preset,
        data=data,
        confusion_matrix=None if cm is None else cm.tolist(),
        predictions=pred,
    )


def write_outputs(ev: Evaluation, tmp: Path, out_dir: Path, name: str = "confusion_matrix.png") -> Evaluation:
    """`ev`'s confusion matrix as a PNG in `tmp` (the output being written, in place at `out_dir` once
    complete); `ev` with the path it will have."""
    if ev.confusion_matrix is None:
        return ev
    write_confusion_png(np.asarray(ev.confusion_matrix), tmp / name, f"{ev.preset} ({ev.split})")
    return replace(ev, confusion_png=str(Path(out_dir) / name))


def evaluate(
    model_path: str | Path | None,
    data_dir: str | Path,
    split: str = "test",
    device: str = "auto",
    batch_size: int = 16,
    out_dir: str | Path | None = None,
    max_samples: int | None = None,
    progress: bool = True,
    force: bool = False,
) -> Evaluation:
    """The network on its own: count accuracy, E_L (end-to-end where the model can, else n known),
    per-n breakdown and the confusion matrix (confusion_matrix.png and evaluation.json under
    `out_dir`) over `split`, on a seeded random subset of `max_samples` if given. No `model_path`:
    the shipped predict model. The samples come from the network's sample source (`nets.sample_sources`) (the
    profile network's: observed and measured once, in every core, and cached; see
    `nets.profile_train`); the measurement is carried in `predictions`, not applied.
    `out_dir` is an output (`spare_twin.output`): `force` replaces a folder that is not an earlier one."""
    _check_count("batch_size", batch_size)
    _check_count("max_samples", max_samples, optional=True)
    model_path = model_path or ckpt.default_model("predict")
    dev = pick_device(device)
    model, net, ck = ckpt.load_model(model_path, dev)
    ds = samples_of(net)([Path(data_dir)], split, net, None, None, progress)
    outputs = (
        contextlib.nullcontext(None)
        if out_dir is None
        else writing(out_dir, EVALUATE, (model_path, data_dir), force)  # checked before the inference
    )
    with outputs as tmp:
        if len(ds) == 0:
            raise SpareTwinError(f"data_dir {data_dir}: split {split!r} is empty")
        idx = None
        if max_samples is not None and max_samples < len(ds):
            idx = torch.randperm(len(ds), generator=torch.Generator().manual_seed(0))[:max_samples].tolist()
        carry = [k for k in ds[0] if k.startswith("measured_")]
        pred = run_inference(model, net, ds, dev, batch_size, idx, f"evaluate {split}", progress, carry)
        out = evaluation_of(pred, split, str(model_path), ck["preset"], str(data_dir))
        if tmp is not None:
            out = write_outputs(out, tmp, Path(out_dir))
            write_json_atomic(tmp / "evaluation.json", out.to_json())
    return out


#: The metrics of an evaluation that a shipped checkpoint records (its card and models/index.json show them).
RECORDED = ("count_accuracy", "E_L", "E_L_end_to_end", "E_L_n_known")


def recorded_metrics(result: Evaluation) -> dict:
    """`result`'s metrics as a checkpoint records them."""
    res = result.to_json()
    return {**{k: res[k] for k in RECORDED}, "instances": res["instances"], "split": res["split"], "data": result.data}


def record_metrics(model_path: str | Path, result: Evaluation | dict, command: str) -> None:
    """Store test metrics (an Evaluation, or `recorded_metrics`-like flat values) in the checkpoint's
    metadata (the model card reads them)."""
    ck = ckpt.load(model_path)
    ck["meta"]["metrics"] = recorded_metrics(result) if isinstance(result, Evaluation) else dict(result)
    ck["meta"]["evaluate_command"] = command
    ckpt.save(model_path, ck)


def ship_evaluated(
    model_path: str | Path,
    recorded: Evaluation | dict,
    ship: str,
    default_for: Sequence[str],
    command: str,
    models_dir: Path = ckpt.MODELS_DIR,
) -> Path:
    """Record the metrics (and `command`, how they were made) in a copy of the checkpoint and ship it
    to `models_dir` as <ship>.pt with a model card, the default model for the tasks in `default_for`.
    The checkpoint itself stays as training wrote it."""
    with tempfile.TemporaryDirectory() as tmp:
        staged = Path(tmp) / "model.pt"
        shutil.copyfile(model_path, staged)
        record_metrics(staged, recorded, command)
        return ckpt.ship(staged, ship, list(default_for), models_dir)
