"""The `spare-twin` command line: one console script with a subcommand per stage.

Each subcommand lives in `spare_twin/commands/<name>.py` with `register(subparsers)`, which adds its
parser and sets `func`. Heavy libraries are imported inside the handlers, so `--help` is instant.

Every failure a user can cause is one line on stderr: argument errors (`spare-twin CMD: error: ...`,
exit 2), library errors (exit 1) and interruptions (Ctrl-C, SIGTERM, SIGHUP: exit 130, after the
output rule's clean-ups have run). With `--json`, stdout holds exactly one JSON object: the handler
`print`s it on a line of its own, as its last word, and everything else written to stdout while it
runs (libraries' own printing, C and C++ included) goes to stderr (`spare_twin.terminal.single_json_stdout`).

Nothing else reaches the user as a crash: an unexpected exception (a bug, a C extension's error) is one
line naming its type, exit 1 (SPARE_TWIN_DEBUG=1 shows the traceback); a current folder that was deleted
or a closed stdout is refused before any work; printing never fails on encoding; a broken pipe on stdout
is one line; and what libraries print on stderr beside a failure is held back (`library_chatter_held`).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys

from spare_twin import SpareTwinError, __version__
from spare_twin.commands import (
    bench,
    capture,
    compare,
    dataset,
    demo,
    evaluate,
    live,
    noise,
    predict,
    render,
    train,
)
from spare_twin.commands import object as object_command

#: Set (to anything) to see the traceback of an unexpected error, and the libraries' own output, unfiltered.
DEBUG_ENV = "SPARE_TWIN_DEBUG"

#: Subcommand modules, in the order `--help` lists them.
COMMANDS = (object_command, render, noise, dataset, train, evaluate, predict, live, capture, compare, demo, bench)


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


def _say(line: str) -> None:
    """One line on stderr; a stderr that is closed or a broken pipe cannot make it a traceback."""
    with contextlib.suppress(OSError, ValueError, AttributeError):
        print(line, file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    # terminal is light (no numpy): text streams must not fail on encoding even for argument errors
    from spare_twin.terminal import (
        environment_problem,
        fill_closed_stdin_stderr,
        library_chatter_held,
        never_fail_on_encoding,
    )

    fill_closed_stdin_stderr()
    never_fail_on_encoding()
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return 2
    # an empty output path would become Path("") == "." (the current folder) further on: say what it is
    empty = next((flag for flag in ("out", "rrd") if getattr(args, flag, None) == ""), None)
    problem = f"--{empty} '': an output path cannot be empty" if empty else environment_problem()
    if problem:
        _say(f"spare-twin {args.command}: error: {problem}")
        return 1
    # OpenCV logs warnings of its own (imread on a corrupt file) beside the error that the code reports
    os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")
    debug = bool(os.environ.get(DEBUG_ENV))
    with library_chatter_held() if not debug else contextlib.nullcontext() as chatter:
        code = _run(args, debug)
        if chatter is not None:
            chatter.keep = code == 0  # a failure says its one line, without the libraries' words around it
    return code


def _run(args: argparse.Namespace, debug: bool) -> int:
    # after parsing: spare_twin.output pulls in numpy, which --help and argument errors need not wait for
    from spare_twin.output import OutputRefused
    from spare_twin.terminal import signals_as_interrupts, single_json_stdout, stdout_gone

    failed = f"spare-twin {args.command}: error:"
    try:
        with signals_as_interrupts(), single_json_stdout(bool(getattr(args, "json", False)), catch_printed=True):
            code = int(args.func(args) or 0)
        return code
    except SpareTwinError as exc:
        message = exc.message("--force") if isinstance(exc, OutputRefused) else str(exc)
        _say(f"{failed} {_one_line(message)}")
        return 1
    except OSError as exc:  # the file system said no where no library check did: still one line, naming the file
        if isinstance(exc, BrokenPipeError) and stdout_gone():  # stdout's reader ended (`| head -1`)
            _say(f"{failed} stdout: the pipe's reader ended before the command had printed everything (broken pipe)")
            return 1
        where = f"{exc.filename}: " if exc.filename else ""
        _say(f"{failed} {where}{exc.strerror or exc}")
        return 1
    except KeyboardInterrupt:
        _say(f"spare-twin {args.command}: interrupted")
        return 130
    except MemoryError as exc:  # numpy says how much it could not allocate
        _say(f"{failed} out of memory{': ' + _one_line(str(exc)) if str(exc) else ''}")
        return 1
    except Exception as exc:  # a bug, or a C extension's error on input no check caught: one line all the same
        if debug:
            raise
        detail = _one_line(str(exc))[:300]
        what = f"{type(exc).__name__}: {detail}" if detail else type(exc).__name__
        _say(f"{failed} internal error, {what} ({DEBUG_ENV}=1 shows where)")
        return 1


if __name__ == "__main__":
    sys.exit(main())
