"""`spare-twin bench live`: `live` on a 640 x 480, 30 fps hand-held sweep replayed in real time:
time to the first estimate, update interval, peak RSS, the last update against the final answer."""

from __future__ import annotations

import json
import sys

from spare_twin.commands.common import flags


def add_bench(sub) -> None:
    p = sub.add_parser(
        "live",
        help="live's latency and memory on a 640x480 30 fps sweep replayed in real time",
        description="Render a 640x480, 30 fps simulated hand-held sweep (or take --rec), replay it through "
        "`live` in real time and print: seconds from the first frame to the first estimate, the interval between "
        "updates, frames received / placed / dropped, peak RSS, and the last update against the final answer "
        "(predict on the recording live wrote) and the truth.",
    )
    p.add_argument("--frames", type=int, default=300, help="frames of the rendered sweep (default: 300, 10 s)")
    p.add_argument("--resolution", default="640x480", help="WxH of the rendered sweep (default: 640x480)")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate of the rendered sweep (default: 30)")
    p.add_argument("--speed", type=float, default=1.0, help="replay speed (default: 1, real time)")
    p.add_argument("--rec", metavar="REC_DIR", help="replay this recording instead of rendering one")
    p.add_argument("--rrd", metavar="OUT.rrd", help="also save the live view (replaces OUT.rrd)")
    p.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    p.set_defaults(func=run)


def run(args) -> int:
    from spare_twin.bench.live import LiveBench, bench_live

    log = (lambda line: print(line, file=sys.stderr)) if args.json else print
    with flags(frames="--frames", resolution="--resolution", fps="--fps", speed="--speed", rec="--rec"):
        res = bench_live(LiveBench(args.frames, args.resolution, args.fps, args.speed, args.rec, args.rrd), log)
    fig = res.to_json()
    if args.json:
        print(json.dumps(fig))
        return 0
    for key, value in fig.items():
        print(f"  {key}: {value}")
    return 0
