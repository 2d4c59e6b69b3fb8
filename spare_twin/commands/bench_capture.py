"""`spare-twin bench capture`: registration accuracy and time on the APC shelf frames; import and fusion frames/s.

The reference poses are withheld; errors are of relative poses between frames 1, 10 and 40 positions
apart in the sequence. Data: --data DIR holding apc_shelf_realsense/ (default: the repository's
tests/data, 4 of the 50 frames; gaps past the sequence are skipped).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

#: The real frames the repository holds (tests/data/apc_shelf_realsense).
DEFAULT_DATA = Path(__file__).resolve().parents[2] / "tests" / "data"


def add_bench(bsub) -> None:
    """Add `capture` to the `spare-twin bench` subparsers."""
    p = bsub.add_parser(
        "capture",
        help="capture: registration accuracy/time on real RealSense frames, import and fusion frames/s",
        description=__doc__.split("\n\n", 1)[0].split(": ", 1)[1],
    )
    p.add_argument(
        "--data",
        default=None,
        help="folder holding apc_shelf_realsense/ (default: the repository's tests/data)",
    )
    p.add_argument("--gaps", default="1,10,40", help="frame gaps to report, comma-separated (default 1,10,40)")
    p.add_argument("--max-frames", type=int, default=None, help="use only the first N frames (quick runs)")
    p.add_argument("--loop-gaps", default="2", help="registration loop-edge gaps (default 2, the library's)")
    p.add_argument("--voxel", type=float, default=0.004, help="ICP voxel size, metres (default 0.004)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(func=bench_capture)


def bench_capture(args: argparse.Namespace) -> int:
    from spare_twin.bench.capture_registration import bench_registration
    from spare_twin.capture.frames import quiet_open3d
    from spare_twin.capture.registration import RegistrationConfig
    from spare_twin.commands.common import flags
    from spare_twin.errors import SpareTwinError

    quiet_open3d()
    try:
        gaps = tuple(int(v) for v in args.gaps.split(","))
        loops = tuple(int(v) for v in args.loop_gaps.split(",") if v.strip())
    except ValueError:
        raise SpareTwinError("--gaps / --loop-gaps: expected comma-separated integers") from None
    with flags(
        data_dir="--data", gaps="--gaps", voxel_m="--voxel", loop_gaps_frames="--loop-gaps", max_frames="--max-frames"
    ):
        r = bench_registration(
            args.data or DEFAULT_DATA,
            gaps,
            RegistrationConfig(voxel_m=args.voxel, loop_gaps_frames=loops),
            max_frames=args.max_frames,
            progress=not args.json or sys.stderr.isatty(),
        )
    if args.json:
        print(json.dumps(r))
        return 0
    print(f"APC shelf, {r['frames']} frames, reference poses withheld")
    for g, row in r["errors"].items():
        rd, tm = row["rotation_deg"], row["translation_mm"]
        print(
            f"  gap {g:>3}: rotation mean {rd['mean']:.2f} max {rd['max']:.2f} deg | translation mean {tm['mean']:.1f} "
            f"max {tm['max']:.1f} mm ({row['pairs']} pairs){'' if row['within_goal'] else '  OVER GOAL'}"
        )
    met = "met" if r["goal"]["met"] else "NOT met"
    print(
        f"  import {r['import_frames_per_s']:.1f} frames/s, registration {r['registration_s']:.1f} s, "
        f"fusion {r['fusion_frames_per_s']:.1f} frames/s; goal (2 deg, 20 mm) {met}"
    )
    return 0
