"""`spare-twin bench`: performance benchmarks, one subcommand each; the benchmarks themselves are
modules of `spare_twin.bench` (its docstring lists them). Here: the flags, and the figures printed."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from spare_twin.commands.common import flags
from spare_twin.errors import SpareTwinError

#: The real frames the repository holds (tests/data/apc_shelf_realsense): `bench capture`'s default data.
DEFAULT_CAPTURE_DATA = Path(__file__).resolve().parents[2] / "tests" / "data"

DATASET_DESCRIPTION = """\
`bench dataset`: dataset images/s end to end on the local and the Ray backend against pybullet's raw
render loop for the same rig and objects, measured in the same run and interleaved, for 1 and 2 workers;
Ray's cost per task; and the wall time of the `paper` preset (measured with --paper full, else
extrapolated from the measured rate). spare_twin/bench/dataset.py says how each figure is measured.
"""

CAPTURE_DESCRIPTION = "registration accuracy and time on the APC shelf frames; import and fusion frames/s."

LIVE_DESCRIPTION = (
    "Render a 640x480, 30 fps simulated hand-held sweep (or take --rec), replay it through `live` in real "
    "time and print: seconds from the first frame to the first estimate, the interval between updates, frames "
    "received / placed / dropped, peak RSS, and the last update against the final answer (predict on the "
    "recording live wrote) and the truth."
)

SIM2REAL_DESCRIPTION = """\
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

TRAINING_DESCRIPTION = (
    "`spare-twin bench training`: training samples/s per preset under several speed settings, measured back "
    "to back in the same run, as ratios against the trainer's defaults (the first setting)."
)

DEFAULT_SENSORS = "realsense_sr300:640x480,kinect_v1:640x480,realsense_d435:848x480"


def register(sub) -> None:
    p = sub.add_parser(
        "bench",
        help="performance benchmarks (bench dataset, ...)",
        description="Performance benchmarks; each subcommand measures one stage.",
    )
    bsub = p.add_subparsers(dest="benchmark", metavar="BENCHMARK")
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])
    for name, help_text, description, add_flags, run in BENCHMARKS:
        b = bsub.add_parser(name, help=help_text, description=description)
        add_flags(b)
        b.set_defaults(func=run)


def _json_flag(p) -> None:
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def _report(args: argparse.Namespace, figures, text: str) -> int:
    """--json: `figures` as one JSON object on stdout; else `text` (whole lines)."""
    print(json.dumps(figures) if args.json else text, end="\n" if args.json else "")
    return 0


def _lines(lines) -> str:
    return "".join(f"{line}\n" for line in lines)


def _log(args: argparse.Namespace):
    """Progress lines: on stderr when stdout holds the JSON, else on stdout."""
    return (lambda line: print(line, file=sys.stderr)) if args.json else print


def _integers(text: str, flag: str, example: str, blanks_ok: bool = False) -> tuple[int, ...]:
    """Comma-separated integers, "1,16" -> (1, 16); with blanks_ok, empty items are skipped ("": none)."""
    try:
        return tuple(int(v) for v in text.split(",") if not blanks_ok or v.strip())
    except ValueError:
        raise SpareTwinError(f"{flag} {text!r}: expected comma-separated integers like {example}") from None


# -- bench dataset ---------------------------------------------------------------------------------
def _dataset_flags(d) -> None:
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
    _json_flag(d)


def bench_dataset(args: argparse.Namespace) -> int:
    from spare_twin.bench.dataset import DatasetBench, bench_dataset

    worker_counts = _integers(args.workers, "--workers", "1,2")
    with flags(instances="--instances", workers="--workers", frames="--frames", rounds="--rounds", paper="--paper"):
        b = DatasetBench(
            args.instances, worker_counts, args.frames, args.geometry, args.rounds, not args.no_ray, args.paper
        )
        result = bench_dataset(b, log=_log(args))
    return _report(args, result.to_json(), "")  # the text is the log, printed as it went


# -- bench capture ---------------------------------------------------------------------------------
def _capture_flags(p) -> None:
    p.add_argument(
        "--data",
        default=None,
        help="folder holding apc_shelf_realsense/ (default: the repository's tests/data)",
    )
    p.add_argument("--gaps", default="1,10,40", help="frame gaps to report, comma-separated (default 1,10,40)")
    p.add_argument("--max-frames", type=int, default=None, help="use only the first N frames (quick runs)")
    p.add_argument("--loop-gaps", default="2", help="registration loop-edge gaps (default 2, the library's)")
    p.add_argument("--voxel", type=float, default=0.004, help="ICP voxel size, metres (default 0.004)")
    _json_flag(p)


def bench_capture(args: argparse.Namespace) -> int:
    from spare_twin.bench.capture_registration import bench_registration
    from spare_twin.capture.registration import RegistrationConfig
    from spare_twin.open3d_loader import quiet_open3d

    quiet_open3d()
    gaps = _integers(args.gaps, "--gaps", "1,10,40")
    loops = _integers(args.loop_gaps, "--loop-gaps", "2", blanks_ok=True)  # "": no loop edges
    with flags(
        data_dir="--data", gaps="--gaps", voxel_m="--voxel", loop_gaps_frames="--loop-gaps", max_frames="--max-frames"
    ):
        r = bench_registration(
            args.data or DEFAULT_CAPTURE_DATA,
            gaps,
            RegistrationConfig(voxel_m=args.voxel, loop_gaps_frames=loops),
            max_frames=args.max_frames,
            progress=not args.json or sys.stderr.isatty(),
        )
    lines = [f"APC shelf, {r['frames']} frames, reference poses withheld"]
    for g, row in r["errors"].items():
        rd, tm = row["rotation_deg"], row["translation_mm"]
        lines.append(
            f"  gap {g:>3}: rotation mean {rd['mean']:.2f} max {rd['max']:.2f} deg | translation mean {tm['mean']:.1f} "
            f"max {tm['max']:.1f} mm ({row['pairs']} pairs){'' if row['within_goal'] else '  OVER GOAL'}"
        )
    met = "met" if r["goal"]["met"] else "NOT met"
    lines.append(
        f"  import {r['import_frames_per_s']:.1f} frames/s, registration {r['registration_s']:.1f} s, "
        f"fusion {r['fusion_frames_per_s']:.1f} frames/s; goal (2 deg, 20 mm) {met}"
    )
    return _report(args, r, _lines(lines))


# -- bench live ------------------------------------------------------------------------------------
def _live_flags(p) -> None:
    p.add_argument("--frames", type=int, default=300, help="frames of the rendered sweep (default: 300, 10 s)")
    p.add_argument("--resolution", default="640x480", help="WxH of the rendered sweep (default: 640x480)")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate of the rendered sweep (default: 30)")
    p.add_argument("--speed", type=float, default=1.0, help="replay speed (default: 1, real time)")
    p.add_argument("--rec", metavar="REC_DIR", help="replay this recording instead of rendering one")
    p.add_argument("--rrd", metavar="OUT.rrd", help="also save the live view (replaces OUT.rrd)")
    p.add_argument("--json", action="store_true", help="print the figures as one JSON object")


def bench_live(args: argparse.Namespace) -> int:
    from spare_twin.bench.live import LiveBench, bench_live

    with flags(frames="--frames", resolution="--resolution", fps="--fps", speed="--speed", rec="--rec"):
        cfg = LiveBench(args.frames, args.resolution, args.fps, args.speed, args.rec, args.rrd)
        fig = bench_live(cfg, _log(args)).to_json()
    return _report(args, fig, _lines(f"  {key}: {value}" for key, value in fig.items()))


# -- bench nets ------------------------------------------------------------------------------------
def _nets_flags(p) -> None:
    src = p.add_mutually_exclusive_group()
    src.add_argument("--model", metavar="CKPT", help="a checkpoint (default: the shipped predict model)")
    src.add_argument(
        "--preset", metavar="NAME", help="an untrained network of this preset (speed does not depend on weights)"
    )
    p.add_argument("--batch-sizes", default="1,16", help="comma-separated (default 1,16)")
    p.add_argument("--iters", type=int, default=10)
    p.add_argument("--threads", type=int, help="torch CPU threads (default: torch's)")
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    _json_flag(p)


def bench_nets(args: argparse.Namespace) -> int:
    from spare_twin.bench.nets import bench_network

    sizes = _integers(args.batch_sizes, "--batch-sizes", "1,16", blanks_ok=True)
    with flags(
        model="--model",
        preset="--preset",
        batch_sizes="--batch-sizes",
        iters="--iters",
        threads="--threads",
        device="--device",
    ):
        res = bench_network(args.model, args.preset, sizes, args.iters, args.threads, args.device).to_json()
    lines = (
        f"{res['model']} batch {bs}: {r['samples_per_s']:.1f} samples/s, {r['latency_ms_per_sample']:.1f} "
        f"ms/sample ({res['threads']} threads, {res['device']})"
        for bs, r in res["batch_sizes"].items()
    )
    return _report(args, res, _lines(lines))


# -- bench object ----------------------------------------------------------------------------------
def _object_flags(p) -> None:
    p.add_argument("--repeats", type=int, default=5, help="objects per measurement (different seeds)")
    p.add_argument("--json", action="store_true", help="print the figures as one JSON object")


def bench_object(args: argparse.Namespace) -> int:
    from spare_twin.bench.object import bench_object

    with flags(repeats="--repeats"):
        res = bench_object(args.repeats).to_json()
    lines = [
        f"6-link object, median of {res['objects']}:",
        f"  geometry only (manifold3d parts -> meshes): {res['geometry_s']:.3f} s",
        f"  object folder (STLs, checks, URDF, preview): {res['object_folder_s']:.3f} s",
        f"  whole CLI (new process):                     {res['whole_cli_s']:.3f} s "
        f"= {res['cli_over_geometry']:.1f} x geometry (python start-up alone: {res['python_startup_s']:.3f} s)",
    ]
    return _report(args, res, _lines(lines))


# -- bench sim2real --------------------------------------------------------------------------------
def _sim2real_flags(p) -> None:
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
        default=DEFAULT_SENSORS,
        metavar="NOISE:WxH,...",
        help="depth sensors (noise model capture/rigs/noise_NOISE.json at WxH), spread over the objects "
        f"(default {DEFAULT_SENSORS})",
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
    p.add_argument("--sim-frames", type=int, default=10, metavar="F", help="frames of the twin in the rig (default 10)")
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
    from spare_twin.bench.settings import BenchConfig, check_bench
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
        # checked before the bench's modules are imported: torch and the measurement take 5 s to load
        check_bench(args.out, cfg, args.workers, args.force)
        from spare_twin.bench.sim2real import bench_sim2real as run_bench

        table, files = run_bench(args.out, cfg, models, args.workers, force=args.force)
    from spare_twin.bench.scoring import bench_markdown

    text = "" if args.json else bench_markdown(table) + f"wrote {', '.join(files.values())}\n"
    return _report(args, table, text)


# -- bench training --------------------------------------------------------------------------------
def _training_flags(p) -> None:
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
    _json_flag(p)


def _speed_settings(text: str) -> list:
    """THREADS/WORKERS[/cl],... -> SpeedSettings."""
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


def bench_training(args: argparse.Namespace) -> int:
    from spare_twin.bench.training import bench_training, default_presets, default_settings

    settings = _speed_settings(args.settings) if args.settings else default_settings()
    presets = [p for p in args.presets.split(",") if p] if args.presets else list(default_presets())
    with flags(data_dir="--data", presets="--presets", steps="--steps"):
        res = bench_training(presets, args.data, settings, args.steps, log=_log(args))
    figures = {"settings": [s.label for s in settings], "presets": [r.to_json(settings) for r in res]}
    lines = ["", f"samples/s ({', '.join(s.label for s in settings)}); ratio against the first"]
    for r in res:
        cells = [f"{v:.1f} ({v / r.samples_per_s[0]:.2f}x)" for v in r.samples_per_s]
        lines.append(f"  {r.preset:<26} " + "  ".join(cells))
    return _report(args, figures, _lines(lines))


#: Every benchmark, in `bench --help`'s order: (name, help, description, its flags, its handler).
BENCHMARKS = (
    (
        "dataset",
        "dataset generation: end-to-end images/s vs the raw pybullet render loop",
        DATASET_DESCRIPTION,
        _dataset_flags,
        bench_dataset,
    ),
    (
        "capture",
        "capture: registration accuracy/time on real RealSense frames, import and fusion frames/s",
        CAPTURE_DESCRIPTION,
        _capture_flags,
        bench_capture,
    ),
    (
        "live",
        "live's latency and memory on a 640x480 30 fps sweep replayed in real time",
        LIVE_DESCRIPTION,
        _live_flags,
        bench_live,
    ),
    ("nets", "network inference speed: samples/s and latency per sample", None, _nets_flags, bench_nets),
    ("object", "time building 6-link objects (geometry only, and the whole CLI)", None, _object_flags, bench_object),
    (
        "sim2real",
        "sim-to-real table: predict, the measurement and each network alone on captures with every effect",
        SIM2REAL_DESCRIPTION,
        _sim2real_flags,
        bench_sim2real,
    ),
    (
        "training",
        "training speed: samples/s per preset under thread / worker / memory-layout settings",
        TRAINING_DESCRIPTION,
        _training_flags,
        bench_training,
    ),
)
