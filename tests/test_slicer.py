"""The printed parts slice in a real slicer: PrusaSlicer 2.5's command line with its default PLA settings."""

import shutil
import subprocess


def test_prusaslicer_slices_every_part(object_dirs, tmp_path):
    slicer = shutil.which("prusa-slicer")
    assert slicer, "prusa-slicer is installed by scripts/setup.sh"
    obj = object_dirs[6]
    for stl in sorted(obj.root.glob("*.stl")):
        gcode = tmp_path / f"{stl.stem}.gcode"
        res = subprocess.run(
            [slicer, "--export-gcode", "--output", str(gcode), str(stl)], capture_output=True, text=True, timeout=120
        )
        assert res.returncode == 0, f"{stl.name}: {res.stderr[-500:]}"
        text = gcode.read_text()
        used = [line for line in text.splitlines() if line.startswith("; filament used [cm3]")]
        assert used and float(used[0].split("=")[1]) > 0, stl.name


def test_shipped_profile_and_examples_slice(tmp_path):
    from conftest import REPO

    from spare_twin.config import ChainSpec
    from spare_twin.object.folder import build_object

    examples = sorted((REPO / "cad" / "examples").glob("*.json"))
    assert len(examples) >= 3
    objects = [build_object(ChainSpec.from_json_file(e), tmp_path / e.stem, preview=False) for e in examples]
    link = objects[0].root / "link1.stl"
    gcode = tmp_path / "profile.gcode"
    res = subprocess.run(
        [
            "prusa-slicer",
            "--load",
            str(REPO / "cad" / "prusaslicer_pla.ini"),
            "--export-gcode",
            "--output",
            str(gcode),
            str(link),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 0, res.stderr[-500:]
    settings = gcode.read_text()
    assert "; fill_density = 20%" in settings and "; support_material = 0" in settings
