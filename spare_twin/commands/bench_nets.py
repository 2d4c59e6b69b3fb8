"""`spare-twin bench nets`: inference throughput and latency of a network on this machine.

The `bench` command (another stage) calls `add_bench(subparsers)` to add this subcommand.
"""

from __future__ import annotations

import json


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
    from spare_twin.errors import SpareTwinError
    from spare_twin.nets.bench import bench_inference

    try:
        sizes = tuple(int(s) for s in args.batch_sizes.split(",") if s)
    except ValueError:
        raise SpareTwinError(f"--batch-sizes {args.batch_sizes!r}: expected integers like 1,16") from None
    if args.preset:
        from spare_twin.nets.models import build_model
        from spare_twin.nets.presets import get_preset

        net = get_preset(args.preset).net
        model, name = build_model(net), args.preset
    else:
        from spare_twin.nets import checkpoint as ckpt

        path = args.model or ckpt.default_model("predict")
        model, net, _ = ckpt.load_model(path)
        name = str(path)
    res = bench_inference(model, net, sizes, iters=args.iters, threads=args.threads, device=args.device)
    res["model"] = name
    res["parameters"] = int(sum(p.numel() for p in model.parameters()))
    if args.json:
        print(json.dumps(res))
    else:
        for bs, r in res["batch_sizes"].items():
            print(
                f"{name} batch {bs}: {r['samples_per_s']:.1f} samples/s, {r['latency_ms_per_sample']:.1f} ms/sample "
                f"({res['threads']} threads, {res['device']})"
            )
    return 0
