"""One name per unit (issue 30, Deliver 2): paper-unit lengths are `link_lengths_pu` in every file and
output; object.json also keeps the key DESIGN.md's object-folder contract names (same values); files
from before 0.6.0, which name them only by that key, still read, and the first one says so once."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO, run_cli, stderr_lines

from spare_twin import config
from spare_twin.config import DESIGN_CONTRACT_LENGTHS_KEY, LENGTHS_KEY, ChainSpec, sample_chain, with_paper_lengths
from spare_twin.errors import SpareTwinError

OLD = "link_lengths_m"  # the key of 0.5.0 and earlier, spelled out: the constant must keep meaning it


def keys_anywhere(value) -> set[str]:
    """Every key of every JSON object nested in `value`."""
    if isinstance(value, dict):
        return set(value) | {k for v in value.values() for k in keys_anywhere(v)}
    if isinstance(value, list):
        return {k for v in value for k in keys_anywhere(v)}
    return set()


def old_json(path: Path, inside: str | None = None) -> None:
    """Rewrite `path` (or its object `inside`) as 0.5.0 wrote it: the lengths under the old key alone."""
    d = json.loads(path.read_text())
    t = d if inside is None else d[inside]
    t[OLD] = t.pop(LENGTHS_KEY)
    path.write_text(json.dumps(d, indent=2, sort_keys=True) + "\n")


def old_npz(path: Path) -> None:
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays[OLD] = arrays.pop(LENGTHS_KEY)
    np.savez_compressed(path, **arrays)


def notes(stderr: str) -> list[str]:
    return [ln for ln in stderr_lines(stderr) if "old key" in ln]


@pytest.fixture
def fresh_note(monkeypatch):
    """The once-per-process note not yet said in this (pytest's) process."""
    monkeypatch.setattr(config, "_old_key_said", False)


def test_the_contract_constant_is_the_old_key():
    assert DESIGN_CONTRACT_LENGTHS_KEY == OLD and LENGTHS_KEY == "link_lengths_pu"


def test_the_reader_renames_the_old_key_and_says_so_once(fresh_note, capsys):
    new = {"n_links": 1, LENGTHS_KEY: [1.5, 0.5]}
    assert with_paper_lengths(new, "a.json") == new and capsys.readouterr().err == ""
    old = {"n_links": 1, OLD: [1.5, 0.5]}
    assert with_paper_lengths(old, "old/object.json") == new
    assert with_paper_lengths({OLD: np.array([2.0])}, "old/ground_truth.npz")[LENGTHS_KEY].tolist() == [2.0]
    err = capsys.readouterr().err
    assert err == "note: old/object.json: old key link_lengths_m read as link_lengths_pu (paper units)\n"
    # both keys (object.json from 0.6.0 on): the new one is read, silently, the old one dropped
    assert with_paper_lengths({**new, OLD: [1.5, 0.5]}, "b.json") == new


def test_two_keys_that_disagree_are_refused_naming_the_file(fresh_note, capsys):
    with pytest.raises(SpareTwinError, match=r"^c\.json: link_lengths_m and link_lengths_pu differ"):
        with_paper_lengths({LENGTHS_KEY: [1.5, 0.5], OLD: [1.5, 0.6]}, "c.json")
    with pytest.raises(SpareTwinError, match="differ"):  # a value that is no list of numbers is compared too
        with_paper_lengths({LENGTHS_KEY: [1.5, 0.5], OLD: "long"}, "c.json")
    assert capsys.readouterr().err == ""


def test_an_old_configuration_reads_as_the_new(fresh_note, capsys):
    spec = sample_chain(3, seed=4)
    d = spec.to_dict()
    assert LENGTHS_KEY in d and OLD not in d
    d[OLD] = d.pop(LENGTHS_KEY)
    assert ChainSpec.from_dict(d, source="cfg.json") == spec
    assert notes(capsys.readouterr().err) == [
        "note: cfg.json: old key link_lengths_m read as link_lengths_pu (paper units)"
    ]


def test_object_writes_the_new_key_and_the_contracts(tmp_path, capsys):
    code, out, err = run_cli(["object", "--links", "2", "--seed", "3", "--out", str(tmp_path / "o"), "--no-preview",
                              "--json"], capsys)  # fmt: skip
    assert code == 0, err
    summary = json.loads(out)
    assert OLD not in summary and len(summary[LENGTHS_KEY]) == 3
    meta = json.loads((tmp_path / "o" / "object.json").read_text())
    # DESIGN.md: object.json has at least n_links, link_lengths_m (n + 1 paper-unit lengths) and print_scale
    assert meta[OLD] == meta[LENGTHS_KEY] == summary[LENGTHS_KEY] == list(sample_chain(2, seed=3).link_lengths_pu)
    assert meta["derived"]["link_lengths_mm"] == pytest.approx([v * 80 for v in meta[LENGTHS_KEY]])


def test_an_object_json_edited_under_one_key_only_is_refused(printed_object, tmp_path, capsys):
    obj = tmp_path / "obj"
    shutil.copytree(printed_object.root, obj)
    meta = json.loads((obj / "object.json").read_text())
    meta[OLD] = [v * 1.1 for v in meta[OLD]]
    (obj / "object.json").write_text(json.dumps(meta))
    code, _, err = run_cli(["render", str(obj), "--out", str(tmp_path / "rec"), "--frames", "1"], capsys)
    assert code == 1 and not (tmp_path / "rec").exists()
    assert stderr_lines(err) == [
        f"spare-twin render: error: {obj}/object.json: link_lengths_m and link_lengths_pu differ (the same "
        "paper-unit lengths under the old and the new name: edit link_lengths_pu and remove link_lengths_m)"
    ]


def spare_twin(*argv: str, cwd: Path) -> tuple[int, str, str]:
    """The command in a process of its own: the note is said once per process."""
    p = subprocess.run([sys.executable, "-m", "spare_twin", *argv], cwd=cwd, capture_output=True, text=True)
    return p.returncode, p.stdout, p.stderr


@pytest.mark.slow
def test_old_object_and_recording_still_render_predict_and_compare(printed_object, registered_rec, tmp_path):
    """A 0.5.0 object folder and registered recording (the lengths under the old key in object.json,
    recording.json and ground_truth.npz): `render`, `predict` and `compare` work on them, each saying
    so in one line, and what they write says `link_lengths_pu` only."""
    obj, real = tmp_path / "obj", tmp_path / "real"
    shutil.copytree(printed_object.root, obj)
    shutil.copytree(registered_rec[0], real)
    old_json(obj / "object.json")
    old_json(real / "recording.json", inside="object")
    old_npz(real / "ground_truth.npz")
    lengths_pu = list(printed_object.spec.link_lengths_pu)
    note = "note: obj/object.json: old key link_lengths_m read as link_lengths_pu (paper units)"

    code, _, err = spare_twin("render", "obj", "--out", "rec", "--frames", "2", "--resolution", "network", cwd=tmp_path)
    assert code == 0, err
    assert notes(err) == [note]  # object.json is read more than once: said once
    rec = json.loads((tmp_path / "rec" / "recording.json").read_text())
    assert rec["object"][LENGTHS_KEY] == lengths_pu and OLD not in keys_anywhere(rec)
    with np.load(tmp_path / "rec" / "ground_truth.npz") as gt:
        assert OLD not in gt.files and gt[LENGTHS_KEY].tolist() == lengths_pu

    code, out, err = spare_twin("predict", "real", "--json", cwd=tmp_path)
    assert code == 0, err
    answer = json.loads(out)
    assert answer["n_links"] == 2 and OLD not in keys_anywhere(answer)

    code, out, err = spare_twin("compare", "--object", "obj", "--real", "real", "--sim-out", "twin", "--json",
                                cwd=tmp_path)  # fmt: skip
    assert code == 0, err
    assert notes(err) == [note]  # and not again for the recording's ground truth
    result = json.loads(out)
    assert result["truth"]["n_links"] == 2 and result["truth"][LENGTHS_KEY] == lengths_pu
    assert OLD not in keys_anywhere(result)
    with np.load(tmp_path / "twin" / "ground_truth.npz") as gt:
        assert OLD not in gt.files and gt[LENGTHS_KEY].tolist() == lengths_pu


#: The files that may still name the old key: the reader and the object.json contract's constant, this
#: test, the history.
MAY_NAME_THE_OLD_KEY = {"spare_twin/config.py", "tests/test_length_keys.py", "CHANGELOG.md"}


def test_no_other_file_names_the_old_key():
    word = re.compile(r"\blink_lengths_m\b")
    found = set()
    for folder, subfolders, files in os.walk(REPO):
        # hidden folders (.git, .venv, caches) and the build's egg-info are no part of the project's text
        subfolders[:] = [d for d in subfolders if not d.startswith(".") and not d.endswith(".egg-info")]
        for name in files:
            path = Path(folder) / name
            if path.suffix in (".py", ".md", ".json") and word.search(path.read_text(errors="replace")):
                found.add(path.relative_to(REPO).as_posix())
    assert found <= MAY_NAME_THE_OLD_KEY, sorted(found - MAY_NAME_THE_OLD_KEY)
    config_lines = [ln for ln in (REPO / "spare_twin/config.py").read_text().splitlines() if word.search(ln)]
    assert [ln for ln in config_lines if not ln.startswith("#")] == [f'DESIGN_CONTRACT_LENGTHS_KEY = "{OLD}"']


def test_a_dataset_sequence_of_either_release_gives_its_label_in_paper_units(tmp_path):
    """Sequence files from 0.6.0 on store the 7-slot label as lengths_label_pu; older ones as
    lengths_label_m (paper units all the same): the one reader gives the label of either."""
    import h5py

    from spare_twin.dataset.store import LABEL_KEY, OLD_LABEL_KEY, lengths_label_pu

    label = np.array([1.5, 0.8, 0.7, 0, 0, 0, 0], np.float32)
    for key in (LABEL_KEY, OLD_LABEL_KEY):
        with h5py.File(tmp_path / f"{key}.h5", "w") as f:
            f.create_dataset(key, data=label)
        with h5py.File(tmp_path / f"{key}.h5", "r") as f:
            assert lengths_label_pu(f).tolist() == label.tolist()
    assert LABEL_KEY == "lengths_label_pu"


def test_a_new_sequence_file_names_the_label_in_paper_units(tmp_path):
    import h5py

    from spare_twin.cli import main

    assert main(["dataset", "--instances", "1", "--frames", "2", "--out", str(tmp_path / "d"), "--workers", "1"]) == 0
    (shard,) = sorted((tmp_path / "d").rglob("*.h5"))[:1]
    with h5py.File(shard, "r") as f:
        assert "lengths_label_pu" in f and "lengths_label_m" not in f
        assert f["lengths_label_pu"][: int(f.attrs["n_links"]) + 1].tolist() == pytest.approx(
            f["link_lengths_pu"][()].tolist(), abs=1e-6
        )
