"""The paper's metrics for a checkpoint on a data split, and shipping an evaluated model to models/.

`spare-twin evaluate` is a thin adapter over `evaluate_model`.
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import torch

from spare_twin.errors import SpareTwinError
from spare_twin.io import write_json_atomic
from spare_twin.nets import checkpoint as ckpt
from spare_twin.nets import metrics
from spare_twin.nets.data import open_split
from spare_twin.nets.distributed import pick_device
from spare_twin.nets.plots import write_confusion_png
from spare_twin.nets.train import run_inference, summarize
from spare_twin.output import writing

#: The output kind of `out_dir` (`spare_twin.output`).
EVALUATE = "evaluate"


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
    """Count accuracy, E_L (end-to-end where the model can, else n known), per-n breakdown and the
    confusion matrix (confusion_matrix.png and evaluation.json under `out_dir`) over `split`, on a
    seeded random subset of `max_samples` if given. No `model_path`: the shipped predict model.
    `out_dir` is an output (`spare_twin.output`): `force` replaces a folder that is not an earlier one."""
    _check_count("batch_size", batch_size)
    _check_count("max_samples", max_samples, optional=True)
    model_path = model_path or ckpt.default_model("predict")
    dev = pick_device(device)
    model, net, ck = ckpt.load_model(model_path, dev)
    ds = open_split(data_dir, split, net)
    if len(ds) == 0:
        raise SpareTwinError(f"data_dir {data_dir}: split {split!r} is empty")
    outputs = (
        contextlib.nullcontext(None)
        if out_dir is None
        else writing(out_dir, EVALUATE, (model_path, data_dir), force)  # checked before the inference
    )
    with outputs as tmp:
        idx = None
        if max_samples is not None and max_samples < len(ds):
            idx = torch.randperm(len(ds), generator=torch.Generator().manual_seed(0))[:max_samples].tolist()
        pred = run_inference(model, net, ds, dev, batch_size, idx, f"evaluate {split}", progress)
        res = summarize(pred)
        cm = png = None
        if "pred_n" in pred:
            cm = metrics.confusion_matrix(pred["true_n"], pred["pred_n"])
            if tmp is not None:
                write_confusion_png(cm, tmp / "confusion_matrix.png", f"{ck['preset']} ({split})")
                png = Path(out_dir) / "confusion_matrix.png"  # where it is once the output is in place
        out = Evaluation(
            count_accuracy=res["count_accuracy"],
            E_L=res["E_L"],
            instances=res["instances"],
            split=split,
            E_L_end_to_end=res["E_L_end_to_end"],
            E_L_n_known=res["E_L_n_known"],
            per_n=res["per_n"],
            model=str(model_path),
            preset=ck["preset"],
            data=str(data_dir),
            confusion_matrix=None if cm is None else cm.tolist(),
            confusion_png=None if png is None else str(png),
        )
        if tmp is not None:
            write_json_atomic(tmp / "evaluation.json", out.to_json())
    return out


def record_metrics(model_path: str | Path, result: Evaluation, command: str) -> None:
    """Store test metrics in the checkpoint's metadata (the model card reads them)."""
    ck = ckpt.load(model_path)
    res = result.to_json()
    keep = ("count_accuracy", "E_L", "E_L_end_to_end", "E_L_n_known", "instances", "split")
    ck["meta"]["metrics"] = {k: res[k] for k in keep}
    ck["meta"]["metrics"]["data"] = result.data
    ck["meta"]["evaluate_command"] = command
    ckpt.save(model_path, ck)


def evaluate_model(
    model_path: str | Path | None,
    data_dir: str | Path,
    split: str = "test",
    device: str = "auto",
    batch_size: int = 16,
    out_dir: str | Path | None = None,
    max_samples: int | None = None,
    ship: str | None = None,
    default_for: Sequence[str] = (),
    command: str = "",
    models_dir: Path = ckpt.MODELS_DIR,
    progress: bool = True,
    force: bool = False,
) -> Evaluation:
    """`evaluate`, then with `ship`: record the metrics (and `command`, how they were made) in a copy
    of the checkpoint and ship it to `models_dir` as <ship>.pt with a model card, the default model
    for the tasks in `default_for`. The checkpoint itself stays as training wrote it."""
    if ship is None and default_for:
        raise SpareTwinError("default_for: only with ship (a model becomes a default when it is shipped)")
    if ship is not None:
        ckpt.check_ship(ship, default_for)  # before the evaluation: it may take minutes
    res = evaluate(model_path, data_dir, split, device, batch_size, out_dir, max_samples, progress, force)
    if ship is None:
        return res
    with tempfile.TemporaryDirectory() as tmp:
        staged = Path(tmp) / "model.pt"
        shutil.copyfile(res.model, staged)
        record_metrics(staged, res, command)
        shipped = ckpt.ship(staged, ship, list(default_for), models_dir)
    return replace(res, shipped=str(shipped))
