"""`spare-twin render OBJECT_DIR --out REC_DIR`: a twin-simulation recording of one object."""

from __future__ import annotations

import argparse

from spare_twin.commands.common import flags


def register(sub) -> None:
    p = sub.add_parser(
        "render",
        help="render a twin-simulation recording of an object folder (rig, random motion, RGB-D frames, ground truth)",
        description="Load OBJECT_DIR's URDF in pybullet, move its joints smoothly at random (within the limits, "
        "clear of the foot) and record every rig camera (or one hand-held camera, --path handheld): colour, "
        "depth, link segmentation, intrinsics, poses and per-frame ground truth, as a spare-twin recording. "
        "The same seed and options give a byte-identical recording.",
    )
    p.add_argument(
        "object_dir",
        metavar="OBJECT_DIR",
        help="object folder written by `spare-twin object`; with --empty it still sets the scene (the camera "
        "path, the clutter kept clear of where the object stands) but is not put on the table",
    )
    p.add_argument(
        "--out",
        required=True,
        metavar="REC_DIR",
        help="recording folder to write: absent, empty or an earlier render (replaced once the new one is whole)",
    )
    p.add_argument("--force", action="store_true", help="replace --out even if it holds something else")
    p.add_argument("--rig", default="spare8", help="rig name in capture/rigs/ or a rig JSON file (default: spare8)")
    p.add_argument("--frames", type=int, default=100, help="frames to record (default: 100)")
    p.add_argument("--fps", type=float, default=10.0, help="frame rate (default: 10)")
    p.add_argument("--seed", type=int, default=0, help="seed of the motion (default: 0)")
    p.add_argument(
        "--resolution",
        default="record",
        metavar="record|network|WxH",
        help="record: the rig's high resolution (default); network: 96x128; or WxH, e.g. 640x480 "
        "(the rig's field of view)",
    )
    p.add_argument("--no-segmentation", action="store_true", help="skip the link segmentation images")
    p.add_argument(
        "--path",
        choices=("rig", "handheld"),
        default="rig",
        help="rig: the rig's fixed cameras (default); handheld: ONE camera carried around the object on "
        "a smooth seeded path (a simulated real capture; recording rig = null, per-frame poses)",
    )
    p.add_argument(
        "--noise",
        default="none",
        metavar="NAME|none",
        help="depth-sensor noise model capture/rigs/noise_NAME.json (e.g. realsense_sr300) or a JSON file; "
        "depth is then stored in the sensor's unit (default: none, clean depth at 0.1 mm)",
    )
    p.add_argument(
        "--motion",
        choices=("moving", "static"),
        help="moving joints, or one seeded random pose held still (default: moving for --path rig, "
        "static for --path handheld: one camera sweeping round a moving object breaks registration)",
    )
    p.add_argument("--static", dest="motion", action="store_const", const="static", help="same as --motion static")
    p.add_argument(
        "--hide-poses",
        action="store_true",
        help="handheld: store the camera poses only as ground truth (poses 'unknown'), as a real "
        "sensor would; `capture register` must then find them",
    )
    p.add_argument(
        "--sweep-deg",
        type=float,
        default=360.0,
        metavar="D",
        help="handheld: azimuth the camera covers, 30..360 degrees (default: 360, one loop round the object; "
        "less: an arc from the first frame to the last)",
    )
    p.add_argument(
        "--distance",
        type=float,
        metavar="M",
        help="handheld: mean camera distance from the object's middle, 0.2..3 m (default: 0.45 m, arm's length, "
        "or 1.3 x the noise model's minimum range where that is farther, e.g. 1.29 m for kinect_v1)",
    )
    p.add_argument(
        "--clutter",
        type=int,
        default=0,
        metavar="N",
        help="N seeded boxes and cylinders (2-12 cm, random colours) standing on the table 12..35 cm from the "
        "base axis, clear of the object (0..8; default: 0)",
    )
    p.add_argument(
        "--empty",
        action="store_true",
        help="render the same scene (table, clutter, cameras, path, noise) with NO object on the table; "
        "ground truth then has no n_links, segmentation is all background",
    )
    p.add_argument(
        "--effects",
        default="none",
        metavar="all|none|NAME,...|FILE.json",
        help="what a real print and a real active sensor add, each seeded by --seed: joint_play, print_error, "
        "shadows, flying_pixels, dark_plastic, principal_point, hand, pose_error, clutter; all; or a JSON file of "
        "switches and ranges (a recording's source.effects replays its effects) (default: none; "
        "ranges and sources: docs/sensor_effects.md)",
    )
    p.add_argument(
        "--renderer",
        choices=("pybullet", "raycast"),
        default="pybullet",
        help="pybullet (TinyRenderer, default) or raycast (open3d's ray caster on the object's meshes: an "
        "independent renderer of the same scene, same recording format)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from spare_twin.sim.effects import parse_effects
    from spare_twin.sim.render import RenderConfig, render_recording

    cfg = RenderConfig(
        rig=args.rig,
        frames=args.frames,
        fps=args.fps,
        seed=args.seed,
        resolution=args.resolution,
        segmentation=not args.no_segmentation,
        path=args.path,
        noise=args.noise,
        motion=args.motion,
        hide_poses=args.hide_poses,
        sweep_deg=args.sweep_deg,
        distance_m=args.distance,
        clutter=args.clutter,
        empty=args.empty,
        effects=parse_effects(args.effects, param="--effects"),
        renderer=args.renderer,
    )
    with flags(
        frames="--frames",
        fps="--fps",
        seed="--seed",
        resolution="--resolution",
        noise="--noise",
        hide_poses="--hide-poses",
        sweep_deg="--sweep-deg",
        distance_m="--distance",
        clutter="--clutter",
        empty="--empty",
        effects="--effects",
        renderer="--renderer",
        rig="--rig",
        force="--force",
    ):
        r = render_recording(args.object_dir, args.out, cfg, force=args.force)
    what = f"{r.cameras} cameras" if cfg.path == "rig" else f"1 hand-held camera ({cfg.sweep_deg:g} deg)"
    clutter = f", {r.clutter} clutter items" if r.clutter else ""
    truth = "no object on the table" if r.n_links is None else f"ground truth for {r.n_links} moving links"
    print(
        f"wrote {r.recording}: {what} x {r.frames} frames at {r.width}x{r.height} "
        f"(colour, depth{', segmentation' if cfg.segmentation else ''}; noise {cfg.noise}; {r.motion} joints"
        f"{clutter}), {truth}"
    )
    return 0
