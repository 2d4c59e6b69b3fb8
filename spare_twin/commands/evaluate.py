"""`spare-twin evaluate`: the paper's metrics for a checkpoint on the test split."""

from __future__ import annotations

import json
import shlex
import sys


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
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from spare_twin.nets import checkpoint as ckpt
    from spare_twin.nets.evaluate import evaluate, record_metrics

    model = args.model or ckpt.default_model("predict")
    res = evaluate(
        model, args.data, args.split, args.device, args.batch_size, args.out, args.max_samples, progress=True
    )
    res["data"] = str(args.data)
    if args.ship:
        import shutil
        import tempfile

        # record into a copy: the run's own model.pt stays as training wrote it
        with tempfile.TemporaryDirectory() as tmp:
            staged = Path(tmp) / "model.pt"
            shutil.copyfile(model, staged)
            record_metrics(staged, res, "spare-twin " + " ".join(shlex.quote(a) for a in sys.argv[1:]))
            tasks = [t for t in args.default_for.split(",") if t]
            res["shipped"] = str(ckpt.ship(staged, args.ship, tasks))
    if args.json:
        print(json.dumps(res))
    else:
        acc = "n/a" if res["count_accuracy"] is None else f"{res['count_accuracy']:.4f}"
        el = "n/a" if res["E_L"] is None else f"{res['E_L']:.4f}"
        print(f"{res['split']}: {res['instances']} instances, count accuracy {acc}, E_L {el}")
        for n, row in res["per_n"].items():
            print(f"  n={n}: {row}")
        if res.get("confusion_png"):
            print(f"wrote {res['confusion_png']}")
        if res.get("shipped"):
            print(f"shipped {res['shipped']}")
    return 0
