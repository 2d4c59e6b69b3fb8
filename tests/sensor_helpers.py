"""Shared fixtures for the simulated-sensor and canonical-view tests: one small printed object, one
hand-held simulated-sensor recording of it (registered once), tiny checkpoints. Module-level caches
make every test module that imports these fixtures share the same (expensive) results."""

import json
import shutil

import pytest
from conftest import run_cli

_CACHE: dict = {}
FRAMES, RESOLUTION, SEED = 12, "320x240", 1


@pytest.fixture(scope="session")
def printed_object(tmp_path_factory):
    """A 2-link object (the one the sensor records)."""
    if "object" not in _CACHE:
        from spare_twin.config import sample_chain
        from spare_twin.object.folder import build_object

        _CACHE["object"] = build_object(
            sample_chain(2, seed=7), tmp_path_factory.mktemp("printed") / "obj", preview=False
        )
    return _CACHE["object"]


@pytest.fixture(scope="session")
def handheld_rec(printed_object, tmp_path_factory):
    """`spare-twin render --path handheld --noise realsense_sr300`: 12 frames at 320x240."""
    if "handheld" not in _CACHE:
        from spare_twin.cli import main

        out = tmp_path_factory.mktemp("handheld") / "rec"
        code = main(
            [
                "render",
                str(printed_object.root),
                "--out",
                str(out),
                "--path",
                "handheld",
                "--noise",
                "realsense_sr300",
                "--resolution",
                RESOLUTION,
                "--frames",
                str(FRAMES),
                "--seed",
                str(SEED),
            ]
        )
        assert code == 0
        _CACHE["handheld"] = out
    return _CACHE["handheld"]


@pytest.fixture(scope="session")
def registered_rec(handheld_rec, tmp_path_factory):
    """A copy of the hand-held recording after `spare-twin capture register` (fast settings)."""
    if "registered" not in _CACHE:
        import io
        from contextlib import redirect_stderr, redirect_stdout

        from spare_twin.cli import main

        out = tmp_path_factory.mktemp("registered") / "rec"
        shutil.copytree(handheld_rec, out)
        buf = io.StringIO()
        with redirect_stdout(buf), redirect_stderr(io.StringIO()):
            code = main(
                [
                    "capture",
                    "register",
                    str(out),
                    "--loop-gaps",
                    "3",
                    "--global-init",
                    "never",
                    "--voxel",
                    "0.006",
                    "--object",
                    "require",
                    "--json",
                ]
            )
        assert code == 0
        _CACHE["registered"] = (out, json.loads(buf.getvalue()))
    return _CACHE["registered"]


@pytest.fixture(scope="session")
def tiny_models(tmp_path_factory):
    """Two tiny count networks trained for one epoch on a tiny synthetic set: a geometry-aware voxel
    net (posed views) and the paper's Conv3D on depth images (canonical rig views)."""
    if "models" not in _CACHE:
        from spare_twin.dataset.synthetic import SyntheticSpec, write_synthetic
        from spare_twin.nets.presets import resolve
        from spare_twin.nets.train import train

        root = tmp_path_factory.mktemp("tiny")
        data = write_synthetic(root / "syn", SyntheticSpec(sizes=(("train", 12), ("val", 6), ("test", 6)), seed=5))
        cfg = {
            "net": {"channels": [4, 8], "fc_hidden": 16, "dropout": 0.0},
            "train": {"epochs": 1, "batch_size": 6, "samples_per_epoch": None, "val_samples": None, "threads": 1},
        }
        models = {}
        for name, preset in (("geo", "geo-depth-mv-count"), ("conv3d", "conv3d-depth-mv-count")):
            train(resolve(preset, cfg), data, root / name, progress=False)
            models[name] = root / name / "model.pt"
        _CACHE["models"] = models
    return _CACHE["models"]


def predict_json(rec, model, capsys, *extra):
    code, out, err = run_cli(["predict", str(rec), "--model", str(model), "--json", *extra], capsys)
    return code, (json.loads(out) if code == 0 else None), err
