"""`spare-twin bench nets`: inference throughput and latency of a network on this machine.

The `bench` command (another stage) calls `add_bench(subparsers)` to add this subcommand.
"""

from __future__ import annotations

import json

from spare_twin.commands.common import flags
from spare_twin.errors import SpareTwinError


def add_bench(sub) -> None:
    p = sub.add_parser("nets", help="network inference speed: samples/s and latency per sample")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--model", metavar="CKPT", help="a checkpoint (default: the shipped predict model)")
    src.add_argument(
        "--preset", metavar="NAME", help="an untrained network of this preset (speed does not depend on weights)"
    )
    p.add_argument("--batch-sizes", default="1,16", help="comma-separated (default 1,16)")
    p.add_argument("--iters", type=int, default=10)
    p.add_argument("--threads", type=int, help="torch CPU threads (default: torch's)")
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    from spare_twin.bench.nets import bench_network

    try:
        sizes = tuple(int(s) for s in args.batch_sizes.split(",") if s)
    except ValueError:
        raise SpareTwinError(f"--batch-sizes {args.batch_sizes!r}: expected integers like 1,16") from None
    with flags(
        model="--model",
        preset="--preset",
        batch_sizes="--batch-sizes",
        iters="--iters",
        threads="--threads",
        device="--device",
    ):
        res = bench_network(args.model, args.preset, sizes, args.iters, args.threads, args.device).to_json()
    if args.json:
        print(json.dumps(res))
    else:
        name = res["model"]
        for bs, r in res["batch_sizes"].items():
            print(
                f"{name} batch {bs}: {r['samples_per_s']:.1f} samples/s, {r['latency_ms_per_sample']:.1f} ms/sample "
                f"({res['threads']} threads, {res['device']})"
            )
    return 0
