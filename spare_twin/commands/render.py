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
    p.add_argument("--resolution", choices=("record", "network"), default="record",
                   help="record: the rig's high resolution (default); network: 96x128")
    p.add_argument("--no-segmentation", action="store_true", help="skip the link segmentation images")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import sys

    import numpy as np
    from tqdm import tqdm

    from spare_twin import SpareTwinError
    from spare_twin.objects import load_object
    from spare_twin.recording import Camera, RecordingWriter
    from spare_twin.sim.motion import MotionConfig, random_motion
    from spare_twin.sim.rig import load_rig
    from spare_twin.sim.twin import Twin

    if args.frames < 1:
        raise SpareTwinError("--frames must be at least 1")
    if args.fps <= 0:
        raise SpareTwinError("--fps must be positive")
    obj = load_object(args.object_dir)
    rig = load_rig(args.rig)
    W, H = (rig.record_width, rig.record_height) if args.resolution == "record" else (rig.width, rig.height)
    K, poses = rig.K(W, H), rig.poses()
    angles = random_motion(obj.joint_limits_rad, obj.link_lengths_phys_m, obj.keepout_height_m, obj.link_half_width_m,
                           np.random.default_rng(args.seed), MotionConfig(n_frames=args.frames, fps=args.fps))
    cameras = [Camera(name, W, H, K, poses[i]) for i, name in enumerate(rig.camera_names())]
    source = {"kind": "sim", "sensor_model": "pybullet-tinyrenderer", "seed": args.seed, "geometry": "print",
              "near_m": rig.near_m, "far_m": rig.far_m}
    link_poses = np.zeros((args.frames, obj.spec.n_links + 1, 4, 4))
    with Twin() as twin, RecordingWriter(args.out, cameras, args.frames, args.fps, source,
                                         object_config=obj.spec.to_dict(), rig=rig.name) as rec:
        twin.load(obj)
        for t in tqdm(range(args.frames), unit="frame", file=sys.stderr, desc="render", dynamic_ncols=True):
            twin.set_joints(angles[t])
            link_poses[t] = twin.link_poses()
            for cam in cameras:
                f = twin.render(cam.T_world_camera, K, W, H, rig.near_m, rig.far_m, segmentation=not args.no_segmentation)
                rec.add_frame(cam.name, t, f.rgb, f.depth_m, f.segmentation)
        rec.set_ground_truth(
            joint_angles_rad=angles,
            T_world_link=link_poses,
            link_lengths_m=np.asarray(obj.spec.link_lengths_m),
            n_links=np.asarray(obj.spec.n_links),
            print_scale=np.asarray(obj.spec.print_scale),
        )
    print(f"wrote {args.out}: {len(cameras)} cameras x {args.frames} frames at {W}x{H} "
          f"(colour, depth{'' if args.no_segmentation else ', segmentation'}), ground truth for {obj.spec.n_links} moving links")
    return 0
