"""`spare-twin evaluate` of the profile network observes and measures its split in a pool of worker
processes (`nets.profile_train.observe_split`, the dataset's pool): the split comes out in the same
order and bytes whatever the number of workers, and a Ctrl-C stops the pool quietly."""

from __future__ import annotations

import os

import numpy as np
import pytest
from conftest import REPO, interrupt_pool, stderr_lines

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


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="evaluate observes in one process on one core")
def test_ctrl_c_stops_the_observing_pool_quietly(two_test_sequences, tmp_path):
    """SIGINT to the whole process group (a terminal's Ctrl-C) while the pool observes: one line,
    exit 130, no worker traceback, no worker left, nothing cached."""
    cache = tmp_path / "cache"
    env = {**os.environ, "XDG_CACHE_HOME": str(cache)}
    argv = [SPARE_TWIN, "evaluate", "--data", str(two_test_sequences), "--device", "cpu", "--json"]
    code, err = interrupt_pool(argv, tmp_path, env)
    assert code == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    said = [ln for ln in stderr_lines(err) if not ln.startswith("observe test:")]  # the progress bar's last state
    assert said == ["spare-twin evaluate: interrupted"], said
    assert not list(cache.rglob("*.npz"))
