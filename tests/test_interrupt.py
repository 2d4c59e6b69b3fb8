"""The fault test (issue 12): `render`, `capture import`, `capture register` and `dataset` killed with SIGKILL
at seeded random moments, half anywhere in the run and half while it writes its output. Right after a
kill the output path holds nothing new, the old output whole, or (for a resumable command) a part of the
finished output; re-running the same command then gives the output of an uninterrupted run byte for
byte, and nothing else on disk changed: inputs untouched, temporaries cleaned up.

The uninterrupted run is made first, in the same workspace (outputs record their inputs' paths). Outputs
compare file by file, byte for byte, except the wall-clock timings a registration records in
recording.json. Only kills that met a running process count.
"""

from __future__ import annotations

import hashlib
import json
import os
import random
import shlex
import shutil
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import pytest
from capture_helpers import APC
from conftest import REPO

SCRIPT = REPO / ".venv" / "bin" / "spare-twin"
KILLS_PER_COMMAND = 5  # 20 in all
MAX_TRIES = 14


def digest(p: Path) -> str:
    if p.name == "recording.json":  # a registration's wall-clock timings differ from run to run, rightly
        meta = json.loads(p.read_text())
        summary = (meta.get("registration") or {}).get("summary") or {}
        summary.pop("seconds", None)
        summary.pop("fusion_s", None)
        return hashlib.sha256(json.dumps(meta, sort_keys=True).encode()).hexdigest()
    return hashlib.sha256(p.read_bytes()).hexdigest()


def tree(root: Path, skip: str | None = None) -> dict[str, str]:
    """Every path under root (but `skip` and what is under it) -> digest of its content, "dir" for folders."""
    out = {}
    if not root.exists():
        return out
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            p = Path(dirpath) / name
            rel = p.relative_to(root).as_posix()
            if skip is not None and (rel == skip or rel.startswith(skip + "/")):
                continue
            out[rel] = "dir" if p.is_dir() else digest(p)
    return out


def diff(a: dict[str, str], b: dict[str, str]) -> str:
    gone = sorted(set(a) - set(b))[:4]
    new = sorted(set(b) - set(a))[:4]
    changed = sorted(k for k in set(a) & set(b) if a[k] != b[k])[:4]
    return f"missing {gone}, extra {new}, different {changed}"


@dataclass(frozen=True)
class Job:
    args: str
    out: str
    """The output path, relative to the workspace (for `capture register`, the recording it updates)."""
    resumable: bool = False
    in_place: bool = False


def make_object(ws: Path, sources: dict) -> None:
    shutil.copytree(sources["obj"], ws / "obj")


def make_source(ws: Path, sources: dict) -> None:
    shutil.copytree(sources["src"], ws / "src")


def make_imported(ws: Path, sources: dict) -> None:
    """The imported recording, with what a user adds to it: register updates it in place and must keep them."""
    shutil.copytree(sources["imported"], ws / "rec")
    (ws / "rec" / ".notes.txt").write_text("notes\n")
    (ws / "rec" / "notes_link").symlink_to(".notes.txt")
    (ws / "rec" / "empty").mkdir()


JOBS = {
    "render": (Job("render obj --out rec --frames 6 --resolution 64x48", "rec"), make_object),
    "capture-import": (Job("capture import src --layout 7scenes --out rec", "rec"), make_source),
    "capture-register": (
        Job("capture register rec --object skip --loop-gaps 2 --voxel 0.01", "rec", in_place=True),
        make_imported,
    ),
    "dataset": (Job("dataset --out data --instances 3 --frames 2", "data", resumable=True), lambda ws, s: None),
}


@pytest.fixture(scope="module")
def sources(printed_object, tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("interrupt_sources")
    src = root / "src"  # the four real frames, four times over: long enough a write to be killed in
    src.mkdir()
    shutil.copy(APC / "intrinsics.K.txt", src)
    for i, f in enumerate(sorted(APC.glob("frame-*.color.png")) * 4):
        for kind in ("color.png", "depth.png", "pose.txt"):
            shutil.copy(f.with_name(f.name.replace("color.png", kind)), src / f"frame-{i:06d}.{kind}")
    shutil.copytree(APC, root / "apc")
    run(["capture", "import", "apc", "--layout", "7scenes", "--out", "imported"], root)
    return {"obj": printed_object.root, "src": src, "imported": root / "imported"}


def run(argv: list[str], cwd: Path) -> None:
    p = subprocess.run([str(SCRIPT), *argv], cwd=cwd, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, f"spare-twin {' '.join(argv)}: {p.stderr[-1500:]}"


@dataclass
class Timeline:
    """When a run started writing (its first new entry in the workspace) and when it ended, in seconds."""

    write_start_s: float
    end_s: float

    @property
    def write_s(self) -> float:
        return max(self.end_s - self.write_start_s, 0.005)


def run_watched(argv: list[str], cwd: Path, kill=None) -> tuple[bool, Timeline]:
    """Run the command, watching the workspace; `kill(elapsed_s, write_start_s)` says when to SIGKILL it
    (and whatever it started). Returns whether it was killed while running, and its timeline."""
    before = set(os.listdir(cwd))
    with tempfile.TemporaryFile() as err:
        p = subprocess.Popen(
            [str(SCRIPT), *argv], cwd=cwd, stdout=subprocess.DEVNULL, stderr=err, start_new_session=True
        )
        t0, write_start = time.perf_counter(), None
        while p.poll() is None:
            now = time.perf_counter() - t0
            if write_start is None and set(os.listdir(cwd)) != before:
                write_start = now
            if kill is not None and kill(now, write_start):
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
                return True, Timeline(write_start or now, now)
            time.sleep(0.002)
        end = time.perf_counter() - t0
        if kill is None:
            err.seek(0)
            assert p.returncode == 0, f"spare-twin {' '.join(argv)}: {err.read()[-1500:].decode()}"
    return False, Timeline(end if write_start is None else write_start, end)


def moment(rng: random.Random, t: Timeline):
    """A seeded random moment: anywhere in the run, or while it writes its output."""
    if rng.random() < 0.5:
        at = rng.uniform(0.1, 1.0) * t.end_s
        return lambda now, write_start: now >= at
    after = rng.uniform(0.0, 1.0) * t.write_s
    return lambda now, write_start: write_start is not None and now >= write_start + after


def check_after_kill(job: Job, out: Path, before_out: dict, reference: dict) -> None:
    """The old output whole, nothing, the finished output, or for a resumable command a part of it."""
    now = tree(out)
    if now in (before_out, reference):
        return
    if job.resumable:
        own = {k: v for k, v in now.items() if k in reference}
        assert own == {k: reference[k] for k in own}, "a partial output differs from the finished one: " + diff(
            {k: reference[k] for k in own}, own
        )
        return
    pytest.fail(f"killed mid-run, {job.out} is neither the old output nor the finished one: {diff(before_out, now)}")


@pytest.mark.parametrize("name", list(JOBS))
def test_killed_runs_leave_old_output_and_rerun_matches(name, sources, tmp_path):
    job, setup = JOBS[name]
    argv = shlex.split(job.args)
    ws = tmp_path / "work"  # the reference run is made here too: outputs record their inputs' paths
    ws.mkdir()
    setup(ws, sources)
    _, timeline = run_watched(argv, ws)
    reference = tree(ws / job.out)
    if job.in_place:  # what the user added before the update is still there (then after every kill and rerun)
        assert {".notes.txt", "notes_link", "empty"} <= set(reference) and (ws / job.out / "notes_link").is_symlink()
    rng = random.Random(f"spare-twin kills {name}")
    kills = tries = 0
    while kills < KILLS_PER_COMMAND:
        # afresh (no output yet; for register the unregistered recording), or over the finished output;
        # a resumable command is always started afresh (finished, it has nothing left to do) and may be
        # killed again while it resumes
        if job.resumable or rng.random() < 0.5:
            shutil.rmtree(ws / job.out, ignore_errors=True)
            if job.in_place:
                setup(ws, sources)
        before_out, before_rest = tree(ws / job.out), tree(ws, skip=job.out)
        for _ in range(2 if job.resumable and rng.random() < 0.5 else 1):
            tries += 1
            assert tries <= MAX_TRIES, f"only {kills} of {tries - 1} kills met a running process"
            killed, seen = run_watched(argv, ws, kill=moment(rng, timeline))
            if killed:
                kills += 1
                check_after_kill(job, ws / job.out, before_out, reference)
            else:  # it ended before its moment: the reference run was slowed by a busy machine
                timeline = Timeline(min(timeline.write_start_s, seen.write_start_s), min(timeline.end_s, seen.end_s))
        run(argv, ws)
        after_out, after_rest = tree(ws / job.out), tree(ws, skip=job.out)
        assert after_out == reference, f"after kill {kills}, the rerun differs: {diff(reference, after_out)}"
        assert after_rest == before_rest, f"after kill {kills}, other files changed: {diff(before_rest, after_rest)}"
