"""`spare-twin live`: the chain measured while the camera moves, shown in Rerun, written as a recording."""

from __future__ import annotations

import json
import sys


def register(sub) -> None:
    p = sub.add_parser(
        "live",
        help="estimate the chain while the camera moves (RealSense, .bag or a replayed recording), live in Rerun",
        description="Frames from a RealSense (default), a .bag (--bag) or a recording folder replayed at its own "
        "frame rate (--replay) are written to --out as a recording, placed one by one against the frames before "
        "them, and the chain is estimated from them at least once a second with predict's own core (count, "
        "lengths, joint angles, sources and evidence). 'enough: n = ...' is said once the answer has held for "
        "--stable-s seconds with strong evidence (--until-stable stops there). Frames that come faster than "
        "they can be used are dropped from the estimate, never from the recording; Ctrl-C keeps every frame "
        "received as a valid recording. The last answer is predict's on the recording written. --jsonl prints "
        "one JSON object per update: predict --json's keys plus t_s, frames_used, frames_received, "
        "frames_placed, frames_dropped, wall_s, enough and final (the last line, final: true).",
    )
    p.add_argument("--out", required=True, metavar="REC_DIR", help="recording folder to write (absent, empty or "
                   "an earlier live recording, replaced once the new one is whole)")  # fmt: skip
    p.add_argument("--force", action="store_true", help="replace --out (or --rrd) even if it holds something else")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--replay", metavar="REC_DIR", help="replay this recording folder's camera instead of a sensor")
    src.add_argument("--bag", metavar="FILE", help="read this RealSense .bag file instead of a sensor")
    p.add_argument(
        "--speed",
        type=float,
        default=1.0,
        help="--replay/--bag: times the source's own frame rate (default 1); 0: as fast as frames are used, "
        "none dropped",
    )
    p.add_argument("--rrd", metavar="OUT.rrd", help="save the live view to this Rerun file instead of a viewer")
    p.add_argument("--connect", metavar="ADDR", help="send the live view to a running viewer (rerun+http://...)")
    p.add_argument("--no-viewer", action="store_true", help="no live view at all (default: spawn a Rerun viewer)")
    p.add_argument("--object", metavar="OBJECT_DIR", help="the printed object's folder: its URDF is posed in the "
                   "view (default: a twin built from the estimate)")  # fmt: skip
    p.add_argument("--jsonl", action="store_true", help="one JSON object per update on stdout, the last the final")
    p.add_argument("--until-stable", action="store_true", help="stop the stream once the answer is 'enough'")
    p.add_argument("--stable-s", type=float, default=3.0, help="seconds the answer must hold (default: 3)")
    p.add_argument("--update-s", type=float, default=1.0, help="seconds between estimates at most (default: 1)")
    p.add_argument(
        "--views",
        type=int,
        default=16,
        help="the most placed frames an update reads; updates start with 8 and read more or fewer to keep the "
        "rate, the last one (after the stream) this many (default: 16)",
    )
    p.add_argument(
        "--answer", default="combined", choices=("combined", "network", "measurement"), help="as predict's --answer"
    )
    p.add_argument("--model", metavar="CKPT", help="profile network checkpoint (default: predict's)")
    p.add_argument("--print-scale", type=float, default=0.08, help="physical metres per paper metre (default 0.08)")
    p.add_argument("--parts", metavar="FILE", help="the part dimensions the chain was printed with, as predict's "
                   "--parts (default: the default parts)")  # fmt: skip
    p.set_defaults(func=run)


def run(args) -> int:
    # The options, the outputs and the source are checked (and the source opened) before the estimate's
    # modules are imported: torch and the measurement take 5 s to load, and "no device" should not wait.
    from spare_twin.commands.common import flags
    from spare_twin.live.config import LiveConfig
    from spare_twin.live.sources import open_live
    from spare_twin.predict.parts import read_parts

    out_lines = []

    def on_update(u) -> None:
        if args.jsonl:
            print(json.dumps(u.to_json()), flush=True)
        else:
            out_lines.append(u)
            p = u.prediction
            what = "final (predict on the recording)" if u.final else f"{u.t_s:6.1f} s"
            if p.n_links is None:
                print(f"{what}: no answer ({p.reason}); {u.frames_received} frames", flush=True)
            else:
                lengths = ", ".join(f"{v:.3f}" for v in p.link_lengths_pu)
                print(f"{what}: n = {p.n_links}, lengths {lengths} pu; {u.frames_received} frames, "
                      f"{u.frames_dropped} dropped", flush=True)  # fmt: skip

    with flags(
        replay="--replay",
        bag="--bag",
        speed="--speed",
        stable_s="--stable-s",
        update_s="--update-s",
        views="--views",
        print_scale="--print-scale",
        answer="--answer",
        model="--model",
        rrd="--rrd",
        connect="--connect",
        object_dir="--object",
        parts="--parts",
    ):
        parts = read_parts(args.parts) if args.parts is not None else None
        LiveConfig(update_s=args.update_s, stable_s=args.stable_s, until_stable=args.until_stable, views=args.views)
        source = open_live(args.out, args.replay, args.bag, args.speed, args.rrd, args.connect, args.force)
        try:
            from spare_twin.live.run import live
        except BaseException:
            source.close()
            raise
        res = live(
            args.out,
            replay=args.replay,
            bag=args.bag,
            speed=args.speed,
            rrd=args.rrd,
            connect=args.connect,
            viewer=not args.no_viewer,
            object_dir=args.object,
            until_stable=args.until_stable,
            stable_s=args.stable_s,
            update_s=args.update_s,
            views=args.views,
            answer=args.answer,
            model=args.model,
            print_scale=args.print_scale,
            parts=parts,
            on_update=on_update,
            say=lambda line: print(line, file=sys.stderr, flush=True),
            force=args.force,
            source=source,
        )
    tail = f"; view saved to {args.rrd}" if args.rrd else ""
    print(f"wrote {args.out}: {res.frames_received} frames ({res.frames_placed} placed, {res.frames_dropped} dropped "
          f"from the estimate){tail}", file=sys.stderr)  # fmt: skip
    return 0
