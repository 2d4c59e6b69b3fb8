"""`spare-twin bench object`: seconds to build a 6-link object, geometry only and the whole CLI."""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def add_bench(sub) -> None:
    p = sub.add_parser("object", help="time building 6-link objects (geometry only, and the whole CLI)")
    p.add_argument("--repeats", type=int, default=5, help="objects per measurement (different seeds)")
    p.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    p.set_defaults(func=run)


def bench_object(repeats: int = 5) -> dict:
    from spare_twin.config import sample_chain
    from spare_twin.object.folder import build_object
    from spare_twin.object.parts import build_parts
    from spare_twin.object.stl import to_trimesh

    geometry, folder, cli = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(repeats):
            spec = sample_chain(6, seed=seed)
            t0 = time.perf_counter()
            meshes = [to_trimesh(p.solid) for p in build_parts(spec)]
            geometry.append(time.perf_counter() - t0)
            assert all(m.is_watertight for m in meshes)
            t0 = time.perf_counter()
            build_object(spec, Path(tmp) / f"lib{seed}")
            folder.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "spare_twin.cli",
                    "object",
                    "--links",
                    "6",
                    "--seed",
                    str(seed),
                    "--out",
                    str(Path(tmp) / f"cli{seed}"),
                ],
                check=True,
                capture_output=True,
            )
            cli.append(time.perf_counter() - t0)
        # Baseline in the same run: a bare interpreter that only imports the package's CLI.
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import spare_twin.cli"], check=True)
        startup = time.perf_counter() - t0
    med = statistics.median
    return {
        "objects": repeats,
        "geometry_s": round(med(geometry), 4),
        "object_folder_s": round(med(folder), 4),
        "whole_cli_s": round(med(cli), 4),
        "python_startup_s": round(startup, 4),
        "cli_over_geometry": round(med(cli) / med(geometry), 2),
    }


def run(args) -> int:
    res = bench_object(args.repeats)
    if args.json:
        print(json.dumps(res))
    else:
        print(f"6-link object, median of {res['objects']}:")
        print(f"  geometry only (manifold3d parts -> meshes): {res['geometry_s']:.3f} s")
        print(f"  object folder (STLs, checks, URDF, preview): {res['object_folder_s']:.3f} s")
        print(
            f"  whole CLI (new process):                     {res['whole_cli_s']:.3f} s "
            f"= {res['cli_over_geometry']:.1f} x geometry (python start-up alone: {res['python_startup_s']:.3f} s)"
        )
    return 0
