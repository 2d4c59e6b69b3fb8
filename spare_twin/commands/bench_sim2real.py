"""`spare-twin bench sim2real`: the sim-to-real table on simulated-sensor captures of unseen objects.

Draws OBJECTS chains from the paper's distribution with seeds SEED, SEED+1, ... (link counts cycling
1..6; the training data draws its chains from other seeds), builds each printable object, captures it
with the simulated hand-held sensor (`spare_twin.capture.simulated`: fitted RealSense noise, poses hidden,
7-Scenes export, import, registration) and runs `compare --batch` over them (`spare_twin.compare.batch`).
Interrupted runs resume: finished captures and comparisons (same model) are kept.
"""

from __future__ import annotations

import argparse


def add_bench(bsub) -> None:
    """Add `sim2real` to the `spare-twin bench` subparsers."""
    p = bsub.add_parser(
        "sim2real",
        help="sim-to-real table: simulated-sensor captures of unseen objects, compare --batch",
        description=__doc__.split("\n\n", 1)[1],
    )
    p.add_argument(
        "--out", required=True, metavar="DIR", help="folder for the objects, captures and sim2real.{json,md,png}"
    )
    p.add_argument("--objects", type=int, default=12, help="objects to capture (default 12: two per link count)")
    p.add_argument("--seed", type=int, default=1000, help="seed of the first object (default 1000)")
    p.add_argument("--model", metavar="CKPT", help="network checkpoint (default: the shipped model)")
    p.add_argument("--force", action="store_true", help="replace --out even if it is not an earlier sim2real benchmark")
    p.add_argument("--json", action="store_true", help="print the table as one JSON object on stdout")
    p.set_defaults(func=bench_sim2real)


def bench_sim2real(args: argparse.Namespace) -> int:
    from spare_twin.commands.common import flags
    from spare_twin.commands.compare import print_table
    from spare_twin.compare.batch import bench_sim2real as run_bench

    with flags(objects="--objects", seed="--seed", model="--model", force="--force"):
        table, files = run_bench(args.out, args.objects, args.seed, args.model, force=args.force)
    print_table(table, files, args.json)
    return 0
