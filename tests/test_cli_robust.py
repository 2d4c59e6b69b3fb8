"""No crash reaches the user (issue 31): the environment and the terminal a command runs in.

A closed or broken stdout, an ASCII-only terminal, a deleted current folder, libraries that talk beside
an error, a result holding NaN, and an unexpected exception each end in exactly one stderr line (or in
strict JSON), the right exit code, no traceback, and an output that is whole or absent. These run the
console script in a subprocess: file descriptors, encodings, exit codes and what the interpreter prints
at exit are the point.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from conftest import REPO

from spare_twin.cli import main

SCRIPT = REPO / ".venv" / "bin" / "spare-twin"
OBJECT = ["object", "--links", "2", "--seed", "1", "--no-preview"]


def lines(stderr: str) -> list[str]:
    """The lines a person sees (a progress bar redraws its line with carriage returns)."""
    return [ln.split("\r")[-1] for ln in stderr.split("\n") if ln.split("\r")[-1].strip()]


def one_error_line(p: subprocess.CompletedProcess, code: int = 1) -> str:
    """Asserts the run failed as a user should see it: exit `code`, one stderr line, no traceback."""
    assert "Traceback" not in p.stderr and "Exception ignored" not in p.stderr, p.stderr[-2000:]
    assert p.returncode == code, (p.returncode, p.stderr[-1000:])
    said = lines(p.stderr)
    assert len(said) == 1, said
    return said[0]


def spare_twin(argv, cwd, **kwargs) -> subprocess.CompletedProcess:
    if "stdout" not in kwargs:
        kwargs.setdefault("capture_output", True)
    return subprocess.run([str(SCRIPT), *argv], cwd=cwd, text=True, timeout=120, **kwargs)


def files(root: Path) -> dict[str, str]:
    """Every file under root -> its hash."""
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def whole_object(tmp_path_factory) -> dict[str, str]:
    """The files of `spare-twin object --links 2 --seed 1 --no-preview`, made undisturbed: what a
    whole output holds (the object is rebuilt bit for bit from its seed)."""
    root = tmp_path_factory.mktemp("whole") / "obj"
    assert spare_twin([*OBJECT, "--out", str(root)], root.parent).returncode == 0
    return files(root)


# -- stdout closed or broken -----------------------------------------------------------------------


def test_closed_stdout_is_refused_before_any_work(tmp_path):
    p = spare_twin([*OBJECT, "--out", "o", "--json"], tmp_path, preexec_fn=lambda: os.close(1))
    assert "stdout is closed" in one_error_line(p)
    assert not (tmp_path / "o").exists()


def test_stdout_a_pipe_nobody_reads_is_refused_before_any_work(tmp_path):
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        p = spare_twin([*OBJECT, "--out", "o", "--json"], tmp_path, stdout=write_end, stderr=subprocess.PIPE)
    finally:
        os.close(write_end)
    assert "nobody reads" in one_error_line(p)
    assert not (tmp_path / "o").exists()


#: Runs `spare-twin ARGV` with stdout a pipe whose only reader closes it once TARGET has done its work:
#: the command started with a good stdout and finds it broken when it prints (`| head -1` done reading).
BREAKS_STDOUT = textwrap.dedent(
    """
    import importlib, os, sys
    from spare_twin.cli import main

    read_end, write_end = os.pipe()
    os.dup2(write_end, 1)
    os.close(write_end)
    module, name = sys.argv[1].split(":")
    mod = importlib.import_module(module)
    real = getattr(mod, name)

    def then_close_the_reader(*args, **kwargs):
        out = real(*args, **kwargs)
        os.close(read_end)
        return out

    setattr(mod, name, then_close_the_reader)
    sys.exit(main(sys.argv[2:]))
    """
)


@pytest.mark.parametrize("json_flag", [["--json"], []], ids=["json", "text"])
def test_stdout_broken_while_running_is_one_line_and_the_output_whole(json_flag, tmp_path, whole_object):
    argv = [*OBJECT, "--out", "o", *json_flag]
    p = subprocess.run(
        [sys.executable, "-c", BREAKS_STDOUT, "spare_twin.object.folder:make_object", *argv],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert "broken pipe" in one_error_line(p)
    assert files(tmp_path / "o") == whole_object


def test_closed_stderr_still_gives_one_json_object_and_the_output_whole(tmp_path, whole_object):
    """With stderr closed, the first file the command opened took its number: C libraries' chatter
    (pybullet's banner) would land in an output file, or on stdout beside the JSON object."""
    p = spare_twin([*OBJECT, "--out", "o", "--json"], tmp_path, preexec_fn=lambda: os.close(2))
    assert p.returncode == 0
    assert len(p.stdout.splitlines()) == 1 and json.loads(p.stdout)["n_links"] == 2, p.stdout
    assert files(tmp_path / "o") == whole_object


# -- encodings -------------------------------------------------------------------------------------


def test_ascii_terminal_and_a_non_ascii_out(tmp_path, whole_object):
    env = {**os.environ, "PYTHONIOENCODING": "ascii"}
    p = spare_twin([*OBJECT, "--out", "objét"], tmp_path, env=env)
    assert p.returncode == 0 and "Traceback" not in p.stderr, p.stderr[-2000:]
    assert "obj\\xe9t" in p.stdout  # said, escaped
    assert files(tmp_path / "objét") == whole_object
    # a one-line error naming a non-ASCII file is still one line
    p = spare_twin(["render", "maquette_née", "--out", "r"], tmp_path, env=env)
    assert "maquette_n\\xe9e" in one_error_line(p)
    # and so is an argument error
    p = spare_twin(["object", "--links", "deux_é", "--out", "x"], tmp_path, env=env)
    assert "--links" in one_error_line(p, code=2)


# -- the current folder deleted --------------------------------------------------------------------


@pytest.mark.parametrize("where", ["relative", "absolute"])
def test_deleted_current_folder_is_one_line(where, tmp_path):
    gone = tmp_path / "gone"
    gone.mkdir()
    out = "x" if where == "relative" else str(tmp_path / "x")
    # the shell enters the folder, then it is removed under it (`mkdir d; cd d; rmdir ../d; spare-twin ...`)
    enter_and_remove = 'cd "$1" && rmdir "$1" && shift && exec "$@"'
    p = subprocess.run(
        ["bash", "-c", enter_and_remove, "_", str(gone), str(SCRIPT), *OBJECT, "--out", out],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert "current folder no longer exists" in one_error_line(p)
    assert not (tmp_path / "x").exists()


# -- libraries talking beside an error -------------------------------------------------------------


@pytest.fixture(scope="module")
def small_rec(printed_object, tmp_path_factory) -> Path:
    from spare_twin.sim.render import RenderConfig, render_recording

    rec = tmp_path_factory.mktemp("robust") / "rec"
    cfg = RenderConfig(frames=3, resolution="64x48", path="handheld", motion="static", segmentation=False)
    render_recording(printed_object.root, rec, cfg, progress=False)
    return rec


def test_a_garbled_png_is_one_line_without_libpngs_own(small_rec, tmp_path):
    """libpng prints "libpng error: IDAT: invalid literal/lengths set" on stderr itself when OpenCV
    reads a PNG whose compressed data is garbled; the command's own error is the one line."""
    import shutil

    rec = tmp_path / "rec"
    shutil.copytree(small_rec, rec)
    png = rec / "cameras" / "cam0" / "depth" / "000001.png"
    data = bytearray(png.read_bytes())
    for i in range(100, len(data), 37):  # the header stays good: the damage is found while decoding
        data[i] ^= 0x5A
    png.write_bytes(bytes(data))
    before = files(rec)
    p = spare_twin(["capture", "register", "rec", "--json"], tmp_path)
    message = one_error_line(p)
    assert "000001.png" in message and "libpng" not in p.stderr
    assert p.stdout == ""
    assert files(rec) == before
    # the libpng line is really printed: with the chatter shown, it is there
    p = spare_twin(["capture", "register", "rec", "--json"], tmp_path, env={**os.environ, "SPARE_TWIN_DEBUG": "1"})
    assert "libpng error" in p.stderr


#: Runs `spare-twin ARGV` with TARGET made to talk as libraries do (a Python warning, numpy's
#: RuntimeWarning, C code's fprintf on stderr, a child process's output, a forked worker's traceback)
#: and then do WHAT: "work" (the real call), "fail" (a SpareTwinError), or raise the named exception
#: ("TypeError", "MemoryError", "RecursionError", "KeyboardInterrupt", "numpy-allocation").
TALKING_LIBRARY = textwrap.dedent(
    """
    import ctypes, importlib, os, subprocess, sys, traceback, warnings
    import numpy as np
    from spare_twin import SpareTwinError
    from spare_twin.cli import main

    module, name = sys.argv[1].split(":")
    what = sys.argv[2]
    mod = importlib.import_module(module)
    real = getattr(mod, name)

    def talking(*args, **kwargs):
        warnings.warn("a library's deprecation", DeprecationWarning)
        warnings.warn("a library's own warning", UserWarning)
        np.log(np.zeros(1))  # RuntimeWarning: divide by zero encountered in log
        libc = ctypes.CDLL(None)
        libc.dprintf(2, b"[ WARN:0@0.1] global loadsave.cpp (1): C code's warning\\n")
        subprocess.run([sys.executable, "-c", "import sys; print('a worker says', file=sys.stderr)"])
        pid = os.fork()  # a forked worker's traceback, as multiprocessing prints it on Ctrl-C
        if pid == 0:
            try:
                raise RuntimeError("a forked worker's error")
            except RuntimeError:
                traceback.print_exc()
            sys.stderr.flush()
            os._exit(0)
        os.waitpid(pid, 0)
        if what == "work":
            return real(*args, **kwargs)
        if what == "fail":
            raise SpareTwinError("seed 1: refused by the test")
        if what == "numpy-allocation":
            np.empty(10**15)
        if what == "RecursionError":
            def deeper(n):
                return deeper(n + 1)
            deeper(0)
        raise getattr(__builtins__, what)("the test's " + what)

    setattr(mod, name, talking)
    sys.exit(main(sys.argv[3:]))
    """
)


def talking(what: str, cwd: Path, argv=(*OBJECT, "--out", "o"), **env) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", TALKING_LIBRARY, "spare_twin.object.folder:make_object", what, *argv],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, **env},
    )


def test_warnings_and_chatter_around_an_error_leave_one_line(tmp_path):
    p = talking("fail", tmp_path)
    assert one_error_line(p) == "spare-twin object: error: --seed 1: refused by the test"
    assert not (tmp_path / "o").exists()


def test_warnings_and_chatter_of_a_command_that_works_are_still_shown(tmp_path, whole_object):
    p = talking("work", tmp_path)
    assert p.returncode == 0, p.stderr[-2000:]
    for said in ("a library's own warning", "divide by zero", "C code's warning", "a worker says", "worker's error"):
        assert said in p.stderr
    assert files(tmp_path / "o") == whole_object


# -- an unexpected exception -----------------------------------------------------------------------


@pytest.mark.parametrize(
    "what, says",
    [
        ("TypeError", "internal error, TypeError: the test's TypeError (SPARE_TWIN_DEBUG=1 shows where)"),
        ("RecursionError", "internal error, RecursionError: maximum recursion depth exceeded"),
        ("MemoryError", "out of memory: the test's MemoryError"),
        ("numpy-allocation", "out of memory: Unable to allocate"),
    ],
)
def test_an_unexpected_exception_is_one_line(what, says, tmp_path):
    p = talking(what, tmp_path)
    assert one_error_line(p).startswith(f"spare-twin object: error: {says}")
    assert not (tmp_path / "o").exists()


def test_ctrl_c_is_one_line_without_the_workers_tracebacks(tmp_path):
    p = talking("KeyboardInterrupt", tmp_path)
    assert one_error_line(p, code=130) == "spare-twin object: interrupted"


def test_debug_shows_the_traceback(tmp_path):
    p = talking("TypeError", tmp_path, SPARE_TWIN_DEBUG="1")
    assert p.returncode == 1
    assert "Traceback (most recent call last)" in p.stderr and "TypeError: the test's TypeError" in p.stderr
    assert "a library's own warning" in p.stderr  # nothing held back either


# -- strict JSON -----------------------------------------------------------------------------------


class _NotFinite:
    """A command's result whose JSON holds NaN and infinities (as a checkpoint with NaN weights gave)."""

    def __init__(self, made):
        self.made = made

    def __getattr__(self, name):
        return getattr(self.made, name)

    def to_json(self):
        return {**self.made.to_json(), "score": math.nan, "E_L": math.inf, "per_n": [1.0, -math.inf]}


def test_json_never_holds_nan_or_infinity(monkeypatch, tmp_path, capsys):
    """`json.dumps` writes a NaN as the bare word NaN, which is not JSON: a checkpoint whose weights
    are NaN made `evaluate --json` print it. Every --json object is strict JSON, non-finite as null."""
    import spare_twin.object.folder as folder

    real = folder.make_object
    monkeypatch.setattr(folder, "make_object", lambda *args, **kwargs: _NotFinite(real(*args, **kwargs)))
    code = main([*OBJECT, "--out", str(tmp_path / "o"), "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err

    def refuse(word):
        raise AssertionError(f"{word} in {out!r}")

    printed = json.loads(out, parse_constant=refuse)
    assert (printed["score"], printed["E_L"], printed["per_n"]) == (None, None, [1.0, None])
    assert printed["n_links"] == 2  # the rest as it was


def test_strict_json_leaves_finite_text_as_it_was():
    from spare_twin.terminal import strict_json

    text = json.dumps({"a": [0.1, 2, "é", None, {"b": 1e300}]}, ensure_ascii=False)
    assert strict_json(text) == text
    assert json.loads(strict_json('{"x": 1e999, "y": -Infinity}')) == {"x": None, "y": None}
