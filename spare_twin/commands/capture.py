"""`spare-twin capture`: record, import, register, calibrate, board and view real RGB-D recordings."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterator
from contextlib import contextmanager

from spare_twin.commands.common import flags
from spare_twin.errors import SpareTwinError


@contextmanager
def _flags(hints: dict[str, str] | None = None, **param_to_flag: str) -> Iterator[None]:
    """`flags` (a message that starts with a parameter), plus `hints`: phrases further inside a message
    that name a parameter ("...; wrong depth_scale?"), as this subcommand's user says them."""
    try:
        with flags(**param_to_flag):
            yield
    except SpareTwinError as exc:
        message = str(exc)
        for said, flag in (hints or {}).items():
            message = message.replace(said, flag)
        if message == str(exc):
            raise
        raise SpareTwinError(message) from None


_FORCE_HELP = "replace what is there even if it is not an earlier {what} (once the new one is complete)"


def _out(args, obj: dict, lines: list[str]) -> None:
    """--json: exactly one JSON object on stdout; else human-readable lines."""
    if getattr(args, "json", False):
        print(json.dumps(obj))
    else:
        for line in lines:
            print(line)


def register(sub) -> None:
    p = sub.add_parser(
        "capture",
        help="real RGB-D: record, import, register, calibrate, view",
        description="Capture tools: bring real RGB-D sequences into recordings, register and view them.",
    )
    csub = p.add_subparsers(dest="capture_command", metavar="SUBCOMMAND")
    p.set_defaults(func=lambda args: (p.print_help(sys.stderr), 2)[1])

    r = csub.add_parser("record", help="record from a live Intel RealSense (Ctrl-C stops and keeps every frame)")
    r.add_argument("--out", required=True, help="recording folder to write (a new or empty folder, or an earlier one)")
    r.add_argument("--force", action="store_true", help=_FORCE_HELP.format(what="capture record output"))
    r.add_argument("--width", type=int, default=640)
    r.add_argument("--height", type=int, default=480)
    r.add_argument("--fps", type=int, default=30)
    r.add_argument("--frames", type=int, default=None, help="stop after this many frames (default: until Ctrl-C)")
    r.add_argument("--seconds", type=float, default=None, help="stop after this many seconds")
    r.add_argument("--serial", default="", help="device serial number (default: the first device)")
    r.add_argument("--bag", default=None, help="also save the raw stream to this .bag file")
    r.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    r.set_defaults(func=cmd_record)

    i = csub.add_parser("import", help="a recorded sequence (7scenes, tum, open3d folder, .bag) into a recording")
    i.add_argument("src", help="source folder (or .bag file with --layout bag)")
    i.add_argument("--layout", required=True, choices=("7scenes", "tum", "open3d", "bag"))
    i.add_argument(
        "--out", required=True, help="recording folder to write (a new or empty folder, or an earlier import)"
    )
    i.add_argument("--force", action="store_true", help=_FORCE_HELP.format(what="capture import output"))
    i.add_argument("--intrinsics", default=None, help="fx,fy,cx,cy in pixels (overrides any intrinsics file)")
    i.add_argument(
        "--depth-scale",
        type=float,
        default=None,
        help="metres per depth unit (default: 0.001; TUM 0.0002; open3d/bag: from the metadata)",
    )
    i.add_argument("--fps", type=float, default=None, help="frame rate when the source has no timestamps (default 30)")
    i.add_argument("--stride", type=int, default=1, help="keep every n-th frame")
    i.add_argument("--max-frames", type=int, default=None, help="import at most this many frames")
    i.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    i.set_defaults(func=cmd_import)

    g = csub.add_parser(
        "register",
        help="estimate camera poses, fuse (TSDF) and find the object",
        description="Registers one camera's frames (FPFH+RANSAC, ICP, pose graph), fuses them into "
        "fused.ply and segments the object on the table; results are written into the recording atomically, "
        "everything else in it kept as it was (run it from outside the recording's folder).",
    )
    g.add_argument("rec", help="recording folder")
    g.add_argument("--camera", default=None, help="camera to register (default: the first)")
    ref = g.add_mutually_exclusive_group()
    ref.add_argument(
        "--use-reference",
        dest="use_reference",
        action="store_true",
        default=True,
        help="use the recording's poses as initial guesses when it has them (default)",
    )
    ref.add_argument(
        "--ignore-reference",
        dest="use_reference",
        action="store_false",
        help="register from scratch, ignoring any poses in the recording",
    )
    g.add_argument("--voxel", type=float, default=0.004, help="ICP voxel size in metres (default 0.004)")
    g.add_argument("--max-depth", type=float, default=2.0, help="ignore depth beyond this, metres (default 2.0)")
    g.add_argument(
        "--loop-gaps",
        default="2",
        help="extra edges between frames this many positions apart (default 2; loop closures across the sweep's "
        "seam are added where the views overlap)",
    )
    g.add_argument(
        "--global-init",
        choices=("auto", "always", "never"),
        default="auto",
        help="FPFH+RANSAC initialisation: when the guess fails (auto), on every edge, or never",
    )
    g.add_argument("--tsdf-voxel", type=float, default=0.004, help="TSDF voxel size in metres (default 0.004)")
    g.add_argument("--mesh", action="store_true", help="also write fused_mesh.ply")
    g.add_argument(
        "--object",
        dest="find",
        choices=("auto", "require", "skip"),
        default="auto",
        help="find the object on the table: auto (warn if none), require (error if none), skip",
    )
    g.add_argument("--seed", type=int, default=0, help="RANSAC seed")
    g.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    g.set_defaults(func=cmd_register)

    b = csub.add_parser("board", help="write the ChArUco calibration board (PNG and PDF at true print size)")
    b.add_argument("--out", required=True, help="folder for board.png, board.pdf, board.json")
    b.add_argument("--force", action="store_true", help=_FORCE_HELP.format(what="capture board output"))
    b.add_argument("--squares", default="7x5", help="squares across x down (default 7x5)")
    b.add_argument("--square-mm", type=float, default=35.0)
    b.add_argument("--marker-mm", type=float, default=26.0)
    b.add_argument("--dictionary", default="DICT_5X5_100")
    b.add_argument("--dpi", type=int, default=300)
    b.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    b.set_defaults(func=cmd_board)

    c = csub.add_parser(
        "calibrate",
        help="camera poses from the ChArUco board lying on the table (refined with depth)",
        description="Detects the board in each camera's colour frames, solves the camera pose (PnP), "
        "refines it with depth and stores it as the camera's fixed pose; world = board on the table, z up.",
    )
    c.add_argument("rec", help="recording folder")
    c.add_argument("--board", default=None, help="board.json (default: the built-in 7x5 35 mm board)")
    c.add_argument("--frame", type=int, default=None, help="frame to use (default: the one with most corners)")
    c.add_argument("--no-depth", action="store_true", help="skip the depth refinement")
    c.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    c.set_defaults(func=cmd_calibrate)

    v = csub.add_parser("view", help="log a recording to a Rerun .rrd file (cameras, colour, depth, fused cloud)")
    v.add_argument("rec", help="recording folder")
    v.add_argument("--rrd", required=True, help="output .rrd file (a new file, or an earlier .rrd)")
    v.add_argument("--force", action="store_true", help="replace --rrd even if it is not a Rerun file (never a folder)")
    v.add_argument("--every", type=int, default=1, help="log every n-th frame")
    v.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    v.set_defaults(func=cmd_view)


def _progress(args) -> bool:
    return sys.stderr.isatty() or not getattr(args, "json", False)


def cmd_record(args: argparse.Namespace) -> int:
    from spare_twin.capture.record import RecordConfig, record_realsense

    progress = _progress(args)
    with _flags(
        width="--width", height="--height", fps="--fps", max_frames="--frames", duration_s="--seconds", bag="--bag"
    ):
        rec = record_realsense(
            args.out,
            RecordConfig(args.width, args.height, args.fps, args.frames, args.seconds, args.serial, args.bag),
            progress=progress,
            force=args.force,
        )
    _out(
        args,
        {"recording": str(rec.root), "frames": rec.n_frames, "fps": rec.fps},
        [f"wrote {rec.root} ({rec.n_frames} frames)"],
    )
    return 0


def cmd_import(args: argparse.Namespace) -> int:
    from spare_twin.capture.frames import parse_intrinsics_arg
    from spare_twin.capture.importers import ImportOptions, import_folder

    progress = _progress(args)
    with _flags(
        {"wrong depth_scale?": "wrong --depth-scale?", "pass the intrinsics K": "pass --intrinsics fx,fy,cx,cy"},
        layout="--layout",
        intrinsics="--intrinsics",
        K="--intrinsics",
        depth_scale="--depth-scale",
        fps="--fps",
        stride="--stride",
        max_frames="--max-frames",
    ):
        opts = ImportOptions(
            K=parse_intrinsics_arg(args.intrinsics) if args.intrinsics else None,
            depth_scale=args.depth_scale,
            fps=args.fps,
            max_frames=args.max_frames,
            stride=args.stride,
            progress=progress,
        )
        rec = import_folder(args.src, args.layout, args.out, opts, force=args.force)
    cam = rec.cameras[0]
    _out(
        args,
        {
            "recording": str(rec.root),
            "frames": rec.n_frames,
            "width": cam.width,
            "height": cam.height,
            "depth_scale": rec.depth_scale,
            "poses": cam.poses,
            "fps": rec.fps,
        },
        [
            f"wrote {rec.root}: {rec.n_frames} frames {cam.width}x{cam.height}, depth scale {rec.depth_scale:g} m, "
            f"poses {cam.poses}"
        ],
    )
    return 0


def cmd_register(args: argparse.Namespace) -> int:
    from spare_twin.capture.fusion import FusionConfig
    from spare_twin.capture.pipeline import register_recording
    from spare_twin.capture.registration import RegistrationConfig

    progress = _progress(args)
    try:
        gaps = tuple(int(v) for v in args.loop_gaps.split(",") if v.strip())
    except ValueError:
        raise SpareTwinError(f"--loop-gaps {args.loop_gaps!r}: expected comma-separated integers") from None
    with _flags(
        voxel_m="--voxel", max_depth_m="--max-depth", loop_gaps_frames="--loop-gaps", global_init="--global-init",
        seed="--seed",
    ):  # fmt: skip
        reg = RegistrationConfig(
            voxel_m=args.voxel,
            max_depth_m=args.max_depth,
            loop_gaps_frames=gaps,
            global_init=args.global_init,
            seed=args.seed,
        )
    with _flags(voxel_m="--tsdf-voxel", sdf_trunc_m="--tsdf-voxel", max_depth_m="--max-depth"):
        fus = FusionConfig(voxel_m=args.tsdf_voxel, sdf_trunc_m=4 * args.tsdf_voxel, max_depth_m=args.max_depth)
    with _flags({"lower voxel_m": "lower --voxel"}, find="--object"):
        res = register_recording(
            args.rec,
            reg,
            fus,
            camera=args.camera,
            use_reference=args.use_reference,
            find=args.find,
            mesh=args.mesh,
            progress=progress,
        )
    summary, obj = res.registration.summary, res.registration.object
    _out(
        args,
        res.to_json(),
        [
            f"registered {len(res.frames)} frames of {res.recording} ({summary['edges']} edges)",
            f"wrote {res.recording}/fused.ply ({summary['fused_points']} points)",
            f"object: {obj['points']} points, height {obj['height_m']:.3f} m" if obj else "object: none found",
        ],
    )
    return 0


def cmd_board(args: argparse.Namespace) -> int:
    from spare_twin.capture.board import BoardSpec, write_board

    try:
        sx, sy = (int(v) for v in args.squares.lower().split("x"))
    except ValueError:
        raise SpareTwinError(f"--squares {args.squares!r}: expected e.g. 7x5") from None
    with _flags(
        squares_x="--squares", squares_y="--squares", square_m="--square-mm", marker_m="--marker-mm",
        dictionary="--dictionary", dpi="--dpi",
    ):  # fmt: skip
        spec = BoardSpec(sx, sy, args.square_mm / 1000, args.marker_mm / 1000, args.dictionary, args.dpi)
        paths = write_board(spec, args.out, force=args.force)
    _out(
        args,
        {k: str(v) for k, v in paths.items()} | {"size_m": list(spec.size_m)},
        [f"wrote {p}" for p in paths.values()]
        + [f"print at 100 % on A4: the board is {spec.size_m[0] * 1000:.0f} x {spec.size_m[1] * 1000:.0f} mm"],
    )
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    from spare_twin.capture.board import BoardSpec
    from spare_twin.capture.calibrate import calibrate_recording

    _progress(args)
    spec = BoardSpec.load(args.board) if args.board else BoardSpec()
    with _flags(frame="--frame"):
        out = calibrate_recording(args.rec, spec, frame=args.frame, use_depth=not args.no_depth)
    _out(
        args,
        out,
        [
            f"{c['name']}: frame {c['frame']}, {c['corners']} corners, reprojection {c['reprojection_px']:.2f} px"
            + (f", depth shift {c['depth']['shift_mm']:.1f} mm" if c.get("depth") else "")
            for c in out["cameras"]
        ]
        + [f"wrote camera poses into {out['recording']}"],
    )
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    from spare_twin.capture.view import ViewConfig, log_recording

    progress = _progress(args)
    with _flags(every="--every"):
        out = log_recording(args.rec, args.rrd, ViewConfig(every=args.every), progress=progress, force=args.force)
    _out(
        args,
        out,
        [
            f"wrote {out['rrd']} ({out['frames']} frames, {len(out['cameras'])} cameras, "
            f"{out['fused_points']} fused points)"
        ],
    )
    return 0
