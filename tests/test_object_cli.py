"""`spare-twin object` end to end in a temporary folder."""

import json
import shutil
import subprocess
import sys

import pytest
from conftest import run_cli


def _files(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def test_object_writes_everything_and_rebuilds_bit_for_bit(tmp_path, capsys):
    out = tmp_path / "obj"
    code, stdout, _ = run_cli(["object", "--links", "4", "--seed", "11", "--out", str(out), "--json"], capsys)
    assert code == 0
    summary = json.loads(stdout)
    assert summary["n_links"] == 4 and len(summary["link_lengths_pu"]) == 5
    names = set(summary["files"])
    assert {
        "object.json",
        "print_report.json",
        "ASSEMBLY.md",
        "preview.png",
        "clearance_coupon.stl",
        "spare_n4_s11.urdf",
    } <= names
    assert {f"link{k}.stl" for k in range(1, 5)} | {f"pin_joint{k}.stl" for k in range(1, 5)} | {
        "link0_base.stl",
        "foot.stl",
    } <= names
    meta = json.loads((out / "object.json").read_text())
    assert meta["n_links"] == 4 and len(meta["link_lengths_pu"]) == 5 and meta["print_scale"] == 0.08

    # Same seed again, and from the written object.json: byte-identical folders.
    again = tmp_path / "again"
    from_json = tmp_path / "from_json"
    assert run_cli(["object", "--links", "4", "--seed", "11", "--out", str(again)], capsys)[0] == 0
    assert run_cli(["object", "--config", str(out / "object.json"), "--out", str(from_json)], capsys)[0] == 0
    assert _files(out) == _files(again) == _files(from_json)


def test_preview_shows_the_object(tmp_path, capsys):
    import cv2
    import numpy as np

    out = tmp_path / "obj"
    assert run_cli(["object", "--links", "2", "--seed", "3", "--out", str(out)], capsys)[0] == 0
    img = cv2.imread(str(out / "preview.png"))
    assert img.shape == (600, 800, 3)
    # The links' colours are in the picture (not just background and table).
    spec = json.loads((out / "object.json").read_text())
    from spare_twin.config import COLORS

    for colour in set(spec["colors"]):
        rgb = np.array(COLORS[colour]) * 255
        dist = np.linalg.norm(img[:, :, ::-1].astype(float) - rgb, axis=2)
        assert (dist < 60).sum() > 200, colour


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--links", "0"], "--links: 0 is out of range"),
        (["--links", "7"], "--links: 7 is out of range"),
        (["--links", "2", "--clearance", "0.02"], "cannot print"),
        (["--links", "2", "--print-scale", "0.25"], "does not fit"),
        (["--links", "2", "--bed", "80x80"], "does not fit"),
        (["--links", "2", "--bed", "big"], "--bed"),
        (["--config", "missing.json"], "missing.json: no such file"),
        (["--links", "2", "--seed", "-1"], "--seed -1: must be a non-negative integer"),
        (["--links", "2", "--bed", "0x200"], "printer.bed_x_mm: 0.0 must be positive"),
    ],
)
def test_bad_input_is_one_line_and_keeps_existing_output(tmp_path, capsys, argv, message):
    out = tmp_path / "obj"
    out.mkdir()
    (out / "keep.txt").write_text("precious")
    argv = [a if a != "missing.json" else str(tmp_path / "missing.json") for a in argv]
    code, stdout, stderr = run_cli(["object", *argv, "--out", str(out)], capsys)
    assert code != 0
    assert message in stderr and stderr.count("\n") == 1 and "Traceback" not in stderr
    assert (out / "keep.txt").read_text() == "precious" and len(list(out.iterdir())) == 1


def test_bad_json_config_names_the_file(tmp_path, capsys):
    bad = tmp_path / "spec.json"
    bad.write_text('{"n_links": 2, "link_lengths_pu": [1.5, 0.5, 0.4], "colors": ["red", "mauve", "blue"]}')
    code, _, stderr = run_cli(["object", "--config", str(bad), "--out", str(tmp_path / "o")], capsys)
    assert code == 1 and "unknown colour 'mauve'" in stderr and str(bad) in stderr
    bad.write_text("{not json")
    code, _, stderr = run_cli(["object", "--config", str(bad), "--out", str(tmp_path / "o")], capsys)
    assert code == 1 and str(bad) in stderr and "not valid JSON" in stderr


def test_console_script_runs_as_a_process(tmp_path):
    exe = shutil.which("spare-twin") or str(__import__("pathlib").Path(sys.executable).parent / "spare-twin")
    res = subprocess.run([exe, "object", "--links", "9", "--out", str(tmp_path / "o")], capture_output=True, text=True)
    assert res.returncode == 1
    assert res.stderr.strip().splitlines()[-1].startswith("spare-twin object: error: ")
    assert "Traceback" not in res.stderr
    assert res.stdout == ""
