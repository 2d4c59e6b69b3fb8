"""`spare-twin predict`: count and measure the links in a recording (sim or real); the answer says its sources."""

from __future__ import annotations

import json
import sys


def register(sub) -> None:
    p = sub.add_parser(
        "predict",
        help="count the moving links and measure them in a recording; the answer says its sources",
        description="Count and measure the chain in a recording folder. Two estimators run: the layer measurement "
        "on the object's points (no network) and a network (default: the shipped yaw-free profile network). "
        "--answer combined (the default) is the measurement where it finds a chain and the network's estimate "
        "elsewhere, or where the network is sure (p >= 0.95) of another count or of its count where the measured "
        "layers blur (image networks: the network's estimate; outside their training rig, no answer where the "
        "measurement finds no chain). "
        "--json prints version 2 of spare-twin-prediction: n_links, link_lengths_pu (n + 1 values, base first, "
        "paper units), link_lengths_mm (at the print scale used), joint_angles_rad, source (which estimate gave "
        "which field), then each estimate with its evidence under network and measurement (null where not run), "
        "and parts (the part dimensions the chain was observed and measured with, --parts); "
        "n_links is null, with a reason, where there is no chain in view or the evidence is too weak.",
    )
    p.add_argument("recording", metavar="REC_DIR", help="recording folder (recording.json)")
    p.add_argument(
        "--answer",
        default="combined",
        choices=("combined", "network", "measurement"),
        help="which estimate is the answer: combined (default), the network's alone, or the measurement's alone",
    )
    p.add_argument("--model", metavar="CKPT", help="checkpoint (default: models/'s predict model, the profile network)")
    p.add_argument("--frame", type=int, help="time step of a multi-camera recording (default: the middle frame)")
    p.add_argument(
        "--camera",
        help="read this one camera as a sweep of its frames, or give it to a temporal model (default: every posed "
        "camera at one time step where there are several, else the only one)",
    )
    p.add_argument(
        "--print-scale",
        type=float,
        help="physical metres per paper metre, for paper units and link_lengths_mm (default: 0.08; the recording's "
        "own object configuration is never read)",
    )
    p.add_argument(
        "--parts",
        metavar="FILE",
        help="the part dimensions the chain was printed with, in mm: a JSON file with the parts block of an "
        'object configuration (e.g. {"link_thickness_mm": 8.0}; the rest the defaults), or an object.json '
        "or object folder whose parts it takes; the layer pitch, plates and socket the chain is observed and "
        "measured with (default: the default parts, on which every network was trained)",
    )
    p.add_argument("--n-links", type=int, help="the known link count, for a lengths-only model only")
    p.add_argument(
        "--yaw-hypotheses",
        type=int,
        choices=(1, 2, 4),
        help="image networks on recordings from other cameras only: rotations of the found object frame tried "
        "(4: every 90 deg, 2: +-x, 1: as found); the most confident output wins (default: 4)",
    )
    p.add_argument(
        "--outside-rig",
        action="store_true",
        help="image networks only: run one on a capture from other cameras than its training rig (a hand-held "
        "sweep), which it refuses otherwise; a diagnostic of its sim-to-real gap, labelled so in the output",
    )
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    # The default (profile) network's path in a process that has yet to import torch: the recording is
    # measured in a process of its own (predict.early), started first of all, so that it starts up while
    # this command imports the measurement and torch (1.3 s and 3 s of this machine's CPU).
    measuring = None
    if args.model is None and args.device == "cpu" and "torch" not in sys.modules:
        from spare_twin.measure.process import MeasureProcess

        measuring = MeasureProcess("predict: the measuring process", wait=False)
    try:
        res = _predicted(args, measuring)
    finally:
        if measuring is not None:
            measuring.close(kill=True)
    if args.json:
        print(json.dumps(res.to_json()))
    elif res.reason is not None and res.network is None:  # no network ran: the one reason is all there is
        print(f"{args.recording}: {res.reason}")
    else:
        for line in res.in_words():
            print(line)
        if res.timings_s:
            print("seconds: " + ", ".join(f"{k} {v:.2f}" for k, v in res.timings_s.items()))
    return 0


def _predicted(args, measuring):
    """`predict_recording` with the command's options, the recording measured in `measuring` (a
    process not yet asked anything) where there is one."""
    from spare_twin.commands.common import flags
    from spare_twin.predict.early import check_options, start_measuring
    from spare_twin.predict.parts import read_parts
    from spare_twin.validate import check_file

    with flags(
        frame="--frame",
        camera="--camera",
        print_scale="--print-scale",
        n_links="--n-links",
        yaw_hypotheses="--yaw-hypotheses",
        device="--device",
        model="--model",
        answer="--answer",
        outside_rig="--outside-rig",
        parts="--parts",
    ):
        parts = read_parts(args.parts) if args.parts is not None else None
        check_options(args.frame, args.print_scale, args.n_links, args.yaw_hypotheses, args.device, args.answer, parts)
        if args.model is not None:  # said before torch is imported to read it (3 s of a new process)
            check_file(args.model, "checkpoint")
        if measuring is not None:
            start_measuring(args.recording, args.frame, args.camera, args.print_scale, parts, process=measuring)
        from spare_twin.predict.run import predict_recording

        return predict_recording(
            args.recording,
            args.model,
            args.frame,
            args.camera,
            args.print_scale,
            args.n_links,
            args.device,
            yaw_hypotheses=args.yaw_hypotheses,
            answer=args.answer,
            outside_rig=args.outside_rig,
            parts=parts,
            measuring=measuring,
        )
