"""Training learns on an easy synthetic set; checkpoints round-trip; resume is exact; evaluate and
predict work end to end through the CLI."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import TINY, refused_before_torch, run_cli


def test_training_learns_well_above_chance(trained):
    hist = json.loads((trained / "history.json").read_text())
    assert len(hist) == 5
    best = max(h["val_count_accuracy"] for h in hist)
    assert best > 0.5, hist  # chance is 1/6
    assert hist[-1]["train_loss"] < hist[0]["train_loss"]
    for f in ("last.pt", "best.pt", "model.pt", "learning_curve.png", "MODEL_CARD.md"):
        assert (trained / f).is_file(), f


def test_checkpoint_round_trip_gives_identical_outputs(trained, synthetic_data, tmp_path):
    from spare_twin.nets import checkpoint as ckpt
    from spare_twin.nets.data import open_split
    from spare_twin.nets.models import model_inputs

    model, net, ck = ckpt.load_model(trained / "model.pt")
    assert ck["meta"]["seed"] == 3 and ck["meta"]["rig"] and ck["normalization"] is None  # geo nets read metres
    batch = torch.utils.data.default_collate([open_split(synthetic_data, "test", net)[i] for i in range(4)])
    with torch.no_grad():
        a = model(**model_inputs(batch, "cpu"))
    ckpt.save(tmp_path / "copy.pt", ck)
    model2, _, _ = ckpt.load_model(tmp_path / "copy.pt")
    with torch.no_grad():
        b = model2(**model_inputs(batch, "cpu"))
    for k in a:
        assert torch.equal(a[k], b[k]), k
    card = ckpt.write_card(tmp_path / "copy.pt")
    assert "geo-depth-mv-multitask" in card.read_text()


def test_evaluate_json(trained, synthetic_data, tmp_path, capsys):
    code, out, err = run_cli(
        [
            "evaluate",
            "--model",
            str(trained / "model.pt"),
            "--data",
            str(synthetic_data),
            "--out",
            str(tmp_path),
            "--json",
        ],
        capsys,
    )
    assert code == 0, err
    res = json.loads(out)  # exactly one JSON object on stdout
    assert res["split"] == "test" and res["instances"] == 64
    assert 0.3 < res["count_accuracy"] <= 1.0
    # End-to-end E_L adds the cost of wrong counts to the n-known error, so it is never below it.
    assert res["E_L"] is not None and res["E_L_n_known"] is not None
    assert res["E_L"] >= res["E_L_n_known"] - 1e-9
    assert sum(r["instances"] for r in res["per_n"].values()) == 64
    assert (tmp_path / "confusion_matrix.png").is_file()
    assert np.asarray(res["confusion_matrix"]).sum() == 64


def test_bad_inputs_are_one_line_errors(synthetic_data, tmp_path, capsys):
    code, out, err = run_cli(
        ["evaluate", "--model", str(tmp_path / "nope.pt"), "--data", str(synthetic_data), "--json"], capsys
    )
    assert code == 1 and "nope.pt" in err and out == ""
    code, out, err = run_cli(
        ["train", "--preset", "bogus", "--data", str(synthetic_data), "--out", str(tmp_path / "r")], capsys
    )
    assert code == 1 and "bogus" in err


def test_a_missing_data_folder_or_a_folder_not_a_run_is_said_before_torch_is_loaded(tmp_path):
    """A missing data folder, a bad count, or a run folder it would not write (yours, the data's, a
    finished run's; nothing to resume): said before the training's modules (torch: 3-5 s of a new
    process) are imported, and nothing written."""
    (tmp_path / "data").mkdir()
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("mine")
    (tmp_path / "done").mkdir()
    (tmp_path / "done" / "last.pt").write_bytes(b"a run")
    train = ["train", "--preset", "profile-depth-multitask"]
    cases = [
        (["--data", "nope", "--out", "run"], ("--data nope", "no such folder")),
        (["--data", "data,nope", "--out", "run"], ("--data nope", "no such folder")),
        (["--data", "data", "--epochs", "0", "--out", "run"], ("--epochs 0",)),
        (["--data", "data", "--workers", "-1", "--out", "run"], ("--workers -1",)),
        (["--data", "data", "--out", "mine"], ("--out mine", "not a training run", "notes.txt")),
        (["--data", "data", "--out", "data/run", "--force"], ("--out data/run", "data folder")),
        (["--data", "data", "--out", "done"], ("--out done", "already holds a run")),
        (["--data", "data", "--out", "run", "--resume"], ("--resume", "nothing to resume")),
    ]
    refused_before_torch([([*train, *args], words) for args, words in cases], tmp_path)


def test_resume_continues_exactly(synthetic_data, tmp_path):
    from spare_twin.errors import SpareTwinError
    from spare_twin.nets import checkpoint as ckpt
    from spare_twin.nets.presets import resolve
    from spare_twin.nets.train import train

    cfg = {
        "net": {"channels": [4, 8], "fc_hidden": 16, "dropout": 0.2},
        "train": {"epochs": 2, "batch_size": 8, "samples_per_epoch": 24, "val_samples": 8, "threads": 1},
    }
    full = resolve("geo-depth-mv-count", cfg)
    train(full, synthetic_data, tmp_path / "a", progress=False)
    first = resolve("geo-depth-mv-count", {**cfg, "train": {**cfg["train"], "epochs": 1}})
    train(first, synthetic_data, tmp_path / "b", progress=False)  # "interrupted" after epoch 1
    with pytest.raises(SpareTwinError, match="resume"):
        train(full, synthetic_data, tmp_path / "b", progress=False)  # refuses to overwrite a run
    train(full, synthetic_data, tmp_path / "b", resume=True, progress=False)
    a, b = ckpt.load(tmp_path / "a" / "last.pt"), ckpt.load(tmp_path / "b" / "last.pt")
    assert a["epoch"] == b["epoch"] == 1
    for k in a["state_dict"]:
        assert torch.equal(a["state_dict"][k], b["state_dict"][k]), k


def test_training_stops_once_validation_stops_improving(synthetic_data, tmp_path, capsys):
    """A learning rate too small to change anything: validation never improves on epoch 1, so with
    patience 2 the run ends after epoch 3 of 20, and model.pt is epoch 1's."""
    cfg = tmp_path / "cfg.json"
    cfg.write_text(
        json.dumps(
            {
                "preset": "geo-depth-mv-count",
                "net": {"channels": [4, 8], "fc_hidden": 16, "dropout": 0.0},
                "train": {"epochs": 20, "batch_size": 8, "samples_per_epoch": 16, "val_samples": 16, "threads": 1},
            }
        )
    )
    argv = ["train", "--config", str(cfg), "--data", str(synthetic_data), "--out", str(tmp_path / "run")]
    code, out, err = run_cli([*argv, "--lr", "1e-12", "--patience", "2", "--json"], capsys)
    assert code == 0, err
    assert "stopping early" in err
    hist = json.loads((tmp_path / "run" / "history.json").read_text())
    assert len(hist) == 3 and json.loads(out)["best_epoch"] == 1
    from spare_twin.nets.train import epochs_since_best

    assert epochs_since_best(hist) == 2
    assert epochs_since_best([{"val_count_accuracy": 0.2}, {"val_count_accuracy": 0.5}]) == 0
    assert epochs_since_best([{"train_loss": 1.0}, {"train_loss": 2.0}, {"train_loss": 1.5}]) == 2


def test_fine_tune_starts_from_a_checkpoint(trained, synthetic_data, tmp_path):
    from spare_twin.errors import SpareTwinError
    from spare_twin.nets import checkpoint as ckpt
    from spare_twin.nets.presets import resolve
    from spare_twin.nets.train import train

    source = trained / "model.pt"
    # one short epoch (the start is what is checked), then the whole validation split
    train_cfg = {**TINY["train"], "epochs": 1, "samples_per_epoch": 16, "lr": 1e-12, "init_from": str(source)}
    cfg = {"net": TINY["net"], "train": train_cfg}
    train(resolve("geo-depth-mv-multitask", cfg), synthetic_data, tmp_path / "ft", progress=False)
    start, tuned = ckpt.load(source), ckpt.load(tmp_path / "ft" / "model.pt")
    assert tuned["meta"]["init_from"]["path"] == str(source)
    weights = [k for k in start["state_dict"] if k.endswith("weight") and start["state_dict"][k].dim() > 1]
    assert weights and all(torch.allclose(start["state_dict"][k], tuned["state_dict"][k], atol=1e-6) for k in weights)
    # the learned count survives: a randomly initialised net at this learning rate stays near chance
    assert tuned["meta"]["val_metrics"]["val_count_accuracy"] > 0.5
    other = {
        "net": {"channels": [4, 8], "fc_hidden": 16},
        "train": {"epochs": 1, "init_from": str(source), "threads": 1},
    }
    with pytest.raises(SpareTwinError, match="different network configuration"):
        train(resolve("geo-depth-mv-multitask", other), synthetic_data, tmp_path / "bad", progress=False)


def test_force_replaces_a_foreign_run_folder_once_training_is_complete(synthetic_data, tmp_path):
    from spare_twin.errors import SpareTwinError
    from spare_twin.nets.presets import resolve
    from spare_twin.nets.train import train

    cfg = {
        "net": {"channels": [4, 8], "fc_hidden": 16, "dropout": 0.0},
        "train": {"epochs": 1, "batch_size": 8, "samples_per_epoch": 16, "val_samples": 8, "threads": 1},
    }
    preset = resolve("geo-depth-mv-count", cfg)
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    with pytest.raises(SpareTwinError, match="not a training run"):
        train(preset, synthetic_data, mine, progress=False)
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
    summary = train(preset, synthetic_data, mine, progress=False, force=True)
    assert summary["model"] == str(mine / "model.pt") and (mine / "model.pt").is_file()
    assert not (mine / "notes.txt").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"]  # no temporary left beside it
    # the data folder is never replaced, force or not
    with pytest.raises(SpareTwinError, match="data folder"):
        train(preset, synthetic_data, Path(synthetic_data) / "run", progress=False, force=True)


def test_batchnorm_recalibration_touches_only_the_running_statistics(synthetic_data):
    from spare_twin.nets.data import open_split
    from spare_twin.nets.presets import resolve
    from spare_twin.nets.registry import build_model
    from spare_twin.nets.train import recalibrate_batchnorm

    net = resolve("geo-depth-mv-count", {"net": {"channels": [4, 8], "fc_hidden": 16}}).net
    torch.manual_seed(0)
    model = build_model(net)
    before = {k: v.clone() for k, v in model.state_dict().items()}
    rng = torch.get_rng_state()
    recalibrate_batchnorm(model, net, open_split(synthetic_data, "train", net), 40, 8, 0, "cpu")
    after = model.state_dict()
    assert torch.equal(torch.get_rng_state(), rng)  # the training that follows draws the same numbers
    bn_stats = [k for k in after if k.endswith(("running_mean", "running_var"))]
    assert bn_stats and all(not torch.equal(before[k], after[k]) for k in bn_stats)
    assert all(int(v) == 5 for k, v in after.items() if k.endswith("num_batches_tracked"))  # 40 / 8 batches
    assert all(torch.equal(before[k], after[k]) for k in after if "running" not in k and "batches" not in k)
    assert model.training


def test_a_checkpoint_from_before_a_new_network_field_still_resumes():
    import dataclasses

    from spare_twin.nets.presets import get_preset
    from spare_twin.nets.train import _same_net

    net = get_preset("geo-grey-mv-multitask").net
    old = dataclasses.asdict(net)
    del old["lift_extremes"]  # a field added after the run started: its default is what ran
    assert _same_net({"net": old}, net)
    assert not _same_net({"net": {**old, "lift_features": 5}}, net)
