"""The `spare-twin` command line: one console script with a subcommand per stage.

Each subcommand lives in `spare_twin/commands/<name>.py` with `register(subparsers)`, which adds its
parser and sets `func`. Heavy libraries are imported inside the handlers, so `--help` is instant.

Every failure a user can cause is one line on stderr: argument errors (`spare-twin CMD: error: ...`,
exit 2), library errors (exit 1) and interruptions (Ctrl-C, SIGTERM, SIGHUP: exit 130, after the
output rule's clean-ups have run). With `--json`, stdout holds exactly one JSON object: the handler
`print`s it on a line of its own, as its last word, and everything else written to stdout while it
runs (libraries' own printing, C and C++ included) goes to stderr (`spare_twin.terminal.single_json_stdout`).
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


class OneLineParser(argparse.ArgumentParser):
    """An argument error is one line (`spare-twin CMD: error: ...`), not the usage and the error:
    scripts and people read the last line. Subcommand parsers are made of the same class."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="spare-twin",
        description="Physical-digital twins of articulated objects: print, simulate, learn, capture, compare.",
    )
    parser.add_argument("--version", action="version", version=f"spare-twin {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in COMMANDS:
        module.register(sub)
    return parser


def _one_line(message: str) -> str:
    return " ".join(part.strip() for part in message.splitlines() if part.strip())


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return 2
    # after parsing: spare_twin.output pulls in numpy, which --help and argument errors need not wait for
    from spare_twin.output import OutputRefused
    from spare_twin.terminal import signals_as_interrupts, single_json_stdout

    try:
        with signals_as_interrupts(), single_json_stdout(bool(getattr(args, "json", False)), catch_printed=True):
            code = int(args.func(args) or 0)
        return code
    except SpareTwinError as exc:
        message = exc.message("--force") if isinstance(exc, OutputRefused) else str(exc)
        print(f"spare-twin {args.command}: error: {_one_line(message)}", file=sys.stderr)
        return 1
    except OSError as exc:  # the file system said no where no library check did: still one line, naming the file
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"spare-twin {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"spare-twin {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
