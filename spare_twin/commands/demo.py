"""`spare-twin demo`: the main job end to end on embedded defaults (`spare_twin.compare.demo`)."""

from __future__ import annotations

import sys


def register(sub) -> None:
    p = sub.add_parser(
        "demo",
        help="run the whole pipeline on embedded defaults (no arguments needed)",
        description=__doc__.split("\n\n")[0] + " Builds a printable object, renders its twin, records it "
        "with a simulated hand-held RGB-D sensor, imports and registers that recording, predicts with "
        "the shipped model and compares sim with real in a Rerun recording.",
    )
    p.add_argument("--out", default="spare-twin-demo", metavar="DIR", help="output folder (default ./spare-twin-demo)")
    p.add_argument("--model", metavar="CKPT", help="network checkpoint (default: the shipped model in models/)")
    p.add_argument(
        "--force",
        action="store_true",
        help="replace --out even if it is not an earlier demo (once the new one is done)",
    )
    p.set_defaults(func=run)


def _step(i: int, what: str) -> None:
    from spare_twin.compare.demo import STEPS

    print(f"[{i}/{STEPS}] {what}", file=sys.stderr, flush=True)


def run(args) -> int:
    from spare_twin.commands.common import flags
    from spare_twin.compare.inputs import check_demo

    with flags(out="--out", model="--model", force="--force"):
        # checked before the demo's modules are imported: torch and every stage take 5 s to load
        check_demo(args.out, args.model, args.force)
        from spare_twin.compare.demo import run_demo

        result = run_demo(args.out, args.model, step=_step, force=args.force)
    print(result.summary())
    return 0
