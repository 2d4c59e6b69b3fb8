"""`spare-twin train`: train a kinematics network from a preset or a config; under
`torchrun --nproc-per-node N -m spare_twin train ...` data-parallel over N processes."""

from __future__ import annotations

import json
import os
import shlex
import sys
from pathlib import Path

from spare_twin.commands.common import flags

#: the train command's flags for the TrainConfig fields they override
OVERRIDE_FLAGS = {
    "epochs": "--epochs",
    "batch_size": "--batch-size",
    "lr": "--lr",
    "seed": "--seed",
    "samples_per_epoch": "--samples-per-epoch",
    "patience": "--patience",
    "workers": "--workers",
    "threads": "--threads",
}


def register(sub) -> None:
    p = sub.add_parser(
        "train",
        help="train a link-count / link-length network from a preset or a config",
        description="Train a network on DATA_DIR's train split (validating on its val split), writing checkpoints "
        "(last.pt every epoch, best.pt, model.pt), history.json, learning_curve.png and MODEL_CARD.md into --out. "
        "Interrupt at any time and continue with --resume. Data-parallel: torchrun --nproc-per-node N -m spare_twin "
        "train ... (gloo on CPUs, NCCL on GPUs; --batch-size is per process; rank 0 writes the run folder).",
    )
    p.add_argument("--preset", metavar="NAME", help="a preset (see --list-presets)")
    p.add_argument("--config", metavar="CFG_JSON", help='{"preset": NAME, "net": {...}, "train": {...}} overrides')
    p.add_argument(
        "--data",
        metavar="DATA_DIR",
        help="dataset folder (spare-twin dataset, or a synthetic.json folder); the profile network takes several, "
        "comma-separated",
    )
    p.add_argument("--out", metavar="RUN_DIR", help="run folder to write")
    p.add_argument("--epochs", type=int, help="override the preset's epochs")
    p.add_argument("--batch-size", type=int, help="override the preset's batch size")
    p.add_argument("--lr", type=float, help="override the preset's learning rate")
    p.add_argument("--samples-per-epoch", type=int, help="training samples drawn per epoch (default: the preset's)")
    p.add_argument(
        "--patience",
        type=int,
        help="stop once validation has not improved for this many epochs (the run then ends before --epochs)",
    )
    p.add_argument("--seed", type=int, help="override the preset's seed (init, sample order)")
    p.add_argument("--workers", type=int, help="DataLoader worker processes")
    p.add_argument("--threads", type=int, help="torch CPU threads")
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"], help="default auto: a GPU when present")
    p.add_argument("--on-the-fly", action="store_true", help="train on freshly rendered samples (nothing stored)")
    p.add_argument("--resume", action="store_true", help="continue the run in --out after its last completed epoch")
    p.add_argument(
        "--force",
        action="store_true",
        help="replace a --out that is another run or not a run at all, once the new run is complete",
    )
    p.add_argument("--list-presets", action="store_true", help="list the presets and exit")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    from spare_twin.errors import SpareTwinError
    from spare_twin.io import read_json
    from spare_twin.validate import check_folder

    if args.list_presets:
        from spare_twin.nets.presets import PRESETS

        rows = {
            n: {"description": p.description, "paper_row": p.paper_row, "paper_result": p.paper_result}
            for n, p in PRESETS.items()
        }
        if args.json:
            print(json.dumps(rows))
        else:
            for n, r in rows.items():
                paper = f"  [paper: {r['paper_row']} = {r['paper_result']}]" if r["paper_row"] else ""
                print(f"{n:28s} {r['description']}{paper}")
        return 0
    for flag in ("data", "out"):
        if not getattr(args, flag):
            raise SpareTwinError(f"--{flag} is required")
    if not args.preset and not args.config:
        raise SpareTwinError("--preset NAME or --config CFG_JSON is required (see --list-presets)")
    from spare_twin.nets.presets import resolve
    from spare_twin.nets.run_folder import refused_run_folder

    config = read_json(args.config) if args.config else {}
    overrides = {
        k: v
        for k, v in {
            "epochs": args.epochs,
            "batch_size": args.batch_size,
            "lr": args.lr,
            "seed": args.seed,
            "samples_per_epoch": args.samples_per_epoch,
            "patience": args.patience,
            "workers": args.workers,
            "threads": args.threads,
        }.items()
        if v is not None
    }
    if overrides:
        config = dict(config)
        config["train"] = {**config.get("train", {}), **overrides}
    given = {f"train.{k}": OVERRIDE_FLAGS[k] for k in overrides}
    data_dirs = args.data.split(",")
    with flags(data_dir="--data", out_dir="--out", resume="--resume", **given):
        preset = resolve(args.preset, config, args.config or "--preset")
        # before torch is imported (3-5 s of a new process): a missing data folder, or a run folder
        # that would be refused, is said at once
        for data_dir in data_dirs:
            check_folder("data_dir", data_dir)
        problem = refused_run_folder(Path(args.out), [Path(d) for d in data_dirs], args.resume, args.force)
        if problem is not None:
            raise SpareTwinError(problem)
    from spare_twin.nets.distributed import is_main_process
    from spare_twin.nets.train import train

    command = "spare-twin " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv and "train" in sys.argv else ""
    if command and int(os.environ.get("WORLD_SIZE", "1")) > 1:
        command = f"torchrun --nproc-per-node {os.environ.get('LOCAL_WORLD_SIZE', '?')} -m spare_twin" + command[10:]
    with flags(
        data_dir="--data", out_dir="--out", resume="--resume", device="--device", on_the_fly="--on-the-fly", **given
    ):
        summary = train(
            preset,
            data_dirs,
            args.out,
            device=args.device,
            on_the_fly=args.on_the_fly,
            resume=args.resume,
            command=command or _reconstruct(args),
            progress=True,
            force=args.force,
        )
    if not is_main_process():
        return 0  # rank 0 prints
    if args.json:
        print(json.dumps(summary))
    else:
        print(
            f"wrote {summary['model']} (best epoch {summary['best_epoch']}, {summary['train_time_s']:.0f} s), "
            f"{summary['learning_curve']}"
        )
    return 0


def _reconstruct(args) -> str:
    parts = ["spare-twin train"]
    for flag in ("preset", "config", "data", "out", "epochs", "batch_size", "seed", "samples_per_epoch"):
        v = getattr(args, flag)
        if v is not None:
            parts.append(f"--{flag.replace('_', '-')} {v}")
    if args.on_the_fly:
        parts.append("--on-the-fly")
    return " ".join(parts)
