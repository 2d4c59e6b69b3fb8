"""`spare-twin bench training`: training samples/s per preset under several speed settings, measured
back to back in the same run, as ratios against the trainer's defaults (the first setting).

The `bench` command (another stage) calls `add_bench(subparsers)` to add this subcommand.
"""

from __future__ import annotations

import json
import sys

from spare_twin.commands.common import flags
from spare_twin.errors import SpareTwinError

#: Besides the multi-view presets of the paper's Table 1 (read off the presets), this project's grey network.
EXTRA_DEFAULT_PRESETS = ("geo-grey-mv-multitask",)


def default_presets() -> tuple[str, ...]:
    from spare_twin.nets.presets import PRESETS

    table_1_mv = tuple(name for name, p in PRESETS.items() if p.paper_row and p.net.mode == "mv")
    return table_1_mv + EXTRA_DEFAULT_PRESETS


def add_bench(sub) -> None:
    p = sub.add_parser(
        "training",
        help="training speed: samples/s per preset under thread / worker / memory-layout settings",
        description=__doc__.split("\n\n", 1)[0],
    )
    p.add_argument("--data", metavar="DATA_DIR", required=True, help="a spare-twin dataset (its train split)")
    p.add_argument(
        "--presets",
        help="comma-separated (default: the multi-view presets of the paper's Table 1 and geo-grey-mv-multitask)",
    )
    p.add_argument(
        "--settings",
        help="comma-separated THREADS/WORKERS[/cl] (cl: channels-last); the first is the baseline "
        "(default: the trainer's defaults, then channels-last, a loader worker, and both)",
    )
    p.add_argument("--steps", type=int, default=10, help="timed training steps per preset and setting (default 10)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(func=run)


def parse_settings(text: str):
    from spare_twin.bench.training import SpeedSetting

    out = []
    for item in text.split(","):
        parts = item.strip().split("/")
        try:
            if len(parts) not in (2, 3) or (len(parts) == 3 and parts[2] != "cl"):
                raise ValueError
            threads, workers = int(parts[0]), int(parts[1])
            if threads < 1 or workers < 0:
                raise ValueError
        except ValueError:
            raise SpareTwinError(f"--settings {text!r}: expected THREADS/WORKERS[/cl] items like 2/0,2/1/cl") from None
        out.append(SpeedSetting(threads, workers, len(parts) == 3))
    return out


def run(args) -> int:
    import torch

    from spare_twin.bench.training import bench_training

    n = torch.get_num_threads()
    settings = parse_settings(args.settings or f"{n}/0,{n}/0/cl,{n}/1,{n}/1/cl")
    presets = [p for p in args.presets.split(",") if p] if args.presets else list(default_presets())
    log = (lambda line: print(line, file=sys.stderr)) if args.json else print
    with flags(data_dir="--data", presets="--presets", steps="--steps"):
        res = bench_training(presets, args.data, settings, args.steps, log=log)
    if args.json:
        print(json.dumps({"settings": [s.label for s in settings], "presets": [r.to_json(settings) for r in res]}))
    else:
        print(f"\nsamples/s ({', '.join(s.label for s in settings)}); ratio against the first")
        for r in res:
            cells = [f"{v:.1f} ({v / r.samples_per_s[0]:.2f}x)" for v in r.samples_per_s]
            print(f"  {r.preset:<26} " + "  ".join(cells))
    return 0
