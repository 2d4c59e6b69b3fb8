"""`spare-twin evaluate`: the paper's metrics for a checkpoint on the test split, the network alone
and, where a measurement stands beside it, the answer `predict` gives."""

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
        "end-to-end rule: slots past the true / predicted count are 0), per-n breakdown, confusion matrix. "
        "The network's own figures lead; for the profile network, whose input is measured layer by layer too, "
        "the figures of predict's combined answer (the network overruled by the measurement) stand beside them "
        "(JSON: network, combined). The profile network's test samples are observed and measured once, on every "
        "core, and kept in the user's cache (~/.cache/spare-twin/observed): a second evaluation takes seconds.",
    )
    p.add_argument("--model", metavar="CKPT", help="checkpoint (default: the shipped model in models/)")
    p.add_argument("--data", required=True, metavar="DATA_DIR", help="dataset folder")
    p.add_argument("--split", default="test", help="split to evaluate (default test)")
    p.add_argument(
        "--out",
        metavar="DIR",
        help="write evaluation.json and confusion_matrix.png (the network's; confusion_matrix_combined.png: "
        "the combined answer's) here",
    )
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
    from spare_twin.predict.evaluate_inputs import check_evaluate

    default_for = [t for t in args.default_for.split(",") if t]
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
        # checked before the evaluation's modules are imported: torch and the network take 5 s to load
        check_evaluate(
            args.model, args.data, args.batch_size, args.max_samples, args.ship, default_for, args.out, args.force
        )
        from spare_twin.predict.evaluate import evaluate_model

        ev = evaluate_model(
            args.model,
            args.data,
            args.split,
            args.device,
            args.batch_size,
            args.out,
            args.max_samples,
            ship=args.ship,
            default_for=default_for,
            command="spare-twin " + " ".join(shlex.quote(a) for a in sys.argv[1:]),
            force=args.force,
        )
    if args.json:
        print(json.dumps(ev.to_json()))
        return 0
    net = ev.network
    print(f"{net.split}: {net.instances} instances")
    for label, e in (("the network alone", net), ("combined with the measurement (predict's answer)", ev.combined)):
        if e is None:
            continue
        acc = "n/a" if e.count_accuracy is None else f"{e.count_accuracy:.4f}"
        el = "n/a" if e.E_L is None else f"{e.E_L:.4f}"
        print(f"{label}: count accuracy {acc}, E_L {el}")
        for n, row in e.per_n.items():
            print(f"  n={n}: {row}")
        if e.confusion_png:
            print(f"wrote {e.confusion_png}")
    if ev.shipped:
        print(f"shipped {ev.shipped}")
    return 0
