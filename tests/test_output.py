"""The output rule (spare_twin.output): what may be written over, write-beside-then-swap, clean-up after
killed runs, signals as interrupts, and one JSON object alone on stdout."""

import builtins
import hashlib
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from conftest import tree

from spare_twin import output, terminal
from spare_twin.errors import SpareTwinError
from spare_twin.output import MARKER, RRD, OutputKind, OutputRefused, check_output, clean_stale, writing

PY = sys.executable
REPO = Path(__file__).resolve().parents[1]


def temporaries(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if ".spare-twin-" in p.name)


def write_output(path, files: dict[str, str], command="render", **kw) -> None:
    with writing(path, command, **kw) as tmp:
        for name, text in files.items():
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp / name).write_text(text)


def dead_pid() -> int:
    p = subprocess.Popen([PY, "-c", "pass"])
    p.wait()
    return p.pid


def refused(path, kind="render", **kw) -> OutputRefused:
    with pytest.raises(OutputRefused) as info:
        check_output(path, kind, **kw)
    assert "\n" not in str(info.value) and str(path) in str(info.value)
    return info.value


# -- what may be written over ---------------------------------------------------------------------


def test_absent_empty_and_own_earlier_output_are_written(tmp_path):
    out = tmp_path / "a" / "b" / "rec"  # missing parents are made
    write_output(out, {"x.txt": "1"})
    assert (out / "x.txt").read_text() == "1"
    marker = {"command": "render", "format": output.MARKER_FORMAT, "files": ["x.txt"]}
    assert json.loads((out / MARKER).read_text()) == marker
    write_output(out, {"y.txt": "2"})  # an earlier render output: replaced whole
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "y.txt"]
    empty = tmp_path / "empty"
    empty.mkdir()
    write_output(empty, {"z.txt": "3"})
    assert (empty / "z.txt").read_text() == "3"
    assert temporaries(tmp_path) == [] and temporaries(out.parent) == []
    assert check_output(out, "render") == out


def test_foreign_folder_refused_and_force_replaces_it(tmp_path):
    mine = tmp_path / "mine"
    (mine / "sub").mkdir(parents=True)
    (mine / "notes.txt").write_text("my notes")
    (mine / "sub" / "data.bin").write_bytes(b"\0\1")
    before = tree(tmp_path)
    with pytest.raises(OutputRefused) as info:
        write_output(mine, {"x.txt": "1"}, command="object")
    err = info.value
    assert err.replaceable and str(err) == f"{mine}: is not empty and not an earlier object output; force replaces it"
    assert err.message("--force").endswith("; --force replaces it")
    assert tree(tmp_path) == before
    write_output(mine, {"x.txt": "1"}, command="object", force=True)
    assert sorted(p.name for p in mine.iterdir()) == [MARKER, "x.txt"]


def test_users_entries_are_carried_and_merged_into_the_new_output(tmp_path):
    out = tmp_path / "rec"
    write_output(out, {"a/x.txt": "1", "e/g.txt": "g"})
    (out / "a" / "mine.txt").write_text("m")  # inside a folder of the command's
    (out / "b").mkdir()  # a folder of the user's, which the next output has too: merged
    (out / "b" / "y.txt").write_text("y")
    write_output(out, {"a/x.txt": "2", "b/z.txt": "z"})
    assert {p: (out / p).read_text() for p in ("a/x.txt", "a/mine.txt", "b/y.txt", "b/z.txt")} == {
        "a/x.txt": "2",
        "a/mine.txt": "m",
        "b/y.txt": "y",
        "b/z.txt": "z",
    }
    assert not (out / "e").exists()  # the command's own, not written again
    assert json.loads((out / MARKER).read_text())["files"] == ["a", "a/x.txt", "b", "b/z.txt"]
    (out / "b" / "w.txt").mkdir()  # a folder of the user's where the next output writes a file
    before = tree(tmp_path)
    with pytest.raises(OutputRefused, match="holds b/w.txt, which render did not write there") as info:
        write_output(out, {"b/w.txt": "w"})
    assert info.value.replaceable and tree(tmp_path) == before and temporaries(tmp_path) == []
    (out / "b" / "w.txt").rmdir()
    (out / "a" / "mine.txt").rename(out / "a" / "sub")
    with pytest.raises(OutputRefused, match="holds a/sub"):  # where the new output has a file, not a folder
        write_output(out, {"a": "now a file"})
    write_output(out, {"a": "now a file"}, force=True)  # force: the new output wins, the rest is kept
    assert (out / "a").read_text() == "now a file" and (out / "b" / "y.txt").read_text() == "y"


def test_other_commands_output_and_files_are_refused(tmp_path):
    rec = tmp_path / "rec"
    write_output(rec, {"recording.json": "{}"}, command="capture import")
    err = refused(rec, "render")
    assert "an earlier capture import output, not a render one" in str(err) and err.replaceable
    write_output(rec, {"recording.json": "{}"}, command="render", force=True)
    f = tmp_path / "file.txt"
    f.write_text("keep")
    assert "is a file, not a folder" in str(refused(f))
    write_output(f, {"a": "b"}, force=True)
    assert f.is_dir()
    bad_marker = tmp_path / "bad"
    bad_marker.mkdir()
    (bad_marker / MARKER).write_text("not json")
    assert "not an earlier render output" in str(refused(bad_marker))


def test_file_outputs_recognised_by_magic(tmp_path):
    rrd = tmp_path / "view.rrd"
    with writing(rrd, RRD) as tmp:
        assert tmp.parent == tmp_path and not tmp.exists()
        tmp.write_bytes(b"RRF2 first")
    assert rrd.read_bytes() == b"RRF2 first" and temporaries(tmp_path) == []
    with writing(rrd, RRD) as tmp:  # an earlier .rrd: replaced
        tmp.write_bytes(b"RRF2 second")
    assert rrd.read_bytes() == b"RRF2 second"
    (tmp_path / "empty.rrd").touch()
    assert check_output(tmp_path / "empty.rrd", RRD) == tmp_path / "empty.rrd"
    notes = tmp_path / "notes.txt"
    notes.write_text("precious")
    assert "is not an earlier rerun output" in str(refused(notes, RRD))
    folder = tmp_path / "folder"
    folder.mkdir()
    for force in (False, True):  # a file never replaces a folder
        err = refused(folder, RRD, force=force)
        assert "is a folder" in str(err) and not err.replaceable
    with pytest.raises(SpareTwinError, match="nothing was written"), writing(tmp_path / "none.rrd", RRD):
        pass
    assert notes.read_text() == "precious" and temporaries(tmp_path) == []


def test_current_folder_inputs_and_places_never_allowed(tmp_path, monkeypatch):
    obj = tmp_path / "obj"
    obj.mkdir()
    (obj / "object.json").write_text("{}")
    monkeypatch.chdir(obj)
    for force in (False, True):
        assert "is the current folder" in str(refused(".", force=force))
        assert "around the current one" in str(refused("..", force=force))
        assert "is the input" in str(refused(obj, inputs=[obj], force=force))
        assert "lies inside the input" in str(refused(obj / "rec", inputs=[obj], force=force))
        assert "contains the input" in str(refused(tmp_path / "x", inputs=[tmp_path / "x" / "in"], force=force))
    monkeypatch.chdir(tmp_path)
    link = tmp_path / "alias"
    link.symlink_to(obj)
    assert "is the input" in str(refused(obj, inputs=[link]))  # the same folder by another name
    assert "symbolic link" in str(refused(link, force=True))
    assert "is the input" in str(refused("obj", inputs=["obj"]))
    assert check_output("rec", "render", inputs=[obj, None]) == tmp_path / "rec"
    with pytest.raises(OutputRefused, match="cannot be empty"):
        check_output("", "render")


def test_under_a_file_and_unwritable_places(tmp_path):
    f = tmp_path / "file.txt"
    f.write_text("x")
    err = refused(f / "rec" / "deeper")
    assert f"{f} is a file, not a folder" in str(err) and not err.replaceable
    # /proc/self takes no new folders, even from root: the error is one line naming the path
    with pytest.raises(SpareTwinError) as info, writing("/proc/self/spare-twin-out", "render"):
        pass
    assert "/proc/self/spare-twin-out" in str(info.value) and "\n" not in str(info.value)
    if os.geteuid() != 0:  # permissions do not stop root
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        try:
            assert "cannot write in" in str(refused(ro / "rec"))
        finally:
            ro.chmod(0o700)


# -- write beside, then swap -----------------------------------------------------------------------


@pytest.mark.parametrize("exc", [RuntimeError("boom"), KeyboardInterrupt(), SpareTwinError("bad input")])
def test_failure_leaves_old_output_whole_and_no_temporary(tmp_path, exc):
    out = tmp_path / "rec"
    write_output(out, {"old.txt": "old"})
    before = tree(tmp_path)
    with pytest.raises(type(exc)), writing(out, "render") as tmp:
        (tmp / "new.txt").write_text("new")
        raise exc
    assert tree(tmp_path) == before
    fresh = tmp_path / "p1" / "p2" / "rec"
    with pytest.raises(type(exc)), writing(fresh, "render"):
        raise exc
    assert tree(tmp_path) == before  # the parents it made are gone too


def test_force_replaces_only_when_complete(tmp_path):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    with pytest.raises(RuntimeError), writing(mine, "object", force=True) as tmp:
        (tmp / "part.stl").write_text("half")
        assert (mine / "notes.txt").read_text() == "mine"  # still there while the new one is written
        raise RuntimeError
    assert tree(mine) == {"notes.txt": hashlib.sha256(b"mine").hexdigest()}


def test_swap_without_atomic_exchange(tmp_path, monkeypatch):
    monkeypatch.setattr(output, "_rename_exchange", lambda a, b: False)
    out = tmp_path / "rec"
    write_output(out, {"a": "1"})
    write_output(out, {"b": "2"})
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "b"] and temporaries(tmp_path) == []


def test_interrupt_inside_the_swap_puts_the_old_output_back(tmp_path, monkeypatch):
    out = tmp_path / "rec"
    write_output(out, {"a": "1"})
    before = tree(tmp_path)
    real_rename = os.rename

    def rename(src, dst):  # Ctrl-C after the old output moved aside, before the new one came in
        real_rename(src, dst)
        if str(dst).endswith(".old"):
            raise KeyboardInterrupt

    monkeypatch.setattr(output, "_rename_exchange", lambda a, b: False)
    monkeypatch.setattr(output.os, "rename", rename)
    with pytest.raises(KeyboardInterrupt):
        write_output(out, {"b": "2"})
    monkeypatch.undo()
    assert tree(tmp_path) == before


def test_destination_changed_while_writing_is_kept(tmp_path):
    out = tmp_path / "rec"
    out.mkdir()
    with pytest.raises(OutputRefused), writing(out, "render") as tmp:
        (tmp / "a").write_text("1")
        (out / "user.txt").write_text("written meanwhile")
    assert tree(out) == {"user.txt": hashlib.sha256(b"written meanwhile").hexdigest()}
    assert temporaries(tmp_path) == []


def test_file_system_errors_are_one_line(tmp_path):
    with pytest.raises(SpareTwinError) as info, writing(tmp_path / "rec", "render") as tmp:
        (tmp / "no" / "such" / "dir.txt").write_text("x")
    assert "dir.txt" in str(info.value) and "No such file" in str(info.value)
    assert not isinstance(info.value, OutputRefused) and temporaries(tmp_path) == []


def test_nested_writes_of_one_path_are_refused(tmp_path):
    with pytest.raises(SpareTwinError, match="already being written"), writing(tmp_path / "r", "render"):
        with writing(tmp_path / "r", "render"):
            pass
    assert temporaries(tmp_path) == []


# -- resumable partial outputs and stale temporaries ----------------------------------------------


def test_resumable_partial_is_kept_and_adopted(tmp_path):
    out = tmp_path / "data"
    with pytest.raises(KeyboardInterrupt), writing(out, "dataset", resumable=True) as tmp:
        (tmp / "seq0").write_text("0")
        raise KeyboardInterrupt
    assert not out.exists() and temporaries(tmp_path) == [f".data.spare-twin-{output.process_token()}.partial"]
    # a killed run's partial (dead pid) is adopted by the next run
    os.rename(tmp_path / temporaries(tmp_path)[0], tmp_path / f".data.spare-twin-{dead_pid()}.partial")
    with writing(out, "dataset", resumable=True) as tmp:
        assert (tmp / "seq0").read_text() == "0"
        (tmp / "seq1").write_text("1")
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "seq0", "seq1"] and temporaries(tmp_path) == []
    with pytest.raises(RuntimeError), writing(out, "dataset", resumable=True) as tmp:
        raise RuntimeError  # a non-resumable run on the same path clears the partial
    write_output(out, {"x": "y"}, command="dataset")
    assert temporaries(tmp_path) == []


def test_resumable_run_extends_an_earlier_output(tmp_path):
    out = tmp_path / "data"
    with writing(out, "dataset", resumable=True) as tmp:
        (tmp / "seq0").write_text("0")
    with writing(out, "dataset", resumable=True) as tmp:
        assert sorted(p.name for p in tmp.iterdir()) == ["seq0"]  # the earlier output, less its marker
        assert (tmp / "seq0").stat().st_ino == (out / "seq0").stat().st_ino  # shared, not copied
        (tmp / "seq1").write_text("1")
        assert not (out / "seq1").exists()  # the earlier output stays as it was until the swap
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "seq0", "seq1"] and temporaries(tmp_path) == []
    with pytest.raises(OutputRefused):  # another command's output is never a starting point
        write_output(out, {"x": "1"}, command="render", resumable=True)


def test_clean_stale(tmp_path):
    out = tmp_path / "rec"
    write_output(out, {"new": "1"})
    dead = dead_pid()
    for state in ("tmp", "partial", "old"):
        (tmp_path / f".rec.spare-twin-{dead}.{state}").mkdir()
        (tmp_path / f".rec.spare-twin-{dead}.{state}" / "f").write_text(state)
    (tmp_path / f".other.spare-twin-{dead}.tmp").mkdir()  # another output's: not ours to remove
    (tmp_path / ".rec.abc.tmp").mkdir()  # no pid: never guessed at
    assert len(clean_stale(out, keep_partial=True)) == 2
    assert temporaries(tmp_path) == [f".other.spare-twin-{dead}.tmp", f".rec.spare-twin-{dead}.partial"]
    clean_stale(out)
    assert temporaries(tmp_path) == [f".other.spare-twin-{dead}.tmp"] and (tmp_path / ".rec.abc.tmp").is_dir()
    # a swap cut off between moving the old output aside and moving the new one in: the old comes back
    old, new = tmp_path / f".gone.spare-twin-{dead}.old", tmp_path / f".gone.spare-twin-{dead}.tmp"
    old.mkdir()
    (old / "keep").write_text("old")
    new.mkdir()
    clean_stale(tmp_path / "gone")
    assert (tmp_path / "gone" / "keep").read_text() == "old" and not new.exists()


def test_a_live_writer_is_respected(tmp_path):
    child = subprocess.Popen([PY, "-c", "import time; time.sleep(30)"])
    try:
        busy = tmp_path / f".rec.spare-twin-{child.pid}.tmp"
        busy.mkdir()
        assert clean_stale(tmp_path / "rec") == [] and busy.is_dir()
        assert f"pid {child.pid}" in str(refused(tmp_path / "rec"))
    finally:
        child.kill()
        child.wait()
    assert clean_stale(tmp_path / "rec") == [busy] and temporaries(tmp_path) == []


# -- killed writers (subprocesses) ----------------------------------------------------------------

WRITER = textwrap.dedent(
    """
    import sys, time
    from spare_twin.output import writing
    from spare_twin.terminal import signals_as_interrupts
    out, tag = sys.argv[1], sys.argv[2]
    with signals_as_interrupts(), writing(out, "render", force=True) as tmp:
        for i in range(400):
            (tmp / f"f{i:03d}.txt").write_text(tag * 50)
            if i == 5:
                print("writing", flush=True)
            time.sleep(0.005)
    """
)


def start_writer(out: Path, tag: str) -> subprocess.Popen:
    p = subprocess.Popen(
        [PY, "-c", WRITER, str(out), tag], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    assert p.stdout.readline() == "writing\n"
    return p


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_killed_writer_leaves_old_output_and_next_run_cleans_up(tmp_path, sig):
    out = tmp_path / "rec"
    write_output(out, {"old.txt": "old"})
    before = tree(tmp_path)
    p = start_writer(out, "a")
    time.sleep(0.1)
    p.send_signal(sig)
    _, err = p.communicate(timeout=30)
    if sig == signal.SIGTERM:  # a clean interrupt: the temporary went with it
        assert p.returncode != 0 and "KeyboardInterrupt" in err
        assert tree(tmp_path) == before
    else:
        assert p.returncode == -signal.SIGKILL
        [left] = temporaries(tmp_path)
        assert left.startswith(f".rec.spare-twin-{p.pid}-") and left.endswith(".tmp")
        assert {k: v for k, v in tree(tmp_path).items() if not k.startswith(".rec.")} == before
    p = start_writer(out, "b")  # the next run cleans up and completes
    p.communicate(timeout=60)
    assert p.returncode == 0 and temporaries(tmp_path) == []
    assert len(list(out.glob("f*.txt"))) == 400 and (out / "f399.txt").read_text() == "b" * 50


def test_signals_as_interrupts_restores_handlers():
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt), terminal.signals_as_interrupts():
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(1)
    assert signal.getsignal(signal.SIGTERM) is before
    old = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        with terminal.signals_as_interrupts():
            assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN  # nohup stays nohup
            os.kill(os.getpid(), signal.SIGHUP)
    finally:
        signal.signal(signal.SIGHUP, old)


def test_an_interrupt_during_an_import_lands_once_the_import_has_finished(tmp_path, monkeypatch):
    """A stop inside an `import` (an extension's initialisation, as torch's) is raised after the outermost
    import statement returns: the module imported whole, then KeyboardInterrupt; the import hook goes
    with the block."""
    (tmp_path / "slow_import_probe.py").write_text(
        "import os, signal, time\nos.kill(os.getpid(), signal.SIGTERM)\ntime.sleep(0.3)\nFINISHED = True\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    before = builtins.__import__
    with pytest.raises(KeyboardInterrupt, match="SIGTERM"), terminal.signals_as_interrupts():
        import slow_import_probe  # noqa: F401
    assert sys.modules.pop("slow_import_probe").FINISHED
    assert builtins.__import__ is before
    with pytest.raises(KeyboardInterrupt, match="SIGINT"), terminal.signals_as_interrupts():
        os.kill(os.getpid(), signal.SIGINT)  # outside an import: at once
        time.sleep(1)


# -- one JSON object on stdout --------------------------------------------------------------------

NOISY = textwrap.dedent(
    """
    import ctypes, os, sys
    from spare_twin.terminal import single_json_stdout
    libc = ctypes.CDLL(None)
    print("before", flush=True)
    with single_json_stdout(enabled=sys.argv[1] == "json") as out:
        libc.printf(b"[Open3D WARNING] Too few correspondences")  # no newline: sits in C's buffer
        os.write(1, b"b3Printf: raw fd write\\n")
        print("python print")
        out.emit({"n_links": 2})
    print("after")
    """
)


def test_single_json_stdout_keeps_c_level_output_off_stdout():
    p = subprocess.run([PY, "-c", NOISY, "json"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    assert p.stdout == 'before\n{"n_links": 2}\nafter\n'
    for noise in ("[Open3D WARNING] Too few correspondences", "b3Printf: raw fd write", "python print"):
        assert noise in p.stderr
    p = subprocess.run([PY, "-c", NOISY, "text"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert "b3Printf" in p.stdout and '{"n_links": 2}' in p.stdout


def test_single_json_stdout_in_process(capfd):
    with terminal.single_json_stdout() as out:
        os.write(1, b"noise\n")
        out.emit({"a": 1})
        with pytest.raises(RuntimeError):
            out.emit({"a": 2})
    got = capfd.readouterr()
    assert got.out == '{"a": 1}\n' and "noise" in got.err
    with pytest.raises(ValueError), terminal.single_json_stdout() as out:
        raise ValueError
    assert capfd.readouterr().out == ""


def test_single_json_stdout_takes_the_object_a_command_prints(capfd):
    """`--json` handlers print their object as they always have; everything else goes to stderr."""
    with terminal.single_json_stdout(catch_printed=True):
        print("library chatter")
        print('{"a": 0}')  # an object printed before the last one is not the command's answer
        os.write(1, b"c-level\n")
        print(json.dumps({"a": 1}))
    got = capfd.readouterr()
    assert got.out == '{"a": 1}\n'
    assert all(noise in got.err for noise in ("library chatter", '{"a": 0}', "c-level"))
    with pytest.raises(ValueError), terminal.single_json_stdout(catch_printed=True):
        print(json.dumps({"a": 1}))
        raise ValueError
    assert capfd.readouterr().out == ""


def test_kind_strings_and_objects_agree(tmp_path):
    write_output(tmp_path / "o", {"a": "1"}, command="object")
    assert check_output(tmp_path / "o", OutputKind("object")) == tmp_path / "o"
    assert output.output_command(tmp_path / "o") == "object" and output.output_command(tmp_path) is None
    assert not OutputKind("object").is_file and RRD.is_file
