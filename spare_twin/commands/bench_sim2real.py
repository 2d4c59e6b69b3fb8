"""`spare-twin bench sim2real`: the sim-to-real table on simulated-sensor captures of unseen objects.

Draws OBJECTS chains from the paper's distribution with seeds SEED, SEED+1, ... (link counts cycling
1..6; the training data draws its chains from other seeds), builds each printable object, captures it
with the simulated hand-held sensor (`spare_twin.sensor_capture`: fitted RealSense noise, poses hidden,
7-Scenes export, import, registration) and runs `compare --batch` over them. Interrupted runs resume:
finished captures and comparisons (same model) are kept.
"""

from __future__ import annotations

import argparse
import json
import sys


def add_bench(bsub) -> None:
    """Add `sim2real` to the `spare-twin bench` subparsers."""
    p = bsub.add_parser("sim2real", help="sim-to-real table: simulated-sensor captures of unseen objects, compare --batch",
                        description=__doc__.split("\n\n", 1)[1])
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the objects, captures and sim2real.{json,md,png}")
    p.add_argument("--objects", type=int, default=12, help="objects to capture (default 12: two per link count)")
    p.add_argument("--seed", type=int, default=1000, help="seed of the first object (default 1000)")
    p.add_argument("--model", metavar="CKPT", help="network checkpoint (default: the shipped model)")
    p.add_argument("--json", action="store_true", help="print the table as one JSON object on stdout")
    p.set_defaults(func=bench_sim2real)


def bench_sim2real(args: argparse.Namespace) -> int:
    from pathlib import Path

    from tqdm import tqdm

    from spare_twin import SpareTwinError
    from spare_twin.config import MAX_MOVING_LINKS, sample_chain
    from spare_twin.objects import build_object
    from spare_twin.sensor_capture import SensorCaptureConfig, simulated_capture

    if args.objects < 1:
        raise SpareTwinError(f"--objects {args.objects}: need at least 1")
    out = Path(args.out)
    for i in tqdm(range(args.objects), desc="captures", unit="object", file=sys.stderr):
        seed = args.seed + i
        d = out / f"n{i % MAX_MOVING_LINKS + 1}_seed{seed}"
        if (d / "real" / "object.ply").is_file():
            continue  # captured and registered by an earlier run
        spec = sample_chain(n_links=i % MAX_MOVING_LINKS + 1, seed=seed)
        obj = build_object(spec, d / "object")
        simulated_capture(obj.root, d, SensorCaptureConfig(seed=seed))
    from spare_twin.commands.compare import run_batch

    return run_batch(argparse.Namespace(batch=str(out), out=str(out), model=args.model, json=args.json))
