"""`spare-twin predict` measures the recording in a process of its own while it imports torch
(`predict.early`, `measure.process`): the same answer as measured in-process, no torch on that path,
and the process gone when the command fails or is stopped. The command's JSON on both paths:
`test_predict_any_recording.py`."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import refused_before_torch

from spare_twin.errors import SpareTwinError
from spare_twin.predict.early import start_measuring
from spare_twin.predict.run import predict_recording


def test_the_measuring_process_gives_predicts_own_answer(sweep):
    here = predict_recording(sweep, progress=False)
    measuring = start_measuring(sweep, progress=False)
    try:
        there = predict_recording(sweep, progress=False, measuring=measuring)
    finally:
        measuring.close()
    assert there.n_links == here.n_links == 2
    assert there.to_json() == here.to_json()  # its JSON has no timings: the same bytes
    assert measuring._proc.returncode == 0 and measuring.peak_rss_mb > 50.0


def test_a_measuring_process_serves_only_the_options_it_was_started_with(sweep):
    measuring = start_measuring(sweep, progress=False)
    try:
        with pytest.raises(ValueError, match="measuring"):
            predict_recording(sweep, progress=False, measuring=measuring, print_scale=0.1)
    finally:
        measuring.close(kill=True)
    assert measuring._proc.returncode == -signal.SIGKILL


def test_a_bad_folder_is_refused_before_the_process_starts(tmp_path, monkeypatch):
    """No recording, or a frame number it cannot take: the in-process error, before any process starts."""
    (tmp_path / "notes.txt").write_text("not a recording\n")
    with pytest.raises(SpareTwinError) as here:
        predict_recording(tmp_path, progress=False)
    monkeypatch.setattr("spare_twin.predict.early.MeasureProcess", None)  # started, it would fail otherwise
    with pytest.raises(SpareTwinError) as there:
        start_measuring(tmp_path, progress=False)
    assert str(there.value) == str(here.value) and "recording.json" in str(here.value)


def test_the_processs_one_line_error_is_predicts(sweep, tmp_path):
    """A frame that does not read, found only by the process: the same error as in-process."""
    rec = tmp_path / "rec"
    shutil.copytree(sweep, rec)
    [depth] = list((rec / "cameras").glob("*/depth"))
    sorted(depth.iterdir())[3].write_bytes(b"not a PNG")
    with pytest.raises(SpareTwinError) as here:
        predict_recording(rec, progress=False)
    measuring = start_measuring(rec, progress=False)
    try:
        with pytest.raises(SpareTwinError) as there:
            predict_recording(rec, progress=False, measuring=measuring)
    finally:
        measuring.close()
    assert str(there.value) == str(here.value) and "depth" in str(here.value), here.value


def test_the_measuring_path_imports_no_torch():
    """What the command imports before it sets the measurement going, and the process itself; and the
    process's caller's side, which `spare-twin predict` imports first of all to start the process while
    it imports the rest, imports nothing heavy."""
    probe = (
        "import sys, spare_twin.commands.predict, spare_twin.predict.early, spare_twin.measure.serve;"
        "print('torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
    probe = (
        "import sys, spare_twin.measure.process;"
        "print([m for m in ('torch', 'scipy', 'spare_twin.measure.chain', 'spare_twin.observe') if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_a_missing_folder_or_checkpoint_is_said_before_torch_is_loaded(sweep, tmp_path):
    """No recording, or a checkpoint (`--model`) that is not there: said before torch is imported to
    read the network (3 s of a new process), and nothing written."""
    cases = [
        (["predict", "nope"], ("nope", "not a folder")),
        (["predict", str(sweep), "--model", "nope.pt"], ("nope.pt", "no such checkpoint")),
        (["predict", "nope", "--model", "nope.pt", "--json"], ("nope.pt", "no such checkpoint")),
    ]
    refused_before_torch(cases, tmp_path)


def _measuring_children(pid: int) -> list[int]:
    """Processes running `spare_twin.measure.serve` whose parent is `pid`."""
    found = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            cmdline = (d / "cmdline").read_bytes()
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid and b"spare_twin.measure.serve" in cmdline:
            found.append(int(d.name))
    return found


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads processes from /proc")
def test_a_stopped_predict_ends_its_measuring_process(sweep):
    """SIGTERM (as Ctrl-C) while the process measures: one line, exit 130, and the process gone."""
    p = subprocess.Popen(
        [sys.executable, "-m", "spare_twin", "predict", str(sweep), "--json"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 120
    children: list[int] = []
    while not children and p.poll() is None and time.monotonic() < deadline:
        children = _measuring_children(p.pid)
        time.sleep(0.05)
    assert children, "the measuring process never started"
    time.sleep(1.0)  # the command on to importing torch, the measurement under way
    p.send_signal(signal.SIGTERM)
    out, err = p.communicate(timeout=120)
    # a stop that landed inside torch's import once exited killed by SIGINT or by SIGABRT
    # (terminal._ImportsFinishFirst)
    assert p.returncode == 130 and out == "", err
    assert err.strip().splitlines()[-1] == "spare-twin predict: interrupted"
    for child in children:
        for _ in range(400):
            if not os.path.exists(f"/proc/{child}") or "Z" in Path(f"/proc/{child}/stat").read_text().split()[2]:
                break
            time.sleep(0.05)
        else:
            pytest.fail(f"the measuring process {child} outlived predict")
