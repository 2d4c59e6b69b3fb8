"""`spare-twin dataset --out DATA_DIR --instances K --seed S --workers W [--backend local|ray]
[--ray-address ADDR]`: generate, resume or extend; with `--handheld`, the profile network's samples
from hand-held captures drawn the bench's way (`bench.handheld_samples`); with `--analytic-profiles`, profile
samples drawn straight from the printed chain's geometry (`nets.profile_analytic`)."""

from __future__ import annotations

import argparse

from spare_twin.commands.common import flags


def register(sub) -> None:
    p = sub.add_parser(
        "dataset",
        help="generate, resume or extend a SPARE dataset (sharded HDF5, manifest, train/val/test splits)",
        description="Render K sampled chains (balanced over n = 1..6) with the camera rig into DATA_DIR. Every "
        "sequence is a pure function of (seed, index): rerunning the same command after an interruption finishes "
        "the dataset, and a larger --instances adds sequences without touching existing ones. The files are the same "
        "bytes whatever --backend and --workers.",
    )
    p.add_argument("--out", required=True, metavar="DATA_DIR", help="dataset folder (created, resumed or extended)")
    p.add_argument(
        "--force",
        action="store_true",
        help="replace a --out that is not this dataset (another folder, other seed or settings), once the new one "
        "is complete",
    )
    p.add_argument(
        "--preset",
        choices=("paper", "small", "tiny"),
        help="paper: 324 sequences x 8 cameras x 100 frames = 259,200 images (the paper's scale); "
        "small: 36; tiny: 6 x 20 frames. Explicit options override the preset.",
    )
    p.add_argument("--instances", type=int, help="number of sequences K")
    p.add_argument("--seed", type=int, help="dataset seed (default: 0)")
    p.add_argument(
        "--workers",
        type=int,
        help="sequences rendered at once: local processes (default: 1), or Ray tasks (default: every CPU of the "
        "Ray cluster)",
    )
    p.add_argument(
        "--backend",
        choices=("local", "ray"),
        default="local",
        help="local: processes on this machine (default); ray: one Ray task per sequence, on the cluster at "
        "--ray-address or on a Ray instance started here",
    )
    p.add_argument(
        "--ray-address",
        metavar="ADDR",
        help="with --backend ray: the cluster's address (HOST:PORT of its head, or auto); default: start Ray here",
    )
    p.add_argument(
        "--ray-shards",
        choices=("driver", "workers"),
        default="driver",
        help="with --backend ray: who writes the sequence files: this process, from the bytes the tasks return "
        "(default; --out need not be visible to the cluster), or the tasks themselves (--out must be on a file "
        "system every node mounts at the same path)",
    )
    p.add_argument("--frames", type=int, help="frames per sequence (default: 100)")
    p.add_argument("--rig", default="spare8", help="rig name in capture/rigs/ or a rig JSON file (default: spare8)")
    p.add_argument(
        "--geometry",
        choices=("sim", "print"),
        default="sim",
        help="the printed parts with circles of 16 segments (sim, default: twice as fast to render) "
        "or of 64 as in the printed STL files (print)",
    )
    p.add_argument(
        "--sim2real",
        action="store_true",
        help="randomise rig pose / intrinsics, lighting, link and table colours, clutter per sequence",
    )
    p.add_argument(
        "--print-physics",
        action="store_true",
        help="render each sequence's object as a print is: joint play (links tilted 1-4 degrees out of the "
        "chain's plane, joint centres shifted by the pins' 0.3 mm clearance) and print error (0.2-0.5 %% shrink, "
        "up to 0.5 degrees off level), drawn from the sequence's seed (docs/sensor_effects.md); labels stay nominal",
    )
    p.add_argument("--no-segmentation", action="store_true", help="do not store link segmentation images")
    p.add_argument(
        "--handheld",
        action="store_true",
        help="instead of rig sequences: K hand-held captures drawn as `bench sim2real` draws its real side (every "
        "effect, 15-60 frames, three sensors, two renderers), each observed as predict observes it and kept as a "
        "profile sample for the profile network (the capture is deleted); chain seeds 1e9 + S * 1e6 + i, never a "
        "bench seed. Takes --out, --instances, --seed, --workers, --force only",
    )
    p.add_argument(
        "--analytic-profiles",
        action="store_true",
        help="instead of rig sequences: K profile samples drawn straight from the printed chain's geometry (joint "
        "play, print error, one or both faces seen, noise, blur, holes, stray points; about 90 ms each) in the format "
        "of --handheld's folders, for the profile network's training; chain seeds 3e9 + S * 1e6 + i. Takes --out, "
        "--instances, --seed, --workers, --force only",
    )
    p.set_defaults(func=run, rig_only_defaults={k: p.get_default(k) for k in _RIG_ONLY})


#: The options `--handheld` does not take (their defaults are the parser's: `register`).
_RIG_ONLY = (
    "preset", "backend", "ray_address", "ray_shards", "frames", "rig", "geometry", "sim2real", "print_physics",
    "no_segmentation",
)  # fmt: skip


def _only_sample_options(args: argparse.Namespace, mode: str) -> None:
    """Refuse the rig's options and a missing --instances with `mode` (--handheld, --analytic-profiles)."""
    from spare_twin.errors import SpareTwinError

    given = [k for k, default in args.rig_only_defaults.items() if getattr(args, k) != default]
    if given:
        flag = "--" + given[0].replace("_", "-")
        raise SpareTwinError(f"{flag}: not an option of {mode} (it draws profile samples, not rig sequences)")
    if args.instances is None:
        raise SpareTwinError(f"{mode}: give --instances K")


def run_analytic(args: argparse.Namespace) -> int:
    from spare_twin.errors import SpareTwinError

    _only_sample_options(args, "--analytic-profiles")
    if args.handheld:
        raise SpareTwinError("--handheld, --analytic-profiles: give one kind of samples, not both")
    workers = args.workers if args.workers is not None else 1
    with flags(instances="--instances", seed="--seed", workers="--workers", out="--out"):
        from spare_twin.nets.profile_analytic_config import AnalyticProfileConfig, check_analytic

        c = AnalyticProfileConfig(samples=args.instances, seed=args.seed if args.seed is not None else 0)
        check_analytic(args.out, c, workers, args.force)  # before the drawing's modules (trimesh: 1-2 s)
        from spare_twin.nets.profile_analytic import analytic_profiles

        m = analytic_profiles(args.out, c, workers, force=args.force)
    s = m["samples"]
    print(f"{args.out}/samples.npz: {s['train']} training and {s['val']} validation analytic profile samples")
    return 0


def run_handheld(args: argparse.Namespace) -> int:
    from spare_twin.bench.handheld_config import HandheldConfig, check_handheld

    _only_sample_options(args, "--handheld")
    workers = args.workers if args.workers is not None else 1
    with flags(instances="--instances", seed="--seed", workers="--workers", out="--out"):
        # checked before the drawing's modules are imported: the measurement and torch take 5 s to load
        hc = HandheldConfig(objects=args.instances, seed=args.seed if args.seed is not None else 0)
        check_handheld(args.out, hc, workers, args.force)
        from spare_twin.bench.handheld_samples import handheld_dataset

        m = handheld_dataset(args.out, hc, workers, force=args.force)
    s, r = m["samples"], m["rejected"]
    print(
        f"{args.out}/samples.npz: {s['train']} training and {s['val']} validation samples from {m['objects']} "
        f"hand-held captures ({r['train'] + r['val']} gave no chain)"
    )
    return 0


def run(args: argparse.Namespace) -> int:
    if args.analytic_profiles:
        return run_analytic(args)
    if args.handheld:
        return run_handheld(args)
    from spare_twin.dataset.build import PRESETS, generate_dataset
    from spare_twin.dataset.generate import GenConfig
    from spare_twin.errors import SpareTwinError
    from spare_twin.sim.rig import load_rig
    from spare_twin.sim.scene import SIM2REAL, DomainRandomization

    preset = PRESETS[args.preset] if args.preset else None
    instances = args.instances if args.instances is not None else (preset.instances if preset else None)
    if instances is None:
        raise SpareTwinError("give --instances K or a --preset")
    seed = args.seed if args.seed is not None else (preset.seed if preset else 0)
    frames = args.frames if args.frames is not None else (preset.frames if preset else 100)
    if args.backend != "ray" and (args.ray_address is not None or args.ray_shards != "driver"):
        raise SpareTwinError("--ray-address and --ray-shards need --backend ray")
    cfg = GenConfig(
        rig=load_rig(args.rig),
        frames=frames,
        geometry=args.geometry,
        segmentation=not args.no_segmentation,
        randomization=SIM2REAL if args.sim2real else DomainRandomization(),
        print_physics=args.print_physics,
    )
    with flags(
        instances="--instances",
        frames="--frames",
        seed="--seed",
        workers="--workers",
        backend="--backend",
        ray_address="--ray-address",
        shards="--ray-shards",
    ):
        r = generate_dataset(
            args.out,
            instances,
            seed,
            args.workers,
            cfg,
            backend=args.backend,
            ray_address=args.ray_address,
            shards=args.ray_shards,
            force=args.force,
        )
    rate = r["generated_images"] / r["generate_s"] if r["generated"] else 0.0
    splits = ", ".join(f"{k} {v['sequences']} seq / {v['images']} img" for k, v in r["splits"].items())
    print(
        f"wrote {r['generated']} new sequences ({r['generated_images']} images, {rate:.0f} images/s) to {args.out}; "
        f"{r['already_present']} were already there"
    )
    print(f"{args.out}/manifest.json: {r['instances']} sequences, {r['images']} images ({splits})")
    return 0
