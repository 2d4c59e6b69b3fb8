"""`spare-twin compare`: sim vs real predictions for one printed object (or many), logged to Rerun."""

from __future__ import annotations

import argparse

from spare_twin.errors import SpareTwinError


def register(sub) -> None:
    p = sub.add_parser(
        "compare",
        help="sim vs real predictions for one printed object (or a batch), logged to Rerun",
        description="Fit the object's URDF twin to the fused real recording (base pose and joint angles), "
        "render the twin through the real cameras, run the network on both recordings and score both "
        "predictions against the printed configuration. `real` is what `predict` says of the real "
        "recording alone; `real_twin_aligned` is a diagnostic that re-aligns the real cameras onto the "
        "fitted printed twin first. The real recording is registered first if it is "
        "not yet (that writes its poses and fused cloud into it). With --batch DIR, every DIR/<name>/ "
        "holding object/ and real/ is compared and a sim-to-real table is written to --out.",
    )
    p.add_argument("--object", metavar="OBJECT_DIR", help="the printed object's folder (spare-twin object)")
    p.add_argument("--real", metavar="REC_DIR", help="a real (or simulated-sensor) recording of it")
    p.add_argument("--batch", metavar="DIR", help="compare every DIR/<name>/{object,real} pair")
    p.add_argument("--out", metavar="TABLE_DIR", help="with --batch: write sim2real.{json,md,png} here")
    p.add_argument("--model", metavar="CKPT", help="network checkpoint (default: the shipped model in models/)")
    p.add_argument("--rrd", metavar="OUT.rrd", help="write the side-by-side Rerun recording here (single pair)")
    p.add_argument(
        "--sim-out", metavar="DIR", help="where to write the twin's recording (default: REC_DIR_sim_twin beside it)"
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="replace --rrd, --sim-out or --out even if they are not earlier outputs of compare",
    )
    p.add_argument("--json", action="store_true", help="print the result as one JSON object on stdout")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json

    from spare_twin.commands.common import flags
    from spare_twin.compare.inputs import check_compare

    if args.batch:
        return run_batch(args)
    if not args.object or not args.real:
        raise SpareTwinError("--object and --real are both needed (or --batch DIR)")
    with flags(model="--model", force="--force"):
        # checked before the comparison's modules are imported: torch and the stages take 5 s to load
        check_compare(args.object, args.real, args.model, args.rrd, args.sim_out, args.force)
        from spare_twin.compare.sim_vs_real import compare

        result = compare(args.object, args.real, model=args.model, rrd=args.rrd, sim_dir=args.sim_out, force=args.force)
    if args.json:
        print(json.dumps(result.to_json()))
    else:
        print(f"compare {args.object} vs {args.real}:")
        print(result.summary())
        print(
            f"  twin recording: {result.sim_recording}"
            + (f"; Rerun: {result.rrd} (open with `rerun {result.rrd}`)" if args.rrd else "")
        )
    return 0


def run_batch(args: argparse.Namespace) -> int:
    from spare_twin.commands.common import flags
    from spare_twin.compare.inputs import check_batch

    if not args.out:
        raise SpareTwinError("--out TABLE_DIR is needed with --batch")
    with flags(batch="--batch", model="--model", force="--force"):
        check_batch(args.batch, args.out, args.model, args.force)
        from spare_twin.compare.batch import compare_batch

        table, files = compare_batch(args.batch, args.out, args.model, force=args.force)
    print_table(table, files, args.json)
    return 0


def print_table(table: dict, files: dict[str, str], as_json: bool) -> None:
    import json

    from spare_twin.compare.batch import batch_markdown

    if as_json:
        print(json.dumps(table))
    else:
        print(batch_markdown(table), end="")
        print(f"wrote {', '.join(files.values())}")
