"""`spare-twin bench`: performance benchmarks, one subcommand (and one function) each.

Stages add their own benchmark as `spare_twin/commands/bench_<name>.py` defining
`add_bench(subparsers)`; this command discovers and registers them.

`bench dataset`: dataset images/s end to end (sample, render, encode, write HDF5) against pybullet's
raw render loop for the same rig and objects, measured in the same run, for 1 and 2 workers; and the
wall time of the `paper` preset (measured with --paper full, else extrapolated from the measured rate).
"""

from __future__ import annotations

import argparse
import json


def register(sub) -> None:
    p = sub.add_parser(
        "bench",
        help="performance benchmarks (bench dataset, ...)",
        description="Performance benchmarks; each subcommand measures one stage.",
    )
    bsub = p.add_subparsers(dest="benchmark", metavar="BENCHMARK")
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])
    d = bsub.add_parser(
        "dataset",
        help="dataset generation: end-to-end images/s vs the raw pybullet render loop",
        description=__doc__.split("\n\n", 1)[1],
    )
    d.add_argument(
        "--instances", type=int, default=4, help="sequences per worker, each timed raw then end to end (default: 4)"
    )
    d.add_argument("--workers", default="1,2", help="worker counts to measure, comma-separated (default: 1,2)")
    d.add_argument("--frames", type=int, default=100, help="frames per sequence (default: 100)")
    d.add_argument(
        "--geometry", choices=("sim", "print"), default="sim", help="tessellation of the parts (default: sim)"
    )
    d.add_argument(
        "--paper",
        choices=("extrapolate", "full"),
        default="extrapolate",
        help="full: generate the whole paper preset (324 sequences) with the largest worker count and "
        "time it; extrapolate (default): predict its wall time from the measured rate",
    )
    d.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    d.set_defaults(func=bench_dataset)
    _add_stage_benchmarks(bsub)


def _add_stage_benchmarks(bsub) -> None:
    """Other stages add theirs as `spare_twin/commands/bench_<name>.py` with `add_bench(subparsers)`."""
    import importlib
    import pkgutil

    import spare_twin.commands as commands

    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("bench_"):
            module = importlib.import_module(f"spare_twin.commands.{info.name}")
            if hasattr(module, "add_bench"):
                module.add_bench(bsub)


def _paired_worker(job: tuple) -> dict:
    """For each sequence, time pybullet's raw render loop (the same object, motion and cameras;
    nothing converted or stored) and then the dataset's full path for it (sample, build the object,
    render, convert, compress, write the HDF5 file). Pairing the two per sequence in one process
    keeps the ratio honest on a machine whose load changes while the benchmark runs."""
    import tempfile
    import time
    from pathlib import Path

    import numpy as np

    from spare_twin.dataset import build
    from spare_twin.dataset.generate import _seeds, load_twin_object, sequence_spec
    from spare_twin.sim.motion import random_motion
    from spare_twin.sim.scene import sample_scene
    from spare_twin.sim.twin import Lighting, projection_matrix, view_matrix

    cfg_dict, seed, indices, out_dir = job
    build._init_worker(cfg_dict, seed, out_dir)
    cfg, twin = build._W["cfg"], build._W["twin"]
    rig, light = cfg.rig, Lighting()
    work = Path(tempfile.mkdtemp(prefix="spare-twin-bench-"))
    raw_s = e2e_s = 0.0
    images = 0
    for index in indices:
        spec = sequence_spec(seed, index)
        scene = sample_scene(rig, spec, cfg.randomization, np.random.default_rng(_seeds(seed, index)["scene"]))
        obj = load_twin_object(cfg, spec, work)
        twin.load(obj)
        angles = random_motion(
            obj.joint_limits_rad,
            obj.link_lengths_m,
            obj.keepout_height_m,
            obj.link_half_width_m,
            np.random.default_rng(_seeds(seed, index)["motion"]),
            cfg.motion(),
        )
        views = [view_matrix(T) for T in scene.T_world_camera]
        projs = [projection_matrix(k, rig.width, rig.height, rig.near_m, rig.far_m) for k in scene.K]
        t0 = time.perf_counter()
        for t in range(cfg.frames):
            twin.set_joints(angles[t])
            for v in range(rig.n_cameras):
                twin.render_raw(views[v], projs[v], rig.width, rig.height, light, cfg.segmentation)
        t1 = time.perf_counter()
        build._work(index)
        t2 = time.perf_counter()
        raw_s += t1 - t0
        e2e_s += t2 - t1
        images += cfg.frames * rig.n_cameras
    build._close_worker()
    return {"images": images, "raw_s": raw_s, "e2e_s": e2e_s}


def _paired_rates(cfg, seed: int, workers: int, per_worker: int, out_dir: str) -> tuple[float, float]:
    """Summed raw and end-to-end images/s of `workers` processes working at the same time."""
    import multiprocessing as mp

    jobs = [(cfg.to_dict(), seed, [w * per_worker + k for k in range(per_worker)], out_dir) for w in range(workers)]
    if workers == 1:
        results = [_paired_worker(jobs[0])]
    else:
        with mp.get_context("spawn").Pool(workers) as pool:
            results = pool.map(_paired_worker, jobs)
    return sum(r["images"] / r["raw_s"] for r in results), sum(r["images"] / r["e2e_s"] for r in results)


def bench_dataset(args: argparse.Namespace) -> int:
    import os
    import shutil
    import sys
    import tempfile

    from spare_twin.dataset.build import PRESETS, generate_dataset
    from spare_twin.dataset.generate import GenConfig
    from spare_twin.errors import SpareTwinError

    try:
        worker_counts = [int(w) for w in args.workers.split(",")]
    except ValueError:
        raise SpareTwinError(f"--workers {args.workers!r}: expected comma-separated integers") from None
    if not worker_counts or min(worker_counts) < 1 or args.instances < 1 or args.frames < 1:
        raise SpareTwinError("--workers, --instances and --frames must be positive")
    cfg = GenConfig(frames=args.frames, geometry=args.geometry)
    seed = 12345  # benchmark sequences: the same objects in the raw and end-to-end runs
    out = {
        "cpu_cores": os.cpu_count(),
        "geometry": args.geometry,
        "frames": args.frames,
        "image_size_hw": [cfg.rig.height, cfg.rig.width],
        "cameras": cfg.rig.n_cameras,
        "runs": [],
    }
    log = (lambda *a: print(*a, file=sys.stderr)) if args.json else print
    tmp = tempfile.mkdtemp(prefix="spare-twin-bench-")
    try:
        for w in worker_counts:
            seq_dir = os.path.join(tmp, f"w{w}")
            os.makedirs(seq_dir)
            raw, e2e = _paired_rates(cfg, seed, w, args.instances, seq_dir)
            run = {
                "workers": w,
                "raw_images_per_s": round(raw, 1),
                "end_to_end_images_per_s": round(e2e, 1),
                "ratio": round(e2e / raw, 3),
                "raw_per_worker": round(raw / w, 1),
                "end_to_end_per_worker": round(e2e / w, 1),
                "sequences_per_worker": args.instances,
            }
            out["runs"].append(run)
            log(
                f"workers {w}: raw render {raw:7.1f} img/s, end to end {e2e:7.1f} img/s, "
                f"ratio {e2e / raw:.2f} (per worker {e2e / w:.1f} vs {raw / w:.1f} img/s)"
            )
            shutil.rmtree(seq_dir, ignore_errors=True)
        paper = PRESETS["paper"]
        paper_images = paper.instances * cfg.rig.n_cameras * paper.frames
        wmax = max(worker_counts)
        best = next(r for r in out["runs"] if r["workers"] == wmax)
        if args.paper == "full":
            r = generate_dataset(
                os.path.join(tmp, "paper"),
                paper.instances,
                paper.seed,
                wmax,
                GenConfig(geometry=args.geometry),
                progress=not args.json,
            )
            out["paper"] = {
                "workers": wmax,
                "images": r["images"],
                "wall_s": round(r["wall_s"], 1),
                "measured": True,
                "images_per_s": round(r["images"] / r["wall_s"], 1),
            }
        else:
            est = paper_images / best["end_to_end_images_per_s"]
            out["paper"] = {"workers": wmax, "images": paper_images, "wall_s": round(est, 1), "measured": False}
        p = out["paper"]
        log(
            f"paper preset ({p['images']} images, {wmax} workers): "
            f"{p['wall_s'] / 60:.1f} min {'measured' if p['measured'] else 'extrapolated from the end-to-end rate'}"
        )
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if args.json:
        print(json.dumps(out))
    return 0
