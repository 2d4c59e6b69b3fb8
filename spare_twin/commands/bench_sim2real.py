"""`spare-twin bench sim2real`: the networks' and predict's sim-to-real table on unseen printed objects.

Draws OBJECTS chains (object i: n = i % 6 + 1 moving links, seed SEED + i; the default range, 30000 up,
is held out: docs/sim2real.md names every range used), builds each printable object and captures it
with the simulated hand-held sensor with every effect of a real print and sensor on (joint play,
print error, shadows, flying pixels, dark plastic, principal point, the hand, tracker pose error,
clutter: --effects), renderers alternating (pybullet, open3d's ray caster), sensors spread over the
objects (SR300, Kinect v1, D435 at 848 x 480), poses tracked for half and hidden for the other half;
written out as a 7-Scenes folder and imported as a real capture is.
Rows: predict's combined answer, the measurement alone and each network alone (--models); columns:
the twin in the training rig, the nominal twin along the capture's own cameras, and the capture
(real); count accuracy, wrong answers and no answers apart, E_L (7 slots, paper units), joint-angle
error (objects counted right), overall and per n. A network that cannot read the captures is shown
as refused. Interrupted runs resume: finished objects (same settings, same models by content) are kept.
"""

from __future__ import annotations

import argparse

from spare_twin.errors import SpareTwinError


def add_bench(bsub) -> None:
    """Add `sim2real` to the `spare-twin bench` subparsers."""
    p = bsub.add_parser(
        "sim2real",
        help="sim-to-real table: predict, the measurement and each network alone on captures with every effect",
        description=__doc__.split("\n\n", 1)[1],
    )
    p.add_argument(
        "--out", required=True, metavar="DIR", help="folder for the objects, captures and sim2real.{json,md,png}"
    )
    p.add_argument("--objects", type=int, default=24, help="objects to capture (default 24: four per link count)")
    p.add_argument(
        "--seed", type=int, default=30000, help="seed of the first object and of the settings (default 30000)"
    )
    p.add_argument("--frames", default="15-60", metavar="LO-HI", help="frame counts of the captures (default 15-60)")
    p.add_argument(
        "--sweep", default="120-360", metavar="LO-HI", help="arcs of the hand-held paths (deg; default 120-360)"
    )
    p.add_argument(
        "--sensors",
        default="realsense_sr300:640x480,kinect_v1:640x480,realsense_d435:848x480",
        metavar="NOISE:WxH,...",
        help="depth sensors (noise model capture/rigs/noise_NOISE.json at WxH), spread over the objects "
        "(default realsense_sr300:640x480,kinect_v1:640x480,realsense_d435:848x480)",
    )
    p.add_argument(
        "--renderers",
        default="pybullet,raycast",
        metavar="NAME,...",
        help="renderers of the captures, alternating within each n (default pybullet,raycast)",
    )
    p.add_argument(
        "--effects",
        default="all",
        metavar="all|none|A,B|FILE.json",
        help="capture effects: all (default), none, a comma-separated list of effect names, or a JSON file of "
        "switches and ranges (docs/sensor_effects.md)",
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
        "--models",
        metavar="NAME,...",
        help="networks to score alone: shipped names (models/index.json) or checkpoint files (default: every "
        "shipped model that can read the captures)",
    )
    p.add_argument(
        "--workers", type=int, default=1, metavar="W", help="objects in parallel processes (default 1; same results)"
    )
    p.add_argument("--force", action="store_true", help="replace --out even if it is not an earlier sim2real bench")
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

    from spare_twin.bench.scoring import bench_markdown
    from spare_twin.bench.settings import BenchConfig
    from spare_twin.bench.sim2real import bench_sim2real as run_bench
    from spare_twin.commands.common import flags
    from spare_twin.sim.effects import parse_effects

    with flags(effects="--effects"):
        effects = parse_effects(args.effects, "--effects")
    cfg = BenchConfig(
        objects=args.objects,
        seed=args.seed,
        frames=_range(args.frames, "--frames", int),
        sweep_deg=_range(args.sweep, "--sweep", float),
        sensors=_names(args.sensors, "--sensors"),
        renderers=_names(args.renderers, "--renderers"),
        effects=effects,
        clutter_max=args.clutter_max,
        sim_frames=args.sim_frames,
    )
    models = None if args.models is None else _names(args.models, "--models")
    with flags(
        objects="--objects",
        seed="--seed",
        frames="--frames",
        sweep_deg="--sweep",
        sensors="--sensors",
        renderers="--renderers",
        effects="--effects",
        clutter_max="--clutter-max",
        sim_frames="--sim-frames",
        models="--models",
        workers="--workers",
        force="--force",
    ):
        table, files = run_bench(args.out, cfg, models, args.workers, force=args.force)
    if args.json:
        print(json.dumps(table))
    else:
        print(bench_markdown(table), end="")
        print(f"wrote {', '.join(files.values())}")
    return 0
