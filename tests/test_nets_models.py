"""Every preset builds and gives the outputs its task promises; the voxel front end is geometric."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from spare_twin.nets.models import slots_to_count
from spare_twin.nets.presets import PRESETS, resolve
from spare_twin.nets.registry import build_model, decode

ROOT = Path(__file__).parents[1]


def _batch(net, B=2):
    V = net.frames
    Kv = 1 if net.mode == "tmp" else V
    K = torch.tensor([[125.0, 0, 63.5], [0, 125.0, 47.5], [0, 0, 1]]).expand(B, Kv, 3, 3)
    return {
        "x": torch.rand(B, V, net.height, net.width),
        "K": K,
        "T_world_camera": torch.eye(4).expand(B, Kv, 4, 4),
        "print_scale": torch.full((B,), 0.08),
    }


@pytest.mark.parametrize("name", [n for n in PRESETS if "tmp" not in n])
def test_presets_forward(name):
    torch.manual_seed(0)
    net = PRESETS[name].net
    model = build_model(net).eval()
    res = decode(model, net, _batch(net), true_n=torch.tensor([2, 5]))
    if net.task in ("count", "multitask") or net.arch == "naive":
        assert res["probabilities"].shape == (2, 6)
        assert torch.allclose(res["probabilities"].sum(1), torch.ones(2))
    if net.task == "lengths":
        assert res["lengths_known"].shape == (2, 7)
        assert (res["lengths_known"][0, 3:] == 0).all() and (res["lengths_known"][1, 6:] == 0).all()
    if net.task in ("e2e", "multitask"):
        n = res["pred_n"]
        assert res["lengths_e2e"].shape == (2, 7)
        for i in range(2):
            assert (res["lengths_e2e"][i, int(n[i]) + 1 :] == 0).all()


def test_every_paper_row_has_a_preset():
    rows = {p.paper_row for p in PRESETS.values() if p.paper_row}
    assert len(rows) == 10


def test_e2e_count_from_slots():
    L = torch.tensor(
        [[1.5, 0.4, 0.3, 0.01, 0.0, 0.0, 0.0], [1.5, 0.4, 0.3, 0.3, 0.3, 0.3, 0.3], [1.5, 0.0, 0.2, 0, 0, 0, 0]]
    )
    assert slots_to_count(L, 0.05).tolist() == [2, 6, 1]


def test_voxel_grid_puts_a_known_point_in_the_right_cell():
    from spare_twin.nets.geometry import voxelize
    from spare_twin.nets.presets import GridConfig

    # camera 1 m above the origin looking straight down (x right, y down = world -y, z forward = world -z)
    T = torch.tensor([[1.0, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 1.0], [0, 0, 0, 1]])
    K = torch.tensor([[100.0, 0, 64], [0, 100.0, 48], [0, 0, 1]])
    depth = torch.zeros(1, 1, 96, 128)
    depth[0, 0, 48, 64] = 0.84  # straight below the camera, world point (0, 0, 0.16)
    g = GridConfig()
    grid = voxelize(depth, K[None, None], T[None, None], torch.tensor([0.08]), g)
    z, y, x = np.unravel_index(int(grid.argmax()), grid.shape[2:])
    # paper units: (0, 0, 2.0) -> x cell 19 of 38 (edge), y cell 16 of 32 (edge), z cell 20 of 32
    assert (z, y) in {(19, 15), (19, 16), (20, 15), (20, 16)} and x in (18, 19)
    assert float(grid.sum()) > 0


def test_config_overrides_are_checked():
    from spare_twin.errors import SpareTwinError

    p = resolve("geo-depth-mv-count", {"net": {"channels": [8, 16]}, "train": {"epochs": 2}})
    assert p.net.channels == (8, 16) and p.train.epochs == 2
    with pytest.raises(SpareTwinError):
        resolve("geo-depth-mv-count", {"net": {"bogus": 1}})
    with pytest.raises(SpareTwinError):
        resolve("no-such-preset", None)


@pytest.mark.parametrize(
    "path",
    sorted((ROOT / "models" / "configs").rglob("*.json")),
    ids=lambda p: p.relative_to(p.parents[1]).as_posix(),
)
def test_every_shipped_training_configuration_resolves(path):
    """The recipes the model cards point at stay valid as the presets change."""
    config = json.loads(path.read_text())
    preset = resolve(None, config, str(path))
    init_from = preset.train.init_from
    # a fine-tuning stage starts from a shipped model or from the run of the stage before it
    assert init_from is None or (ROOT / init_from).is_file() or init_from.startswith("runs/"), init_from


def test_the_profile_networks_layer_histogram_says_where_the_plates_lie_wherever_they_are():
    from spare_twin.errors import SpareTwinError
    from spare_twin.nets.presets import NetConfig

    net = NetConfig("profile", "multitask", "depth", mode="profile", frames=3, height=64, width=80, layer_bins=31)
    model = build_model(net)

    def plates(first_row: int, first_col: int) -> torch.Tensor:
        """Five plates of 5 x 20 cells at layers 0..4 (mean t in channel 1), occupancy in channel 0."""
        x = torch.zeros(1, 3, 64, 80)
        for k in range(5):
            rows, cols = slice(first_row + 8 * k, first_row + 8 * k + 5), slice(first_col, first_col + 20)
            x[0, 0, rows, cols], x[0, 1, rows, cols] = 1.0, float(k)
        return x

    h = model.layer_histogram(plates(2, 5))[0]
    centres = model.layer_centres
    for k in range(5):
        assert float(h[centres == k]) == pytest.approx(0.2, abs=1e-3)  # each plate's share of the cells
    assert float(h[centres >= 5].sum()) < 1e-3 and float(h[centres <= -1].sum()) < 1e-3  # no sixth plate
    assert torch.allclose(model.layer_histogram(plates(20, 50)), model.layer_histogram(plates(2, 5)))
    with pytest.raises(SpareTwinError, match="layer_bins"):
        NetConfig("conv3d", "count", "depth", layer_bins=31)
    with pytest.raises(SpareTwinError, match="at least 2 bins"):
        NetConfig("profile", "multitask", "depth", mode="profile", frames=3, layer_bins=1)
