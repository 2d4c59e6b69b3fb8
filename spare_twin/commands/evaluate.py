"""`spare-twin evaluate`: the paper's metrics for a checkpoint on the test split."""

from __future__ import annotations

import json
import shlex
import sys

from spare_twin.commands.common import flags


def register(sub) -> None:
    p = sub.add_parser(
        "evaluate",
        help="count accuracy and link-length error E_L of a model on a data split",
        description="Evaluate a checkpoint with the paper's metrics: link-count accuracy and E_L (paper units; "
        "end-to-end rule: slots past the true / predicted count are 0), per-n breakdown, confusion matrix.",
    )
    p.add_argument("--model", metavar="CKPT", help="checkpoint (default: the shipped model in models/)")
    p.add_argument("--data", required=True, metavar="DATA_DIR", help="dataset folder")
    p.add_argument("--split", default="test", help="split to evaluate (default test)")
    p.add_argument("--out", metavar="DIR", help="write confusion_matrix.png and evaluation.json here")
    p.add_argument("--batch-size", type=int, default=16)
    p.add_argument("--max-samples", type=int, help="evaluate a seeded random subset of this size")
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    p.add_argument(
        "--ship",
        metavar="NAME",
        help="record the metrics in the checkpoint and copy it to models/NAME.pt with a model card",
    )
    p.add_argument(
        "--default-for",
        metavar="TASKS",
        default="",
        help="with --ship: comma-separated tasks it becomes the default for "
        "(predict, count-mv, count-tmp, lengths-mv, e2e-mv, e2e-tmp)",
    )
    p.add_argument("--force", action="store_true", help="replace --out even if it is not an earlier evaluate output")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    from spare_twin.nets.evaluate import evaluate_model

    with flags(
        model="--model",
        model_path="--model",
        data_dir="--data",
        data="--data",
        split="--split",
        device="--device",
        batch_size="--batch-size",
        max_samples="--max-samples",
        out_dir="--out",
        name="--ship",
        ship="--ship",
        tasks="--default-for",
        default_for="--default-for",
        force="--force",
    ):
        ev = evaluate_model(
            args.model,
            args.data,
            args.split,
            args.device,
            args.batch_size,
            args.out,
            args.max_samples,
            ship=args.ship,
            default_for=[t for t in args.default_for.split(",") if t],
            command="spare-twin " + " ".join(shlex.quote(a) for a in sys.argv[1:]),
            force=args.force,
        )
    if args.json:
        print(json.dumps(ev.to_json()))
    else:
        acc = "n/a" if ev.count_accuracy is None else f"{ev.count_accuracy:.4f}"
        el = "n/a" if ev.E_L is None else f"{ev.E_L:.4f}"
        print(f"{ev.split}: {ev.instances} instances, count accuracy {acc}, E_L {el}")
        for n, row in ev.per_n.items():
            print(f"  n={n}: {row}")
        if ev.confusion_png:
            print(f"wrote {ev.confusion_png}")
        if ev.shipped:
            print(f"shipped {ev.shipped}")
    return 0
