"""Checkpoints: one ``.pt`` file per model, loadable with ``torch.load(weights_only=True)``.

Keys: ``format`` ("spare-twin-net"), ``version`` (1), ``preset`` (name), ``net`` and ``train``
(the dataclass configs as dicts), ``state_dict``, ``normalization`` ({"mean", "std"} of the input,
also inside the state_dict), ``meta`` (data folder, dataset rig, seed, epochs, time, machine,
metrics, the command that made it). Training checkpoints (``last.pt``) add ``optimizer``,
``scheduler``, ``epoch``, ``history``, ``rng`` (torch CPU RNG state).

Model cards (``<name>.md``) are generated from ``meta``; ``models/index.json`` names the shipped
default model per task.
"""

from __future__ import annotations

import dataclasses
import io
import os
import platform
import shutil
import time
from collections.abc import Sequence
from pathlib import Path

import torch

from spare_twin.errors import SpareTwinError, first_line
from spare_twin.io import read_json, write_bytes_atomic, write_json_atomic
from spare_twin.nets.evaluate_names import check_ship
from spare_twin.nets.models import input_norms
from spare_twin.nets.presets import net_from_dict
from spare_twin.nets.registry import build_model

FORMAT = "spare-twin-net"
VERSION = 1
MODELS_DIR = Path(__file__).resolve().parents[2] / "models"


def machine_description() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    dev = f", GPU {torch.cuda.get_device_name(0)}" if torch.cuda.is_available() else ""
    return f"{cpu} ({os.cpu_count()} logical cores){dev}, torch {torch.__version__}"


def save(path: str | Path, obj: dict) -> Path:
    """Atomic write: a crash mid-save leaves the previous file intact (resume relies on it)."""
    buf = io.BytesIO()
    torch.save(obj, buf)
    path = Path(path)
    write_bytes_atomic(path, buf.getvalue())
    return path


def load(path: str | Path, device="cpu") -> dict:
    path = Path(path)
    if not path.is_file():
        raise SpareTwinError(f"{path}: no such checkpoint")
    try:
        ck = torch.load(path, map_location=device, weights_only=True)
    except Exception as exc:  # corrupt / truncated / not a torch file
        raise SpareTwinError(f"{path}: not a readable checkpoint ({type(exc).__name__})") from None
    if not isinstance(ck, dict) or ck.get("format") != FORMAT:
        raise SpareTwinError(f"{path}: not a {FORMAT} checkpoint")
    if ck.get("version") != VERSION:
        raise SpareTwinError(f"{path}: unsupported checkpoint version {ck.get('version')}")
    _check_structure(ck, path)
    return ck


#: What every checkpoint holds, and the type of each (the loaders and the model card read them all).
REQUIRED = {"preset": str, "net": dict, "train": dict, "state_dict": dict, "meta": dict}


def _check_structure(ck: dict, path: Path) -> None:
    """The keys a checkpoint must have, of the right types, and every weight finite: a NaN weight would
    give NaN scores that argmax turns into a confident-looking answer."""
    for key, kind in REQUIRED.items():
        if key not in ck:
            raise SpareTwinError(f"{path}: not a complete checkpoint (no {key!r})")
        if not isinstance(ck[key], kind):
            raise SpareTwinError(f"{path}: {key!r} must be a {kind.__name__}, not a {type(ck[key]).__name__}")
    for name, value in ck["state_dict"].items():
        if not isinstance(value, torch.Tensor):
            raise SpareTwinError(f"{path}: state_dict entry {name!r} is not a tensor")
        if value.is_floating_point() and not bool(torch.isfinite(value).all()):
            raise SpareTwinError(f"{path}: weight {name!r} is not finite (NaN or infinity): a broken checkpoint")


def model_record(preset_name: str, net, train, model, meta: dict) -> dict:
    """The lean, shippable checkpoint dict for `model` (no optimiser state)."""
    norms = input_norms(model)
    normalization = {"mean": float(norms[0].mean), "std": float(norms[0].std)} if norms else None
    return {
        "format": FORMAT,
        "version": VERSION,
        "preset": preset_name,
        "net": dataclasses.asdict(net),
        "train": dataclasses.asdict(train),
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "normalization": normalization,
        "meta": meta,
    }


def load_model(path: str | Path, device="cpu"):
    """(model in eval mode, NetConfig, checkpoint dict)."""
    ck = load(path, device)
    try:
        net = net_from_dict(ck["net"], f"{path}: net")
    except SpareTwinError as exc:  # a field out of its range ("net.height: nan ...")
        message = str(exc)
        raise SpareTwinError(message if message.startswith(str(path)) else f"{path}: {message}") from None
    except (TypeError, ValueError, AttributeError, KeyError) as exc:  # a net entry no configuration fits
        raise _not_a_configuration(path, exc) from None
    try:
        model = build_model(net)
    except (TypeError, ValueError, AttributeError, KeyError) as exc:  # a net entry no architecture fits
        raise _not_a_configuration(path, exc) from None
    try:
        model.load_state_dict(ck["state_dict"])  # strict: every weight of the architecture, of its shape
    except RuntimeError as exc:
        raise SpareTwinError(f"{path}: weights do not fit the {net.arch} network ({first_line(exc)})") from None
    model.to(device).eval()
    return model, net, ck


def _not_a_configuration(path, exc: Exception) -> SpareTwinError:
    """The one-line error of a checkpoint whose net entry no configuration or architecture fits."""
    return SpareTwinError(f"{path}: net: not a network configuration ({type(exc).__name__}: {first_line(exc)})")


def new_meta(data_dir, dataset_rig, seed: int, command: str) -> dict:
    return {
        "data": str(data_dir),
        "rig": dataset_rig,
        "seed": int(seed),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "machine": machine_description(),
        "command": command,
        "metrics": {},
    }


def model_card(ck: dict, name: str) -> str:
    """Markdown model card from a checkpoint's configs and metadata."""
    m, net, tr = ck.get("meta", {}), ck["net"], ck["train"]
    metrics = m.get("metrics", {})
    view = {
        "mv": "multi-view (8 views)",
        "tmp": f"temporal ({int(net['frames'])} frames)",
        "profile": "the chain's profile from any posed views (docs/observe.md)",
    }[net["mode"]]
    lines = [
        f"# {name}",
        "",
        f"Preset `{ck['preset']}`: {net['arch']} network, task `{net['task']}`, {net['input']} input, {view}.",
        "",
        "| | |",
        "|---|---|",
        f"| architecture | `{net['arch']}`, channels {tuple(net['channels'])}, FC {net['fc_hidden']} |",
        f"| parameters | {m.get('parameters', '?')} |",
        f"| training data | `{m.get('data', '?')}` (rig `{m.get('rig')}`) |",
        f"| seed | {m.get('seed')} |",
        f"| epochs | {m.get('epochs_trained', '?')} of {tr['epochs']}, batch {tr['batch_size']}, lr {tr['lr']} |",
        f"| training time | {m.get('train_time_s', 0) / 60:.1f} min |",
        f"| machine | {m.get('machine', '?')} |",
        f"| created | {m.get('created', '?')} |",
        "",
        "## Test metrics",
        "",
    ]
    if metrics:
        lines += ["| metric | value |", "|---|---|"]
        for k, v in metrics.items():
            if isinstance(v, (int, float, str)) or v is None:
                lines.append(f"| {k} | {v if not isinstance(v, float) else f'{v:.4f}'} |")
    else:
        lines.append("(not evaluated yet: `spare-twin evaluate --model ... --data ... --ship NAME` records them)")
    lines += ["", "## Reproduce", "", "```", m.get("command", "?")]
    if m.get("evaluate_command"):
        lines.append(m["evaluate_command"])
    lines += ["```", ""]
    return "\n".join(lines)


def write_card(ckpt_path: str | Path, out_md: str | Path | None = None, name: str | None = None) -> Path:
    ck = load(ckpt_path)
    ckpt_path = Path(ckpt_path)
    out_md = Path(out_md) if out_md else ckpt_path.with_suffix(".md")
    write_bytes_atomic(out_md, model_card(ck, name or ckpt_path.stem).encode())
    return out_md


def read_index(models_dir: Path = MODELS_DIR) -> dict:
    p = Path(models_dir) / "index.json"
    if not p.is_file():
        return {"format": "spare-twin-models", "version": 1, "defaults": {}, "models": {}}
    return read_json(p)


def default_model(task: str = "predict", models_dir: Path = MODELS_DIR) -> Path:
    """The shipped checkpoint models/index.json names for `task`."""
    idx = read_index(models_dir)
    name = idx.get("defaults", {}).get(task)
    if not name:
        raise SpareTwinError(
            f"model: none given, and {Path(models_dir) / 'index.json'} names no shipped default for {task!r}"
        )
    entry = idx.get("models", {}).get(name, {})
    path = Path(models_dir) / entry.get("file", f"{name}.pt")
    if not path.is_file():
        raise SpareTwinError(f"model: none given, and the shipped default {name!r} is missing ({path})")
    return path


def ship(ckpt_path: str | Path, name: str, tasks: Sequence[str], models_dir: Path = MODELS_DIR) -> Path:
    """Copy a checkpoint into models/ as <name>.pt, write <name>.md, register it in index.json and make
    it the default for `tasks`."""
    check_ship(name, tasks)
    models_dir = Path(models_dir)
    models_dir.mkdir(parents=True, exist_ok=True)
    dst = models_dir / f"{name}.pt"
    if Path(ckpt_path).resolve() != dst.resolve():
        tmp = dst.with_suffix(".pt.tmp")
        shutil.copyfile(ckpt_path, tmp)
        tmp.replace(dst)
    card = write_card(dst, models_dir / f"{name}.md", name)
    ck = load(dst)
    idx = read_index(models_dir)
    idx["models"][name] = {
        "file": dst.name,
        "card": card.name,
        "preset": ck["preset"],
        "task": ck["net"]["task"],
        "mode": ck["net"]["mode"],
        "metrics": {k: v for k, v in ck["meta"].get("metrics", {}).items() if not isinstance(v, dict)},
    }
    for t in tasks:
        idx["defaults"][t] = name
    write_json_atomic(models_dir / "index.json", idx)
    return dst
