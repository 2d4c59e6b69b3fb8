"""`spare-twin noise fit`: the depth-noise model fitted to the real frames in tests/data."""

import json

import pytest
from conftest import REPO, run_cli

from spare_twin.errors import SpareTwinError
from spare_twin.sim.noise import DepthNoise, fit_noise_models, load_noise


def sigma_at(model: DepthNoise, depth_m: float) -> float:
    return model.sigma0_m + model.sigma2_per_m * depth_m**2


def test_fit_reproduces_the_shipped_models(tmp_path, capsys):
    out = tmp_path / "noise"
    code, stdout, stderr = run_cli(["noise", "fit", "--out", str(out), "--json"], capsys)
    assert code == 0, stderr
    written = json.loads(stdout)["models"]
    assert sorted(p.name for p in out.glob("noise_*")) == ["noise_kinect_v1.json", "noise_realsense_sr300.json"]
    assert {m["model"]["sensor"] for m in written} == {"kinect_v1", "realsense_sr300"}

    # The Kinect pair in tests/data is the very pair the shipped Kinect model was fitted to.
    assert DepthNoise.from_json_file(out / "noise_kinect_v1.json") == load_noise("kinect_v1")
    fit = json.loads((out / "noise_kinect_v1.json").read_text())["fit"]
    assert fit["frames"] == 2 and fit["source"] == "data/tum_desk_pair"

    # 4 of the 50 SR300 frames the shipped model saw: the same sensor, measured again.
    mine, shipped = DepthNoise.from_json_file(out / "noise_realsense_sr300.json"), load_noise("realsense_sr300")
    assert mine.unit_m == shipped.unit_m == 0.001
    assert sigma_at(mine, 0.6) == pytest.approx(sigma_at(shipped, 0.6), rel=0.3)
    assert mine.edge_hole_prob == pytest.approx(shipped.edge_hole_prob, abs=0.1)
    assert mine.edge_band_px == pytest.approx(shipped.edge_band_px, rel=0.2)

    # An earlier fit may be replaced; a folder with anything else in it may not.
    assert run_cli(["noise", "fit", str(REPO / "tests/data/tum_desk_pair"), "--out", str(out)], capsys)[0] == 0
    assert sorted(p.name for p in out.iterdir() if p.name.endswith(".json")) == [
        ".spare-twin-output.json",
        "noise_kinect_v1.json",
    ]
    code, stdout, stderr = run_cli(["noise", "fit", "--out", str(tmp_path)], capsys)
    assert code == 1 and stderr.count("\n") == 1 and "not an earlier noise fit output; --force replaces it" in stderr
    assert (tmp_path / "noise").is_dir()


def test_bad_sources_are_one_line_errors_naming_them(tmp_path, capsys):
    code, _, stderr = run_cli(["noise", "fit", str(tmp_path / "nope"), "--out", str(tmp_path / "o")], capsys)
    assert code == 1 and "nope: no such folder" in stderr and stderr.count("\n") == 1
    assert not (tmp_path / "o").exists()
    (tmp_path / "empty").mkdir()
    code, _, stderr = run_cli(["noise", "fit", str(tmp_path / "empty"), "--out", str(tmp_path / "o")], capsys)
    assert code == 1 and "empty: no 7-Scenes" in stderr
    with pytest.raises(SpareTwinError, match="^sources: "):
        fit_noise_models(tmp_path / "o", [])
    with pytest.raises(SpareTwinError, match="lies inside the input"):
        fit_noise_models(REPO / "tests/data/tum_desk_pair/out", [REPO / "tests/data/tum_desk_pair"])
