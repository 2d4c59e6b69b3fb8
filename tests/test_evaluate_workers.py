"""`spare-twin evaluate` of the profile network observes and measures its split in a pool of worker
processes (`nets.profile_train.observe_split`, the dataset's pool): the split comes out in the same
order and bytes whatever the number of workers, and a Ctrl-C stops the pool quietly."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO, stderr_lines

from spare_twin.cli import main
from spare_twin.nets.profile_train import observe_split

SPARE_TWIN = str(REPO / ".venv" / "bin" / "spare-twin")


@pytest.fixture(scope="module")
def two_test_sequences(tmp_path_factory):
    """A rig dataset whose test split is sequences 6 and 7 (20 time steps each)."""
    data = tmp_path_factory.mktemp("eval_workers") / "data"
    assert main(["dataset", "--out", str(data), "--instances", "8", "--seed", "1", "--frames", "20"]) == 0
    return data


def test_the_split_is_the_same_whatever_the_workers(two_test_sequences):
    """Two workers give the split one process gives, sample for sample (the measurement too)."""
    kw = dict(seed=0, variants=1, augment=False, frame_stride=10, progress=False, measure=True, keep_rejected=True)
    alone = observe_split([two_test_sequences], "test", workers=1, **kw)
    pooled = observe_split([two_test_sequences], "test", workers=2, **kw)
    assert len(alone["n"]) == 4  # 2 sequences x time steps 0 and 10
    assert alone.keys() == pooled.keys() and "measured_lengths_pu" in alone
    for k in alone:
        assert np.array_equal(alone[k], pooled[k]), k


def _children(pid: int) -> list[int]:
    out = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        out += [int(c) for c in (task / "children").read_text().split()]
    return out


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="evaluate observes in one process on one core")
def test_ctrl_c_stops_the_observing_pool_quietly(two_test_sequences, tmp_path):
    """SIGINT to the whole process group (a terminal's Ctrl-C) while the pool observes: one line,
    exit 130, no worker traceback, no worker left, nothing cached."""
    cache = tmp_path / "cache"
    env = {**os.environ, "XDG_CACHE_HOME": str(cache)}
    argv = [SPARE_TWIN, "evaluate", "--data", str(two_test_sequences), "--device", "cpu", "--json"]
    proc = subprocess.Popen(
        argv, cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 120
        workers: list[int] = []
        while time.monotonic() < deadline and proc.poll() is None:
            workers = [c for c in _children(proc.pid) if b"spawn_main" in Path(f"/proc/{c}/cmdline").read_bytes()]
            if len(workers) == 2:
                break
            time.sleep(0.1)
        assert len(workers) == 2, "the pool of 2 never started"
        time.sleep(0.5)  # the workers are importing or observing: either way they must stay quiet
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    said = [ln for ln in stderr_lines(err) if not ln.startswith("observe test:")]  # the progress bar's last state
    assert said == ["spare-twin evaluate: interrupted"], said
    for pid in workers:
        for _ in range(50):
            if not Path(f"/proc/{pid}").exists() or "Z" in Path(f"/proc/{pid}/stat").read_text().split()[2]:
                break
            time.sleep(0.1)
        else:
            pytest.fail(f"worker {pid} outlived the interrupted run")
    assert not list(cache.rglob("*.npz"))
