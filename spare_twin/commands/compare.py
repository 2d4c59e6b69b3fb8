"""`spare-twin compare`: sim vs real predictions for one printed object (or many), logged to Rerun."""

from __future__ import annotations

import argparse
import sys


def register(sub) -> None:
    p = sub.add_parser(
        "compare",
        help="sim vs real predictions for one printed object (or a batch), logged to Rerun",
        description="Fit the object's URDF twin to the fused real recording (base pose and joint angles), "
        "render the twin through the real cameras, run the network on both recordings and score both "
        "predictions against the printed configuration. The real recording is registered first if it is "
        "not yet (that writes its poses and fused cloud into it). With --batch DIR, every DIR/<name>/ "
        "holding object/ and real/ is compared and a sim-to-real table is written to --out.",
    )
    p.add_argument("--object", metavar="OBJECT_DIR", help="the printed object's folder (spare-twin object)")
    p.add_argument("--real", metavar="REC_DIR", help="a real (or simulated-sensor) recording of it")
    p.add_argument("--batch", metavar="DIR", help="compare every DIR/<name>/{object,real} pair")
    p.add_argument("--out", metavar="TABLE_DIR", help="with --batch: write sim2real.{json,md,png} here")
    p.add_argument("--model", metavar="CKPT", help="network checkpoint (default: the shipped model in models/)")
    p.add_argument("--rrd", metavar="OUT.rrd", help="write the side-by-side Rerun recording here (single pair)")
    p.add_argument("--sim-out", metavar="DIR", help="where to write the twin's recording (default: REC_DIR_sim_twin beside it)")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object on stdout")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from spare_twin import SpareTwinError
    import json

    from spare_twin.compare import compare, format_summary

    if args.batch:
        return run_batch(args)
    if not args.object or not args.real:
        raise SpareTwinError("--object and --real are both needed (or --batch DIR)")
    result = compare(args.object, args.real, model=args.model, rrd=args.rrd, sim_dir=args.sim_out)
    if args.json:
        print(json.dumps(result))
    else:
        print(f"compare {args.object} vs {args.real}:")
        print(format_summary(result))
        print(f"  twin recording: {result['sim_recording']}" + (f"; Rerun: {result['rrd']} (open with `rerun {result['rrd']}`)" if args.rrd else ""))
    return 0


def run_batch(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from tqdm import tqdm

    from spare_twin import SpareTwinError
    from spare_twin.compare import compare
    from spare_twin.sim2real import sim2real_table, table_markdown, write_table

    root = Path(args.batch)
    pairs = sorted(d for d in root.iterdir() if (d / "object").is_dir() and (d / "real").is_dir()) if root.is_dir() else []
    if not pairs:
        raise SpareTwinError(f"--batch {root}: no <name>/object and <name>/real folders in it")
    if not args.out:
        raise SpareTwinError("--out TABLE_DIR is needed with --batch")
    from spare_twin.io import read_json, write_json_atomic
    from spare_twin.nets.checkpoint import default_model

    model = str(args.model or default_model("predict"))
    results = []
    for d in tqdm(pairs, desc="compare", unit="object", file=sys.stderr):
        done = d / "compare.json"  # a finished comparison, same model and settings, is kept: batches resume
        if done.is_file() and _reusable(read_json(done), model):
            results.append(read_json(done))
            continue
        r = compare(d / "object", d / "real", model=model, sim_dir=d / "sim_twin")
        r["name"] = d.name
        write_json_atomic(done, r)
        results.append(r)
    table = sim2real_table(results)
    table["model"] = model
    table["instances"] = [{k: r.get(k) for k in ("name", "truth", "sim", "real", "real_estimated_frame", "errors")} for r in results]
    files = write_table(table, args.out)
    if args.json:
        print(json.dumps(table))
    else:
        print(table_markdown(table), end="")
        print(f"wrote {', '.join(files.values())}")
    return 0


def _reusable(previous: dict, model: str) -> bool:
    import json

    from spare_twin.compare import CompareConfig

    return previous.get("model") == model and previous.get("settings") == json.loads(json.dumps(CompareConfig().settings()))
