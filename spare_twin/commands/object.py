"""`spare-twin object`: a printable object and its URDF twin."""

from __future__ import annotations

import argparse
import json
import sys

from spare_twin.commands.common import flags
from spare_twin.errors import SpareTwinError


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
    p.add_argument(
        "--out",
        required=True,
        metavar="DIR",
        help="object folder to write: absent, empty or an earlier object folder (replaced once the new one is whole)",
    )
    p.add_argument("--force", action="store_true", help="replace --out even if it holds something else")
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


def _bed_mm(text: str | None) -> tuple[float, float] | None:
    if text is None:
        return None
    try:
        bx, by = (float(v) for v in text.lower().split("x"))
    except ValueError:
        raise SpareTwinError(f"--bed: expected XxY in mm, e.g. 220x220, got {text!r}") from None
    return bx, by


#: Library parameters (and configuration fields) as `object` spells them on its command line.
FLAGS = {
    "n_links": "--links",
    "seed": "--seed",
    "config": "--config",
    "out_dir": "--out",
    "print_scale": "--print-scale",
    "parts.pin_clearance_mm": "--clearance",
    "name": "--name",
    "force": "--force",
}


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from spare_twin.object.folder import BUILD_STEPS, make_object

    steps = len(BUILD_STEPS) + (0 if args.no_preview else 1)
    with (
        tqdm(total=steps, desc="object", unit="step", file=sys.stderr, leave=False, disable=None) as bar,
        flags(**FLAGS),
    ):

        def progress(what):
            bar.set_postfix_str(what)
            bar.update(1)

        made = make_object(
            args.out,
            n_links=args.links,
            seed=args.seed,
            config=args.config,
            print_scale=args.print_scale,
            clearance_mm=args.clearance,
            bed_mm=_bed_mm(args.bed),
            name=args.name,
            preview=not args.no_preview,
            progress=progress,
            force=args.force,
        )
    spec, obj = made.folder.spec, made.folder
    if args.json:
        print(json.dumps(made.to_json()))
    else:
        print(
            f"wrote {obj.root}/ ({len(made.files)} files): {spec.n_links} moving links, lengths "
            + ", ".join(f"{x:.1f}" for x in spec.link_lengths_mm)
            + " mm"
        )
        print(
            f"  URDF {obj.urdf_path.name}; print checks {'passed' if made.print_checks_passed else 'FAILED'}; "
            "see ASSEMBLY.md" + ("" if args.no_preview else " and preview.png")
        )
    return 0
