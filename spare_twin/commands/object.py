"""`spare-twin object`: a printable object and its URDF twin."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys


def register(sub) -> None:
    p = sub.add_parser(
        "object",
        help="build a printable object (STL parts, pin joints) and its URDF twin",
        description="Build a printable SPARE object and its URDF twin from a sampled chain (--links/--seed) "
        "or a configuration file (--config). Writes object.json, one STL per part, the URDF, "
        "print_report.json, ASSEMBLY.md, clearance_coupon.stl and preview.png into --out.",
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument(
        "--links",
        type=int,
        metavar="N",
        help="moving links (1..6), lengths and colours sampled from the paper's distribution",
    )
    src.add_argument(
        "--config", metavar="SPEC_JSON", help="a chain configuration (an object.json, or a subset of its keys)"
    )
    p.add_argument("--seed", type=int, default=0, help="sampling seed with --links (default 0)")
    p.add_argument("--out", required=True, metavar="DIR", help="object folder to write (replaced atomically)")
    p.add_argument(
        "--print-scale", type=float, metavar="M_PER_PAPER_M", help="physical metres per paper metre (default 0.08)"
    )
    p.add_argument(
        "--clearance",
        type=float,
        metavar="MM",
        help="radial pin clearance in mm (default 0.3; see the clearance coupon)",
    )
    p.add_argument("--bed", metavar="XxY", help="printer bed in mm, e.g. 220x220 (default 200x200)")
    p.add_argument("--name", help="object name (URDF robot name and file stem)")
    p.add_argument("--no-preview", action="store_true", help="skip rendering preview.png")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    p.set_defaults(func=run)


def _spec_from_args(args):
    from spare_twin.config import ChainSpec, sample_chain
    from spare_twin.errors import SpareTwinError

    if args.config:
        spec = ChainSpec.from_json_file(args.config)
    else:
        spec = sample_chain(args.links, seed=args.seed)
    changes: dict = {}
    if args.print_scale is not None:
        changes["print_scale"] = args.print_scale
    if args.name is not None:
        changes["name"] = args.name
    if args.clearance is not None:
        changes["parts"] = dataclasses.replace(spec.parts, pin_clearance_mm=args.clearance)
    if args.bed is not None:
        try:
            bx, by = (float(v) for v in args.bed.lower().split("x"))
        except ValueError:
            raise SpareTwinError(f"--bed: expected XxY in mm, e.g. 220x220, got {args.bed!r}") from None
        changes["printer"] = dataclasses.replace(spec.printer, bed_x_mm=bx, bed_y_mm=by)
    return dataclasses.replace(spec, **changes) if changes else spec


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from spare_twin.object.folder import build_object

    spec = _spec_from_args(args)
    steps = ["modelling parts", "writing STL files", "checking printability", "writing assembly notes"] + (
        [] if args.no_preview else ["rendering preview"]
    )
    with tqdm(total=len(steps), desc="object", unit="step", file=sys.stderr, leave=False, disable=None) as bar:

        def progress(what):
            bar.set_postfix_str(what)
            bar.update(1)

        obj = build_object(spec, args.out, preview=not args.no_preview, progress=progress)
    report = json.loads((obj.root / "print_report.json").read_text())
    files = sorted(p.name for p in obj.root.iterdir() if p.is_file())
    summary = {
        "out": str(obj.root),
        "n_links": spec.n_links,
        "link_lengths_m": list(spec.link_lengths_pu),
        "link_lengths_mm": [round(x, 3) for x in spec.link_lengths_mm],
        "print_scale": spec.print_scale,
        "urdf": obj.urdf_path.name,
        "print_checks_passed": report["passed"],
        "files": files,
    }
    if args.json:
        print(json.dumps(summary))
    else:
        print(
            f"wrote {obj.root}/ ({len(files)} files): {spec.n_links} moving links, lengths "
            + ", ".join(f"{x:.1f}" for x in spec.link_lengths_mm)
            + " mm"
        )
        print(
            f"  URDF {obj.urdf_path.name}; print checks {'passed' if report['passed'] else 'FAILED'}; "
            "see ASSEMBLY.md" + ("" if args.no_preview else " and preview.png")
        )
    return 0
