"""`spare-twin bench training` times real training steps; channels-last changes speed, not results."""

import json

import pytest
import torch
from conftest import run_cli

from spare_twin.nets.presets import get_preset
from spare_twin.nets.registry import build_model
from spare_twin.nets.train import to_channels_last


@pytest.fixture(scope="module")
def small_data(tmp_path_factory):
    from spare_twin.dataset.build import generate_dataset
    from spare_twin.dataset.generate import GenConfig

    root = tmp_path_factory.mktemp("speed")
    generate_dataset(root, 6, seed=4, workers=1, cfg=GenConfig(frames=3), progress=False)
    return root


def test_bench_training_reports_every_preset_and_setting(small_data, capsys):
    argv = ["bench", "training", "--data", str(small_data), "--presets", "conv3d-depth-mv-count,lstm-grey-mv-count"]
    code, out, err = run_cli([*argv, "--settings", "1/0,1/0/cl", "--steps", "1", "--json"], capsys)
    assert code == 0, err
    res = json.loads(out)
    assert [p["preset"] for p in res["presets"]] == ["conv3d-depth-mv-count", "lstm-grey-mv-count"]
    for p in res["presets"]:
        first, cl = p["settings"]
        assert first["vs_first"] == 1.0 and first["samples_per_s"] > 0 and cl["channels_last"] is True
        assert cl["vs_first"] == pytest.approx(cl["samples_per_s"] / first["samples_per_s"], rel=0.01)
    assert "conv3d-depth-mv-count: 1 thr, 0 workers, channels-last:" in err  # progress goes to stderr


def test_bench_training_refuses_bad_settings(small_data, capsys):
    code, out, err = run_cli(["bench", "training", "--data", str(small_data), "--settings", "2-0"], capsys)
    assert code != 0 and "--settings" in err and "Traceback" not in err and out == ""


@pytest.mark.parametrize("name", ["conv3d-depth-mv-count", "lstm-grey-mv-count", "geo-grey-mv-multitask"])
def test_channels_last_gives_the_same_outputs(name):
    torch.manual_seed(0)
    net = get_preset(name).net
    a = build_model(net).eval()
    b = build_model(net).eval()
    b.load_state_dict(a.state_dict())
    b = to_channels_last(b)
    x = {
        "x": torch.rand(2, net.frames, net.height, net.width),
        "K": torch.tensor([[125.0, 0, 63.5], [0, 125.0, 47.5], [0, 0, 1]]).expand(2, net.frames, 3, 3),
        "T_world_camera": torch.eye(4).expand(2, net.frames, 4, 4).clone(),
        "print_scale": torch.full((2,), 0.08),
    }
    x["T_world_camera"][..., 2, 3] = -0.4  # the grid in front of the cameras
    with torch.no_grad():
        oa, ob = a(**x), b(**x)
    for k in oa:
        assert torch.allclose(oa[k], ob[k], atol=1e-4, rtol=1e-4), k
