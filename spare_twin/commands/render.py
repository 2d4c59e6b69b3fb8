"""`spare-twin render OBJECT_DIR --out REC_DIR`: a twin-simulation recording of one object."""

from __future__ import annotations

import argparse


def register(sub) -> None:
    p = sub.add_parser(
        "render",
        help="render a twin-simulation recording of an object folder (rig, random motion, RGB-D frames, ground truth)",
        description="Load OBJECT_DIR's URDF in pybullet, move its joints smoothly at random (within the limits, "
        "clear of the foot) and record every rig camera: colour, depth, link segmentation, intrinsics, poses "
        "and per-frame ground truth, as a spare-twin recording.",
    )
    p.add_argument("object_dir", metavar="OBJECT_DIR", help="object folder written by `spare-twin object`")
    p.add_argument("--out", required=True, metavar="REC_DIR", help="recording folder to write (replaced atomically)")
    p.add_argument("--rig", default="spare8", help="rig name in capture/rigs/ or a rig JSON file (default: spare8)")
    p.add_argument("--frames", type=int, default=100, help="frames to record (default: 100)")
    p.add_argument("--fps", type=float, default=10.0, help="frame rate (default: 10)")
    p.add_argument("--seed", type=int, default=0, help="seed of the motion (default: 0)")
    p.add_argument("--resolution", default="record", metavar="record|network|WxH",
                   help="record: the rig's high resolution (default); network: 96x128; or WxH, e.g. 640x480 "
                   "(the rig's field of view)")
    p.add_argument("--no-segmentation", action="store_true", help="skip the link segmentation images")
    p.add_argument("--path", choices=("rig", "handheld"), default="rig",
                   help="rig: the rig's fixed cameras (default); handheld: ONE camera carried around the object on "
                   "a smooth seeded path (a simulated real capture; recording rig = null, per-frame poses)")
    p.add_argument("--noise", default="none", metavar="NAME|none",
                   help="depth-sensor noise model capture/rigs/noise_NAME.json (e.g. realsense_sr300) or a JSON file; "
                   "depth is then stored in the sensor's unit (default: none, clean depth at 0.1 mm)")
    p.add_argument("--motion", choices=("moving", "static"),
                   help="moving joints, or one seeded random pose held still (default: moving for --path rig, "
                   "static for --path handheld: one camera sweeping round a moving object breaks registration)")
    p.add_argument("--static", dest="motion", action="store_const", const="static", help="same as --motion static")
    p.add_argument("--hide-poses", action="store_true",
                   help="handheld: store the camera poses only as ground truth (poses 'unknown'), as a real "
                   "sensor would; `capture register` must then find them")
    p.set_defaults(func=run)


def parse_resolution(text: str, rig) -> tuple[int, int]:
    """(width, height) from record | network | WxH."""
    from spare_twin import SpareTwinError

    if text == "record":
        return rig.record_width, rig.record_height
    if text == "network":
        return rig.width, rig.height
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise SpareTwinError(f"--resolution {text!r}: expected record, network or WxH (e.g. 640x480)") from None
    if not (16 <= w <= 4096 and 16 <= h <= 4096):
        raise SpareTwinError(f"--resolution {text!r}: width and height must be within 16..4096")
    return w, h


def run(args: argparse.Namespace) -> int:
    import sys

    import numpy as np
    from tqdm import tqdm

    from spare_twin import SpareTwinError
    from spare_twin.objects import load_object
    from spare_twin.recording import SIM_DEPTH_SCALE, Camera, RecordingWriter
    from spare_twin.sim.motion import MotionConfig, random_motion
    from spare_twin.sim.rig import load_rig
    from spare_twin.sim.twin import Twin

    if args.frames < 1:
        raise SpareTwinError("--frames must be at least 1")
    if args.fps <= 0:
        raise SpareTwinError("--fps must be positive")
    if args.hide_poses and args.path != "handheld":
        raise SpareTwinError("--hide-poses: only for --path handheld (a rig's cameras are calibrated)")
    obj = load_object(args.object_dir)
    rig = load_rig(args.rig)
    W, H = parse_resolution(args.resolution, rig)
    from spare_twin.sim.noise import load_noise

    noise = load_noise(args.noise, flag="--noise")
    K = rig.K(W, H)
    angles = random_motion(obj.joint_limits_rad, obj.link_lengths_phys_m, obj.keepout_height_m, obj.link_half_width_m,
                           np.random.default_rng(args.seed), MotionConfig(n_frames=args.frames, fps=args.fps))
    motion = args.motion or ("static" if args.path == "handheld" else "moving")
    if motion == "static":  # one pose of the seeded motion (so it respects limits and keep-out), held still
        angles = np.repeat(angles[len(angles) // 2][None], args.frames, axis=0)
    if args.path == "rig":
        poses = rig.poses()
        cameras = [Camera(name, W, H, K, poses[i]) for i, name in enumerate(rig.camera_names())]
        frame_poses = {c.name: np.repeat(c.T_world_camera[None], args.frames, axis=0) for c in cameras}
    else:
        from spare_twin.sim.handheld import HandheldPath, handheld_poses

        frame_poses = {"cam0": handheld_poses(HandheldPath(), args.frames, args.seed)}
        cameras = [Camera("cam0", W, H, K, None, "unknown" if args.hide_poses else "per_frame")]
    source = {"kind": "sim", "sensor_model": noise.sensor if noise else "pybullet-tinyrenderer", "seed": args.seed,
              "geometry": "print", "near_m": rig.near_m, "far_m": rig.far_m, "path": args.path, "motion": motion,
              "noise": None if noise is None else noise.to_dict()}
    link_poses = np.zeros((args.frames, obj.spec.n_links + 1, 4, 4))
    depth_scale = noise.unit_m if noise else SIM_DEPTH_SCALE  # the sensor's own unit, as a real capture stores it
    with Twin() as twin, RecordingWriter(args.out, cameras, args.frames, args.fps, source, depth_scale=depth_scale,
                                         object_config=obj.spec.to_dict(),
                                         rig=rig.name if args.path == "rig" else None) as rec:
        twin.load(obj)
        for t in tqdm(range(args.frames), unit="frame", file=sys.stderr, desc="render", dynamic_ncols=True):
            twin.set_joints(angles[t])
            link_poses[t] = twin.link_poses()
            for v, cam in enumerate(cameras):
                T = frame_poses[cam.name][t]
                f = twin.render(T, K, W, H, rig.near_m, rig.far_m, segmentation=not args.no_segmentation)
                depth = f.depth_m
                if noise is not None:  # one stream per (seed, camera, frame): any subset re-renders identically
                    depth = noise.apply(depth, np.random.default_rng([args.seed, 0x5E, v, t]))
                rec.add_frame(cam.name, t, f.rgb, depth, f.segmentation,
                              T_world_camera=T if cam.poses == "per_frame" else None)
        gt = dict(joint_angles_rad=angles, T_world_link=link_poses, link_lengths_m=np.asarray(obj.spec.link_lengths_m),
                  n_links=np.asarray(obj.spec.n_links), print_scale=np.asarray(obj.spec.print_scale))
        if args.path == "handheld":
            gt["T_world_camera"] = frame_poses["cam0"]  # true poses, also when the recording hides them
        rec.set_ground_truth(**gt)
    what = f"{len(cameras)} cameras" if args.path == "rig" else "1 hand-held camera"
    print(f"wrote {args.out}: {what} x {args.frames} frames at {W}x{H} "
          f"(colour, depth{'' if args.no_segmentation else ', segmentation'}; noise {args.noise}; {motion} joints), "
          f"ground truth for {obj.spec.n_links} moving links")
    return 0
