"""The yaw-free profile network: a short training run must learn; evaluate and predict read it; the
samples are made the way `predict` makes its input (spare_twin.nets.profile_samples / profile_train)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from spare_twin.nets import checkpoint as ckpt
from spare_twin.nets.models import decode
from spare_twin.nets.profile_train import observe_split


@pytest.fixture(scope="module")
def small_data(tmp_path_factory):
    from spare_twin.cli import main

    out = tmp_path_factory.mktemp("profile") / "data"
    assert main(["dataset", "--out", str(out), "--instances", "36", "--frames", "3", "--seed", "4"]) == 0
    return out


@pytest.fixture(scope="module")
def run(small_data, tmp_path_factory):
    from spare_twin.cli import main

    out = tmp_path_factory.mktemp("profile_run") / "run"
    argv = ["train", "--preset", "profile-depth-multitask", "--data", str(small_data), "--out", str(out)]
    assert main([*argv, "--epochs", "25", "--batch-size", "8", "--seed", "1"]) == 0
    return out


def test_samples_are_deterministic_and_labelled(small_data):
    a = observe_split([small_data], "test", seed=3, variants=1, augment=True, progress=False)
    b = observe_split([small_data], "test", seed=3, variants=1, augment=True, progress=False)
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert a["x"].shape[1:] == (3, 64, 80) and len(a["n"]) + int(a["rejected"]) == len(a["n"]) + int(b["rejected"])
    # labels: 7 slots zero past the count, angles zero past the last joint
    for n, lengths, angles in zip(a["n"], a["lengths"], a["angles"]):
        assert (lengths[: n + 1] > 0).all() and not lengths[n + 1 :].any() and not angles[n:].any()


def test_a_short_training_run_learns(run, small_data):
    history = json.loads((run / "history.json").read_text())["history"]
    assert history[-1]["loss"] < 0.5 * history[0]["loss"]
    # it fits what it was shown: the training samples' counts and lengths
    model, net, _ = ckpt.load_model(run / "model.pt")
    with np.load(run / "samples-train.npz") as z:  # the observed training samples, as cached by the run
        train = {k: z[k] for k in z.files}
    res = decode(model, net, {"x": torch.from_numpy(train["x"].astype(np.float32))})
    acc = float((res["pred_n"].numpy() == train["n"]).mean())
    assert acc >= 0.9, acc


def test_evaluate_reads_the_profile_network(run, small_data, capsys):
    from spare_twin.cli import main

    assert main(["evaluate", "--model", str(run / "model.pt"), "--data", str(small_data), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["split"] == "test" and res["instances"] > 0
    assert 0.0 <= res["count_accuracy"] <= 1.0 and res["E_L"] >= 0.0
