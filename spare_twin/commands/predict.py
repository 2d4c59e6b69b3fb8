"""`spare-twin predict`: count and measure the links in a recording (sim or real)."""

from __future__ import annotations

import json
import math


def register(sub) -> None:
    p = sub.add_parser(
        "predict",
        help="count the moving links and measure them in a recording",
        description="Run a network on a recording folder: n_links, link_lengths_m (n + 1 values, base first, "
        "paper units) and the count-class probabilities.",
    )
    p.add_argument("recording", metavar="REC_DIR", help="recording folder (recording.json)")
    p.add_argument("--model", metavar="CKPT", help="checkpoint (default: the shipped model in models/)")
    p.add_argument("--frame", type=int, help="time step for multi-view models (default: the middle frame)")
    p.add_argument("--camera", help="camera for temporal models (default: the first)")
    p.add_argument(
        "--print-scale", type=float, help="physical metres per paper metre (default: the recording's object, else 0.08)"
    )
    p.add_argument("--n-links", type=int, help="the known link count, for length-only models")
    p.add_argument(
        "--yaw-hypotheses",
        type=int,
        default=4,
        choices=(1, 2, 4),
        help="recordings from other cameras: rotations of the found object frame tried (4: every 90 deg, "
        "2: +-x, 1: as found); the most confident output wins (default: 4)",
    )
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    from spare_twin.commands.common import flags
    from spare_twin.nets.predict import predict_recording

    with flags(
        frame="--frame",
        camera="--camera",
        print_scale="--print-scale",
        n_links="--n-links",
        yaw_hypotheses="--yaw-hypotheses",
        device="--device",
        model="--model",
    ):
        res = predict_recording(
            args.recording,
            args.model,
            args.frame,
            args.camera,
            args.print_scale,
            args.n_links,
            args.device,
            yaw_hypotheses=args.yaw_hypotheses,
        )
    if args.json:
        print(json.dumps(res.to_json()))
    elif res.reason is not None:
        print(f"{args.recording}: {res.reason}")
    else:
        lengths = "n/a" if res.link_lengths_pu is None else ", ".join(f"{v:.3f}" for v in res.link_lengths_pu)
        line = f"{res.n_links} moving links; lengths (paper units, base first): {lengths}"
        if res.joint_angles_rad is not None:
            line += "; joint angles (deg): " + ", ".join(f"{math.degrees(a):.1f}" for a in res.joint_angles_rad)
        print(line)
        if res.timings_s:
            print("seconds: " + ", ".join(f"{k} {v:.2f}" for k, v in res.timings_s.items()))
    return 0
