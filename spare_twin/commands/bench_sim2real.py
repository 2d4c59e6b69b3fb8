"""`spare-twin bench sim2real`: predict-only sim-to-real figures on unseen printed objects.

Draws OBJECTS chains from the paper's distribution (object i: n = i % 6 + 1 moving links, seed
SEED + i; seeds from 7000 up, which no dataset, test or demo uses, so no model saw them), builds each
printable object and captures it with the simulated hand-held sensor, its settings varied per object
from a seeded table (arc, frame count, resolution, fitted noise model, clutter on the table; poses
hidden for half of each n), written out as a 7-Scenes folder and imported as a real capture is.
Scores per n and overall: count accuracy and E_L (7 slots, paper units) for the twin in the training
rig (sim) and for `predict` on the capture alone (real: no object folder, no print scale, no poses
beyond the recording's), the real joint-angle error over objects counted right (up to one global
sign: a planar chain's mirror image), and predict's wall time per capture.
Interrupted runs resume: finished objects (same settings, same model by content) are kept.
"""

from __future__ import annotations

import argparse

from spare_twin.errors import SpareTwinError


def add_bench(bsub) -> None:
    """Add `sim2real` to the `spare-twin bench` subparsers."""
    p = bsub.add_parser(
        "sim2real",
        help="sim-to-real table: predict alone on simulated hand-held captures of unseen objects",
        description=__doc__.split("\n\n", 1)[1],
    )
    p.add_argument(
        "--out", required=True, metavar="DIR", help="folder for the objects, captures and sim2real.{json,md,png}"
    )
    p.add_argument("--objects", type=int, default=24, help="objects to capture (default 24: four per link count)")
    p.add_argument("--seed", type=int, default=7000, help="seed of the first object and of the settings (default 7000)")
    p.add_argument("--frames", default="15-60", metavar="LO-HI", help="frame counts of the captures (default 15-60)")
    p.add_argument(
        "--sweep", default="120-360", metavar="LO-HI", help="arcs of the hand-held paths (deg; default 120-360)"
    )
    p.add_argument(
        "--resolutions",
        default="320x240,640x480,848x480",
        metavar="WxH,...",
        help="capture resolutions, comma-separated (default 320x240,640x480,848x480)",
    )
    p.add_argument(
        "--noise",
        default="realsense_sr300,kinect_v1",
        metavar="NAME,...",
        help="fitted noise models capture/rigs/noise_NAME.json, comma-separated (default realsense_sr300,kinect_v1)",
    )
    p.add_argument("--clutter-max", type=int, default=4, metavar="N", help="clutter items 0..N (default 4)")
    p.add_argument(
        "--sim-frames",
        type=int,
        default=10,
        metavar="F",
        help="frames of the twin in the rig (default 10)",
    )
    p.add_argument(
        "--twin-aligned",
        action="store_true",
        help="also run `compare` (articulated fit, real cameras re-aligned onto the printed twin) per object: "
        "a slow diagnostic, reported as real_twin_aligned, never as real",
    )
    p.add_argument("--model", metavar="CKPT", help="network checkpoint (default: the shipped model)")
    p.add_argument("--force", action="store_true", help="replace --out even if it is not an earlier sim2real benchmark")
    p.add_argument("--json", action="store_true", help="print the whole table as one JSON object")
    p.set_defaults(func=bench_sim2real)


def _range(text: str, flag: str, kind) -> tuple:
    """LO-HI (or one value) -> (lo, hi)."""
    try:
        parts = [kind(v) for v in text.split("-")]
    except ValueError:
        parts = []
    if len(parts) not in (1, 2):
        raise SpareTwinError(f"{flag} {text!r}: expected LO-HI, e.g. 15-60")
    return parts[0], parts[-1]


def _names(text: str, flag: str) -> tuple[str, ...]:
    names = tuple(v.strip() for v in text.split(",") if v.strip())
    if not names:
        raise SpareTwinError(f"{flag} {text!r}: give at least one value")
    return names


def bench_sim2real(args: argparse.Namespace) -> int:
    import json

    from spare_twin.commands.common import flags
    from spare_twin.compare.batch import BenchConfig, bench_markdown
    from spare_twin.compare.batch import bench_sim2real as run_bench

    cfg = BenchConfig(
        objects=args.objects,
        seed=args.seed,
        frames=_range(args.frames, "--frames", int),
        sweep_deg=_range(args.sweep, "--sweep", float),
        resolutions=_names(args.resolutions, "--resolutions"),
        noises=_names(args.noise, "--noise"),
        clutter_max=args.clutter_max,
        sim_frames=args.sim_frames,
        twin_aligned=args.twin_aligned,
    )
    with flags(
        objects="--objects",
        seed="--seed",
        frames="--frames",
        sweep_deg="--sweep",
        resolutions="--resolutions",
        noises="--noise",
        clutter_max="--clutter-max",
        sim_frames="--sim-frames",
        model="--model",
        force="--force",
    ):
        table, files = run_bench(args.out, cfg, args.model, force=args.force)
    if args.json:
        print(json.dumps(table))
    else:
        print(bench_markdown(table), end="")
        print(f"wrote {', '.join(files.values())}")
    return 0
