"""`spare-twin noise fit [SRC ...] --out DIR`: fit the depth-sensor noise model to real frames."""

from __future__ import annotations

import argparse
import json

from spare_twin.commands.common import flags


def register(sub) -> None:
    p = sub.add_parser(
        "noise",
        help="depth-sensor noise models (noise fit: fit one to real depth frames)",
        description="Depth-sensor noise models, as `render --noise` and training's depth_noise use them.",
    )
    nsub = p.add_subparsers(dest="noise_command", metavar="SUBCOMMAND")
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])
    f = nsub.add_parser(
        "fit",
        help="fit the noise model to folders of real depth frames, one noise_<sensor>.json each",
        description="Fit the depth-sensor noise model (depth-dependent noise, quantisation, holes at depth "
        "edges, dropouts) to each SRC folder of real depth frames (7-Scenes frame-*.depth.png: a RealSense "
        "SR300; TUM *_depth.png: a Kinect v1) and write noise_<sensor>.json into --out, the files that "
        "capture/rigs/ ships. Default SRC: the real samples in tests/data.",
    )
    f.add_argument("sources", nargs="*", metavar="SRC", help="folders of real depth frames (default: tests/data's)")
    f.add_argument(
        "--out", required=True, metavar="DIR", help="folder to write (absent, empty or an earlier noise fit)"
    )
    f.add_argument("--force", action="store_true", help="replace --out even if it is not an earlier noise fit")
    f.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    f.set_defaults(func=run_fit)


def run_fit(args: argparse.Namespace) -> int:
    from spare_twin.sim.noise import SAMPLE_SOURCES, fit_noise_models

    with flags(out_dir="--out", sources="SRC", force="--force"):
        fits = fit_noise_models(args.out, args.sources or SAMPLE_SOURCES, force=args.force)
    if args.json:
        print(json.dumps({"models": [f.to_json() for f in fits]}))
    else:
        for f in fits:
            m = f.model
            print(
                f"wrote {f.path}: {m.sensor}, sigma {m.sigma0_m * 1000:.2f} mm + {m.sigma2_per_m * 1000:.2f} mm/m^2 "
                f"d^2, edge holes {m.edge_hole_prob:.2f} x {m.edge_band_px:.1f} px, range "
                f"{m.min_range_m}..{m.max_range_m} m ({f.report['frames']} frames of {f.source})"
            )
    return 0
