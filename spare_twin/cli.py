"""The `spare-twin` command line: one console script with a subcommand per stage.

Each subcommand lives in `spare_twin/commands/<name>.py` with `register(subparsers)`, which adds its
parser and sets `func`. Heavy libraries are imported inside the handlers, so `--help` is instant.
"""

from __future__ import annotations

import argparse
import sys

from spare_twin import SpareTwinError, __version__
from spare_twin.commands import (
    bench,
    capture,
    compare,
    dataset,
    demo,
    evaluate,
    noise,
    predict,
    render,
    train,
)
from spare_twin.commands import object as object_command

#: Subcommand modules, in the order `--help` lists them.
COMMANDS = (object_command, render, noise, dataset, train, evaluate, predict, capture, compare, demo, bench)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="spare-twin",
        description="Physical-digital twins of articulated objects: print, simulate, learn, capture, compare.",
    )
    parser.add_argument("--version", action="version", version=f"spare-twin {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in COMMANDS:
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return 2
    try:
        return int(args.func(args) or 0)
    except SpareTwinError as exc:
        print(f"spare-twin {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"spare-twin {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
