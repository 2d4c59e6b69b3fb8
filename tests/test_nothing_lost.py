"""Issue 31, nothing lost: no command deletes what it did not write. In-place updates (`capture register`,
`compare` registering its real recording) keep every file, hidden file, link and empty folder they did
not make; re-running a command over its earlier output carries the user's additions into the new one
(and refuses, before anything is replaced, where it would write one of those paths itself); stale
locks and temporaries whose pid went to another process (a reboot) block nothing; long output names,
linked folders and file systems without atomic exchange or cross-folder renames (overlayfs) work.

Every CLI case runs end to end in a tmp folder; an error is one stderr line, no traceback, exit 1,
and every pre-existing entry stays byte-identical (links compared as links)."""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest
from capture_helpers import APC
from conftest import run_cli, tree

from spare_twin import output
from spare_twin.output import MARKER, process

BOOT = process._boot_id()


def add_users_things(root: Path, inside: str | None = None) -> dict[str, str]:
    """What a user adds to an output: a hidden file, a settings file, a dangling link to a folder, a link
    to a file, an empty folder, a folder of their own with a hidden file deep in it, and (`inside`) a
    hidden file in one of the command's folders. Returns their snapshot."""
    (root / ".notes.txt").write_text("notes\n")
    (root / "my_slicer_settings.ini").write_text("[slicer]\nlayer_height = 0.2\n")
    (root / "extras").symlink_to("../elsewhere")
    (root / "notes_link").symlink_to(".notes.txt")
    (root / "empty").mkdir()
    (root / "mine" / "deep").mkdir(parents=True)
    (root / "mine" / "deep" / ".hidden").write_bytes(b"\0\1\2")
    if inside:
        (root / inside / ".thumbs.db").write_bytes(b"thumbs")
    return {k: v for k, v in tree(root).items() if _users(k, inside)}


def _users(rel: str, inside: str | None) -> bool:
    top = rel.split("/")[0]
    return top in (".notes.txt", "my_slicer_settings.ini", "extras", "notes_link", "empty", "mine") or (
        inside is not None and rel == f"{inside}/.thumbs.db"
    )


def kept(root: Path, users: dict[str, str]) -> bool:
    now = tree(root)
    return all(now.get(k) == v for k, v in users.items())


def temporaries(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if ".spare-twin-" in p.name)


def one_line_error(code: int, err: str) -> str:
    assert code == 1, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


def listed(root: Path) -> list[str]:
    return json.loads((root / MARKER).read_text())["files"]


def import_apc(out: Path, capsys, *extra: str) -> None:
    code, _, err = run_cli(["capture", "import", str(APC), "--layout", "7scenes", "--out", str(out), *extra], capsys)
    assert code == 0, err


# -- in-place updates --------------------------------------------------------------------------------


def test_register_keeps_every_file_it_did_not_write(tmp_path, capsys):
    rec = tmp_path / "rec"
    import_apc(rec, capsys)
    users = add_users_things(rec, inside="cameras/cam0/color")
    code, _, err = run_cli(["capture", "register", str(rec), "--object", "skip"], capsys)
    assert code == 0, err
    assert kept(rec, users) and (rec / "fused.ply").is_file()
    assert (rec / "cameras/cam0/T_world_camera.reference.npy").is_file()
    files = listed(rec)  # the import's files and the registration's, nothing of the user's
    assert "fused.ply" in files and "cameras/cam0/color/000000.png" in files
    assert not any(_users(f, "cameras/cam0/color") for f in files)
    assert temporaries(tmp_path) == []

    (rec / "object.ply").write_text("my own scan")  # a registration without an object would remove it
    before = tree(tmp_path)
    err = one_line_error(*run_cli(["capture", "register", str(rec), "--object", "skip"], capsys)[::2])
    assert f"{rec}/object.ply: not written by spare-twin" in err and tree(tmp_path) == before


def test_compare_registers_its_real_recording_keeping_the_users_files(
    printed_object, handheld_rec, tmp_path, capsys, monkeypatch
):
    from spare_twin.compare import sim_vs_real
    from spare_twin.errors import SpareTwinError
    from spare_twin.recording import Recording

    real = tmp_path / "real"
    shutil.copytree(handheld_rec, real, symlinks=True)
    users = add_users_things(real, inside="cameras")

    def stop(*args, **kwargs):  # the fit and the twin after the registration are not what is tested
        raise SpareTwinError("stopped after the registration")

    monkeypatch.setattr(sim_vs_real, "object_cloud", stop)
    code, _, err = run_cli(["compare", "--object", str(printed_object.root), "--real", str(real)], capsys)
    assert "stopped after the registration" in one_line_error(code, err.splitlines()[-1] + "\n")
    assert Recording.open(real).registration is not None  # registered in place
    assert kept(real, users) and temporaries(tmp_path) == []


def test_register_of_the_current_folder_says_what_it_would_do(tmp_path, capsys, monkeypatch):
    rec = tmp_path / "rec"
    import_apc(rec, capsys)
    before = tree(tmp_path)
    monkeypatch.chdir(rec)
    err = one_line_error(*run_cli(["capture", "register", "."], capsys)[::2])
    assert "current folder" in err and "update in place" in err and "run this from outside it" in err
    assert "output" not in err and tree(tmp_path) == before


def test_linked_colour_folder_registers_and_a_linked_camera_folder_is_refused_by_name(tmp_path, capsys):
    rec = tmp_path / "rec"
    import_apc(rec, capsys)
    shutil.move(rec / "cameras/cam0/color", tmp_path / "colour_frames")
    (rec / "cameras/cam0/color").symlink_to("../../../colour_frames")
    code, _, err = run_cli(["capture", "register", str(rec), "--object", "skip"], capsys)
    assert code == 0, err
    assert os.readlink(rec / "cameras/cam0/color") == "../../../colour_frames" and (rec / "fused.ply").is_file()

    other = tmp_path / "other"
    import_apc(other, capsys)
    shutil.move(other / "cameras/cam0", tmp_path / "cam0")
    (other / "cameras/cam0").symlink_to("../../cam0")
    before = tree(tmp_path)
    err = one_line_error(*run_cli(["capture", "register", str(other)], capsys)[::2])
    assert f"{other}/cameras/cam0: is a symbolic link" in err and ".spare-twin-" not in err
    assert tree(tmp_path) == before


# -- replacing an earlier output of the same command -------------------------------------------------


def test_object_rerun_keeps_the_users_files_and_refuses_to_overwrite_one(tmp_path, capsys):
    obj = tmp_path / "obj"
    argv = ["object", "--links", "2", "--seed", "1", "--out", str(obj)]
    assert run_cli([*argv, "--no-preview"], capsys)[0] == 0
    first = tree(obj)
    users = add_users_things(obj)
    code, _, err = run_cli([*argv, "--no-preview"], capsys)
    assert code == 0, err
    assert kept(obj, users) and {k: v for k, v in tree(obj).items() if not _users(k, None)} == first

    (obj / "preview.png").write_bytes(b"my own photo")  # a path the next run writes itself
    before = tree(tmp_path)
    err = one_line_error(*run_cli(argv, capsys)[::2])
    assert "holds preview.png" in err and "--force replaces it" in err
    assert tree(tmp_path) == before  # refused before anything was replaced
    code, _, err = run_cli([*argv, "--force"], capsys)
    assert code == 0, err
    assert (obj / "preview.png").read_bytes()[:4] == b"\x89PNG" and kept(obj, users)
    assert temporaries(tmp_path) == []


def test_render_rerun_keeps_the_users_files_and_none_of_its_old_frames(printed_object, tmp_path, capsys):
    rec = tmp_path / "rec"
    argv = ["render", str(printed_object.root), "--out", str(rec), "--path", "handheld", "--resolution", "80x60"]
    assert run_cli([*argv, "--frames", "4"], capsys)[0] == 0
    [cam] = [p.name for p in (rec / "cameras").iterdir()]
    users = add_users_things(rec, inside=f"cameras/{cam}/color")
    code, _, err = run_cli([*argv, "--frames", "2"], capsys)
    assert code == 0, err
    assert kept(rec, users)
    assert sorted(p.name for p in (rec / "cameras" / cam / "color").glob("*.png")) == ["000000.png", "000001.png"]
    assert temporaries(tmp_path) == []


def test_capture_import_rerun_keeps_the_users_files_and_none_of_the_registration(tmp_path, capsys):
    rec = tmp_path / "rec"
    import_apc(rec, capsys)
    assert run_cli(["capture", "register", str(rec), "--object", "skip"], capsys)[0] == 0
    users = add_users_things(rec, inside="cameras/cam0/depth")
    import_apc(rec, capsys, "--max-frames", "2")
    assert kept(rec, users)
    assert not (rec / "fused.ply").exists()  # the registration of the earlier frames was spare-twin's
    assert sorted(p.name for p in (rec / "cameras/cam0/color").iterdir()) == ["000000.png", "000001.png"]


def test_an_older_marker_is_replaced_only_where_nothing_would_be_dropped(tmp_path, capsys):
    rec = tmp_path / "rec"
    import_apc(rec, capsys)

    def older_marker():  # as spare-twin wrote it before markers listed files
        (rec / MARKER).write_text(json.dumps({"command": "capture import", "format": "spare-twin-output/1"}))

    older_marker()
    import_apc(rec, capsys)  # writes every path the earlier one holds
    assert "files" in json.loads((rec / MARKER).read_text())
    older_marker()
    (rec / "my_notes.txt").write_text("mine")
    before = tree(tmp_path)
    argv = ["capture", "import", str(APC), "--layout", "7scenes", "--out", str(rec), "--json"]
    err = one_line_error(*run_cli(argv, capsys)[::2])
    assert "older spare-twin" in err and "my_notes.txt" in err and "--force replaces it" in err
    assert tree(tmp_path) == before
    (rec / "my_notes.txt").unlink()
    before = tree(tmp_path)
    argv += ["--max-frames", "2"]
    err = one_line_error(*run_cli(argv, capsys)[::2])  # old frames would be mixed in, or guessed at
    assert "000002.png" in err and tree(tmp_path) == before
    assert run_cli([*argv, "--force"], capsys)[0] == 0
    assert len(list((rec / "cameras/cam0/color").iterdir())) == 2


def test_resumable_run_extends_an_earlier_output_keeping_the_users_files(tmp_path):
    out = tmp_path / "data"
    with output.writing(out, "dataset", resumable=True) as tmp:
        (tmp / "seq0").write_text("0")
    users = add_users_things(out)
    with output.writing(out, "dataset", resumable=True) as tmp:
        assert sorted(p.name for p in tmp.iterdir()) == ["seq0"]  # started from its own files
        (tmp / "seq1").write_text("1")
    assert kept(out, users) and (out / "seq0").read_text() == "0" and (out / "seq1").read_text() == "1"
    assert listed(out) == ["seq0", "seq1"]


# -- locks and temporaries of a pid that another process has now -------------------------------------


@pytest.fixture
def sleeper():
    p = subprocess.Popen(["sleep", "60"])
    yield p
    p.kill()
    p.wait()


def forge_tmp(parent: Path, name: str, owner: str, mtime_s: float | None = None) -> Path:
    t = parent / f".{name}.spare-twin-{owner}.tmp"
    t.mkdir()
    (t / "half.stl").write_text("half")
    if mtime_s is not None:
        os.utime(t, (mtime_s, mtime_s))
    return t


def test_a_temporary_of_a_pid_now_anothers_blocks_nothing(tmp_path, capsys, sleeper):
    obj = tmp_path / "obj"
    argv = ["object", "--links", "2", "--seed", "1", "--out", str(obj), "--no-preview"]
    ticks = process._start_ticks(sleeper.pid)
    # the sleeper's pid and pid 1, each with another start time: written by processes that are gone
    forge_tmp(tmp_path, "obj", f"{sleeper.pid}-{ticks + 1}-{BOOT}")
    forge_tmp(tmp_path, "obj", f"1-{process._start_ticks(1) + 7}-{BOOT}")
    forge_tmp(tmp_path, "obj", f"{sleeper.pid}-{ticks}-{'0' * 8}")  # its very start time, but another boot
    forge_tmp(tmp_path, "obj", "1", mtime_s=1.0)  # an older temporary: written before pid 1 started
    code, _, err = run_cli(argv, capsys)
    assert code == 0, err
    assert temporaries(tmp_path) == []

    alive = forge_tmp(tmp_path, "obj", f"{sleeper.pid}-{ticks}-{BOOT}")  # the very process: still writing
    for extra in ([], ["--force"]):
        err = one_line_error(*run_cli([*argv, *extra], capsys)[::2])
        assert f"another spare-twin process (pid {sleeper.pid}) is writing it" in err
    alive.rename(tmp_path / f".obj.spare-twin-{sleeper.pid}.tmp")  # older kind, written after it started
    assert f"pid {sleeper.pid}" in one_line_error(*run_cli(argv, capsys)[::2])


def test_a_dataset_lock_of_a_pid_now_anothers_blocks_nothing(tmp_path, capsys, sleeper):
    data = tmp_path / "data"
    argv = ["dataset", "--out", str(data), "--frames", "2", "--instances"]
    assert run_cli([*argv, "1"], capsys)[0] == 0
    lock = data / ".lock"
    ticks = process._start_ticks(sleeper.pid)
    lock.write_text(f"{sleeper.pid}-{ticks}-{BOOT}")  # a live writer
    err = one_line_error(*run_cli([*argv, "2"], capsys)[::2])
    assert f"pid {sleeper.pid}" in err and lock.read_text() == f"{sleeper.pid}-{ticks}-{BOOT}"
    lock.write_text("my notes")  # a file of the user's under the lock's name is neither taken nor deleted
    err = one_line_error(*run_cli([*argv, "2"], capsys)[::2])
    assert "not a spare-twin lock" in err and lock.read_text() == "my notes"
    lock.write_text(f"{sleeper.pid}-{ticks + 1}-{BOOT}")  # the pid went to another process
    code, out, err = run_cli([*argv, "2"], capsys)
    assert code == 0 and "1 new" in out, err
    lock.write_text("1")  # an older lock, written before pid 1 started: after a reboot
    os.utime(lock, (1.0, 1.0))
    code, _, err = run_cli([*argv, "3"], capsys)
    assert code == 0 and not lock.exists(), err
    lock.write_text("")  # a run killed as it wrote its lock
    code, _, err = run_cli([*argv, "4"], capsys)
    assert code == 0 and not lock.exists(), err


# -- names and file systems ----------------------------------------------------------------------------


def test_a_long_output_name_fits_its_temporaries(tmp_path, capsys):
    name = "o" * 240
    obj = tmp_path / name
    argv = ["object", "--links", "2", "--seed", "1", "--out", str(obj), "--no-preview"]
    assert run_cli(argv, capsys)[0] == 0
    users = add_users_things(obj)
    code, _, err = run_cli(argv, capsys)
    assert code == 0, err
    assert kept(obj, users) and temporaries(tmp_path) == []
    for long in (tmp_path / ("é" * 127), obj):  # 254 bytes of two-byte characters, and the 240 above
        for state in ("tmp", "partial", "old", "away"):
            t = output._temporary(long, state, owner="4194304-99999999999999-ffffffff")
            assert len(os.fsencode(t.name)) <= 255
            t.mkdir()
            assert [p for p, _, _ in output._temporaries(long)] == [t]  # still known as the output's
            assert output.clean_stale(long) == [t]  # its process is gone


def test_no_atomic_exchange_no_rename_no_hard_links(tmp_path, capsys, monkeypatch):
    """overlayfs answers EXDEV to renameat2(RENAME_EXCHANGE), to renaming a folder of a lower layer and
    to hard links across layers: the swap falls back to rename aside, then to copies."""
    obj = tmp_path / "obj"
    argv = ["object", "--links", "2", "--seed", "1", "--out", str(obj), "--no-preview"]
    assert run_cli(argv, capsys)[0] == 0
    users = add_users_things(obj)
    real_rename = os.rename

    def rename(src, dst, *a, **kw):
        if Path(src) == obj:
            raise OSError(errno.EXDEV, os.strerror(errno.EXDEV), str(src))
        return real_rename(src, dst, *a, **kw)

    def link(src, dst, *a, **kw):
        raise OSError(errno.EXDEV, os.strerror(errno.EXDEV), str(src))

    monkeypatch.setattr(output, "_exchange", lambda a, b: errno.EXDEV)
    monkeypatch.setattr(os, "rename", rename)
    monkeypatch.setattr(os, "link", link)
    code, _, err = run_cli(argv, capsys)
    assert code == 0, err
    assert kept(obj, users) and (obj / "object.json").is_file() and temporaries(tmp_path) == []


def test_a_swap_by_copies_cut_short_puts_the_old_output_back(tmp_path, monkeypatch):
    out = tmp_path / "rec"
    with output.writing(out, "render") as tmp:
        (tmp / "old.txt").write_text("old")
    users = add_users_things(out)
    before = tree(tmp_path)
    real_rename, interrupted = os.rename, []

    def rename(src, dst, *a, **kw):
        if Path(src) == out:
            raise OSError(errno.EXDEV, os.strerror(errno.EXDEV), str(src))
        if Path(dst) == out and not interrupted:  # Ctrl-C after the old output was deleted, before the new came
            interrupted.append(src)
            raise KeyboardInterrupt
        return real_rename(src, dst, *a, **kw)

    monkeypatch.setattr(output, "_exchange", lambda a, b: errno.EXDEV)
    monkeypatch.setattr(os, "rename", rename)
    with pytest.raises(KeyboardInterrupt), output.writing(out, "render") as tmp:
        (tmp / "new.txt").write_text("new")
    monkeypatch.undo()
    assert interrupted and tree(tmp_path) == before and kept(out, users)

    # the same cut by SIGKILL: the copy and the new output are left; the next run puts the copy back
    dead = "999999999-1-00000000"
    away, new = output._temporary(out, "away", dead), output._temporary(out, "tmp", dead)
    shutil.copytree(out, away, symlinks=True)
    shutil.copytree(out, new, symlinks=True)
    (new / "new.txt").write_text("new")
    (out / "old.txt").unlink()  # half deleted
    output.clean_stale(out)
    assert tree(tmp_path) == before


def test_an_empty_output_path_is_said_to_be_empty(printed_object, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for argv in (["object", "--links", "2"], ["render", str(printed_object.root)], ["dataset", "--instances", "1"]):
        err = one_line_error(*run_cli([*argv, "--out", ""], capsys)[::2])
        assert "--out '': an output path cannot be empty" in err and "current folder" not in err
    assert list(tmp_path.iterdir()) == []
