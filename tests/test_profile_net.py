"""The yaw-free profile network: a short training run must learn; evaluate and predict read it; the
samples are made the way `predict` makes its input (spare_twin.nets.profile_samples / profile_train)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import run_cli

from spare_twin.nets import checkpoint as ckpt
from spare_twin.nets.profile_train import observe_split
from spare_twin.nets.registry import decode
from spare_twin.predict.combine import overrule


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
    assert main([*argv, "--epochs", "12", "--batch-size", "8", "--seed", "1"]) == 0
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
    """The profile network trains through the one training loop (nets.train) like every network."""
    history = json.loads((run / "history.json").read_text())
    assert len(history) == 12
    assert history[-1]["train_loss"] < 0.5 * history[0]["train_loss"]
    for name in ("last.pt", "best.pt", "model.pt", "learning_curve.png", "MODEL_CARD.md", "samples-val.npz"):
        assert (run / name).is_file(), name
    assert "scheduler" in ckpt.load(run / "last.pt")  # its one-cycle rate goes on where a resumed run left it
    # it fits what it was shown: the training samples' counts and lengths
    model, net, ck = ckpt.load_model(run / "model.pt")
    with np.load(run / "samples-train.npz") as z:  # the observed training samples, as cached by the run
        train = {k: z[k] for k in z.files}
    assert ck["meta"]["training_samples"] == len(train["n"])
    res = decode(model, net, {"x": torch.from_numpy(train["x"].astype(np.float32))})
    acc = float((res["pred_n"].numpy() == train["n"]).mean())
    assert acc >= 0.9, acc


#: A profile network small enough to train for a few epochs in a second.
TINY_PROFILE = {
    "net": {"channels": [8, 8, 8, 8, 8], "fc_hidden": 16},
    "train": {"epochs": 3, "batch_size": 16, "workers": 1, "threads": 1},
}


def _with_samples_of(run, folder):
    """A run folder that starts from `run`'s observed samples (observing them again costs most of a run)."""
    folder.mkdir()
    for f in run.glob("samples-*.npz"):
        shutil.copyfile(f, folder / f.name)
    return folder


def test_profile_training_resumes_exactly(run, small_data, tmp_path, monkeypatch):
    from spare_twin.nets import train as trainer
    from spare_twin.nets.presets import resolve

    preset = resolve("profile-depth-multitask", TINY_PROFILE)
    trainer.train(preset, [small_data], _with_samples_of(run, tmp_path / "a"), progress=False)
    end_epoch = trainer._RunWriter.end_epoch

    def interrupted(self, row, *args):  # a kill right after epoch 2's checkpoint
        best = end_epoch(self, row, *args)
        if row["epoch"] == 2:
            raise KeyboardInterrupt
        return best

    monkeypatch.setattr(trainer._RunWriter, "end_epoch", interrupted)
    with pytest.raises(KeyboardInterrupt):
        trainer.train(preset, [small_data], _with_samples_of(run, tmp_path / "b"), progress=False)
    monkeypatch.undo()
    assert ckpt.load(tmp_path / "b" / "last.pt")["epoch"] == 1
    trainer.train(preset, [small_data], tmp_path / "b", resume=True, progress=False)
    a, b = ckpt.load(tmp_path / "a" / "last.pt"), ckpt.load(tmp_path / "b" / "last.pt")
    assert a["epoch"] == b["epoch"] == 2 and len(b["history"]) == 3
    for k in a["state_dict"]:
        assert torch.equal(a["state_dict"][k], b["state_dict"][k]), k


def test_profile_training_takes_patience_and_device(run, small_data, tmp_path, capsys):
    """A rate too small to change the weights: validation moves only with BatchNorm's running
    statistics, which settle within a few epochs; with patience 1 the run ends one epoch after its
    best, well before epoch 10."""
    cfg = tmp_path / "cfg.json"
    cfg.write_text(json.dumps({"preset": "profile-depth-multitask", **TINY_PROFILE}))
    out = _with_samples_of(run, tmp_path / "run")
    argv = ["train", "--config", str(cfg), "--data", str(small_data), "--out", str(out), "--epochs", "10"]
    code, stdout, err = run_cli([*argv, "--lr", "1e-12", "--patience", "1", "--device", "cpu", "--json"], capsys)
    assert code == 0, err
    summary = json.loads(stdout)
    assert "stopping early" in err and summary["epochs"] == summary["best_epoch"] + 1 < 10
    assert len(json.loads((out / "history.json").read_text())) == summary["epochs"]
    code, stdout, err = run_cli([*argv, "--out", str(tmp_path / "otf"), "--on-the-fly"], capsys)
    assert code == 1 and "--on-the-fly" in err and not (tmp_path / "otf").exists()


def test_evaluate_gives_the_network_alone_and_combined(run, small_data, tmp_path, monkeypatch, capsys):
    """The network's own figures lead; the combined answer (overruled by the layer measurement, as
    predict answers) stands beside them; the observed split is cached, so a second evaluation reads it."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    argv = ["evaluate", "--model", str(run / "model.pt"), "--data", str(small_data), "--json"]
    code, out, err = run_cli(argv, capsys)
    assert code == 0, err
    res = json.loads(out)
    network, combined = res["network"], res["combined"]
    assert res["split"] == "test" and res["instances"] > 0 and res["headline"] == "network"
    assert res["count_accuracy"] == network["count_accuracy"] and res["E_L"] == network["E_L"]
    # the network's figure is the network's: its own argmax on the observed test profiles
    (cache,) = (tmp_path / "cache" / "spare-twin" / "observed").glob("test-*.npz")
    with np.load(cache) as z:
        test = {k: z[k] for k in z.files}
    model, net, _ = ckpt.load_model(run / "model.pt")
    own = decode(model, net, {"x": torch.from_numpy(test["x"].astype(np.float32))})
    assert len(test["n"]) == res["instances"]
    assert network["count_accuracy"] == pytest.approx(float((own["pred_n"].numpy() == test["n"]).mean()))
    # the combined figure is predict's rule applied to the same instances, with the measurement each carries
    answer = overrule(own, {k: torch.as_tensor(v) for k, v in test.items() if k.startswith("measured_")})
    assert combined["count_accuracy"] == pytest.approx(float((answer["pred_n"].numpy() == test["n"]).mean()))
    # on the rig's views as they are the layers find nearly every chain, and count it right
    assert (test["measured_n"] > 0).mean() >= 0.9 and combined["count_accuracy"] >= 0.9
    code, again, err = run_cli(argv, capsys)
    assert code == 0 and json.loads(again) == res and "observe test" not in err


def test_the_shipped_network_reads_an_image_and_its_mirror_alike():
    """`decode` averages the profile network over the image and its mirror image (the chain with its
    joint angles negated): the two readings give one count and the same lengths, the angles negated,
    though the network's own outputs on the two differ."""
    model, net, _ = ckpt.load_model(Path(__file__).resolve().parents[1] / "models" / "profile-multitask.pt")
    rng = np.random.default_rng(0)
    x = torch.from_numpy(rng.random((4, net.frames, net.height, net.width), dtype=np.float32))
    x[:, 0] = (x[:, 0] > 0.7).float()  # occupancy; channel 1 a mean t in layers, 0..1 here
    x[:, 1] *= 4 * x[:, 0]
    x[:, 2] *= 0.3 * x[:, 0]
    seen, mirrored = decode(model, net, {"x": x}), decode(model, net, {"x": x.flip(-1)})
    assert torch.allclose(seen["probabilities"], mirrored["probabilities"], atol=1e-6)
    assert torch.allclose(seen["lengths_e2e"], mirrored["lengths_e2e"], atol=1e-6)
    assert torch.allclose(seen["angles"], -mirrored["angles"], atol=1e-5)
    with torch.no_grad():
        plain, plain_mirrored = model(x=x), model(x=x.flip(-1))
    assert not torch.allclose(plain["count_logits"], plain_mirrored["count_logits"], atol=1e-3)
