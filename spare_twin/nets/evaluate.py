"""`spare-twin evaluate`: the paper's metrics for a checkpoint on a data split."""

from __future__ import annotations

from pathlib import Path

import torch

from spare_twin.errors import SpareTwinError
from spare_twin.nets import checkpoint as ckpt
from spare_twin.nets import metrics
from spare_twin.nets.data import open_split
from spare_twin.nets.train import pick_device, run_inference, summarize


def evaluate(
    model_path,
    data_dir,
    split: str = "test",
    device: str = "auto",
    batch_size: int = 16,
    out_dir=None,
    max_samples: int | None = None,
    progress: bool = True,
) -> dict:
    """Count accuracy, E_L (end-to-end where the model can, else n known), per-n breakdown and the
    confusion matrix (PNG under `out_dir`) over `split`."""
    dev = pick_device(device)
    model, net, ck = ckpt.load_model(model_path, dev)
    ds = open_split(data_dir, split, net)
    if len(ds) == 0:
        raise SpareTwinError(f"--data {data_dir}: split {split!r} is empty")
    idx = None
    if max_samples is not None and max_samples < len(ds):
        idx = torch.randperm(len(ds), generator=torch.Generator().manual_seed(0))[:max_samples].tolist()
    pred = run_inference(model, net, ds, dev, batch_size, idx, f"evaluate {split}", progress)
    res = summarize(pred)
    out = {
        "count_accuracy": res["count_accuracy"],
        "E_L": res["E_L"],
        "instances": res["instances"],
        "split": split,
        "E_L_end_to_end": res["E_L_end_to_end"],
        "E_L_n_known": res["E_L_n_known"],
        "per_n": res["per_n"],
        "model": str(model_path),
        "preset": ck["preset"],
    }
    if "pred_n" in pred:
        cm = metrics.confusion_matrix(pred["true_n"], pred["pred_n"])
        out["confusion_matrix"] = cm.tolist()
        if out_dir is not None:
            png = metrics.write_confusion_png(cm, Path(out_dir) / "confusion_matrix.png", f"{ck['preset']} ({split})")
            out["confusion_png"] = str(png)
    if out_dir is not None:
        from spare_twin.io import write_json_atomic

        write_json_atomic(Path(out_dir) / "evaluation.json", out)
    return out


def record_metrics(model_path, result: dict, command: str) -> None:
    """Store test metrics in the checkpoint's metadata (the model card reads them)."""
    ck = ckpt.load(model_path)
    keep = ("count_accuracy", "E_L", "E_L_end_to_end", "E_L_n_known", "instances", "split")
    ck["meta"]["metrics"] = {k: result[k] for k in keep if k in result}
    ck["meta"]["metrics"]["data"] = str(result.get("data", ""))
    ck["meta"]["evaluate_command"] = command
    ckpt.save(model_path, ck)
