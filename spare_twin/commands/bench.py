"""`spare-twin bench`: performance benchmarks, one subcommand (and one function) each.

Stages add their own benchmark as `spare_twin/commands/bench_<name>.py` defining
`add_bench(subparsers)`; this command discovers and registers them.

`bench dataset`: dataset images/s end to end on the local and the Ray backend against pybullet's raw
render loop for the same rig and objects, measured in the same run and interleaved, for 1 and 2 workers;
Ray's cost per task; and the wall time of the `paper` preset (measured with --paper full, else
extrapolated from the measured rate). spare_twin/bench/dataset.py says how each figure is measured.
"""

from __future__ import annotations

import argparse
import json


def register(sub) -> None:
    p = sub.add_parser(
        "bench",
        help="performance benchmarks (bench dataset, ...)",
        description="Performance benchmarks; each subcommand measures one stage.",
    )
    bsub = p.add_subparsers(dest="benchmark", metavar="BENCHMARK")
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])
    d = bsub.add_parser(
        "dataset",
        help="dataset generation: end-to-end images/s vs the raw pybullet render loop",
        description=__doc__.split("\n\n", 1)[1],
    )
    d.add_argument("--instances", type=int, default=4, help="sequences per worker in every measured run (default: 4)")
    d.add_argument("--workers", default="1,2", help="worker counts to measure, comma-separated (default: 1,2)")
    d.add_argument("--frames", type=int, default=100, help="frames per sequence (default: 100)")
    d.add_argument(
        "--geometry", choices=("sim", "print"), default="sim", help="tessellation of the parts (default: sim)"
    )
    d.add_argument(
        "--rounds",
        type=int,
        default=1,
        help="interleaved rounds: raw, local, ray, ray (workers write), then backwards; each round runs every "
        "column twice (default: 1)",
    )
    d.add_argument("--no-ray", action="store_true", help="measure the raw loop and the local backend only")
    d.add_argument(
        "--paper",
        choices=("extrapolate", "full"),
        default="extrapolate",
        help="full: generate the whole paper preset (324 sequences) with the largest worker count and "
        "time it; extrapolate (default): predict its wall time from the measured rate",
    )
    d.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    d.set_defaults(func=bench_dataset)
    _add_stage_benchmarks(bsub)


def _add_stage_benchmarks(bsub) -> None:
    """Other stages add theirs as `spare_twin/commands/bench_<name>.py` with `add_bench(subparsers)`."""
    import importlib
    import pkgutil

    import spare_twin.commands as commands

    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("bench_"):
            module = importlib.import_module(f"spare_twin.commands.{info.name}")
            if hasattr(module, "add_bench"):
                module.add_bench(bsub)


def bench_dataset(args: argparse.Namespace) -> int:
    import sys

    from spare_twin.bench.dataset import DatasetBench, bench_dataset
    from spare_twin.commands.common import flags
    from spare_twin.errors import SpareTwinError

    try:
        worker_counts = tuple(int(w) for w in args.workers.split(","))
    except ValueError:
        raise SpareTwinError(f"--workers {args.workers!r}: expected comma-separated integers") from None
    with flags(instances="--instances", workers="--workers", frames="--frames", rounds="--rounds", paper="--paper"):
        b = DatasetBench(
            args.instances, worker_counts, args.frames, args.geometry, args.rounds, not args.no_ray, args.paper
        )
        result = bench_dataset(b, log=(lambda line: print(line, file=sys.stderr)) if args.json else print)
    if args.json:
        print(json.dumps(result.to_json()))
    return 0
