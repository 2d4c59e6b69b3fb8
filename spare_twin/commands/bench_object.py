"""`spare-twin bench object`: seconds to build a 6-link object, geometry only and the whole CLI."""

from __future__ import annotations

import json

from spare_twin.commands.common import flags


def add_bench(sub) -> None:
    p = sub.add_parser("object", help="time building 6-link objects (geometry only, and the whole CLI)")
    p.add_argument("--repeats", type=int, default=5, help="objects per measurement (different seeds)")
    p.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    p.set_defaults(func=run)


def run(args) -> int:
    from spare_twin.bench.object import bench_object

    with flags(repeats="--repeats"):
        res = bench_object(args.repeats).to_json()
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
