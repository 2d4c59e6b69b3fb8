"""Fixtures shared by the test modules. Session-scoped: the expensive ones (a training run, a
registered hand-held capture, tiny checkpoints) are made once per test run, and once for all of
pytest-xdist's workers (`built_once`)."""

# ruff: noqa: E402  (the threads are set before the imports below load numpy or torch)
import os

# Before anything loads numpy or torch: each pytest-xdist worker gets its share of the cores for OpenMP
# (torch, and `spare_twin.threads`), and one BLAS thread (`spare_twin/__init__.py` says why). With two
# workers each running threads for every core, the suite's tests took 16 % longer on this 2-core machine
# (1,305 s of test time against 1,123 s).
if "PYTEST_XDIST_WORKER_COUNT" in os.environ and "OMP_NUM_THREADS" not in os.environ:
    _share = len(os.sched_getaffinity(0)) // int(os.environ["PYTEST_XDIST_WORKER_COUNT"])
    os.environ["OMP_NUM_THREADS"] = str(max(_share, 1))
import hashlib
import json
import pickle
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from filelock import FileLock

import spare_twin  # noqa: F401  (sets the BLAS threads, before anything loads numpy)

REPO = Path(__file__).resolve().parents[1]

# A terminal starts a command with SIGINT at its default; a test run started in the background (`cmd &`
# in a script, `nohup`) ignores it, and every process it starts inherits that, so the Ctrl-C tests would
# see no interrupt (exit 0 where 130 is asked) and the commands would be right to ignore it
# (`terminal.signals_as_interrupts` keeps an ignored signal ignored). Caught here, it raises
# KeyboardInterrupt in this process and is at its default in every process the tests start (exec resets
# a caught signal), as under a terminal.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

#: The files that take half a minute or more, slowest first (seconds summed over their tests at release
#: 0.6.15, on the 2-core machine: 99, 94, 83, 74, 69, 68, 63, 53, 51, 38, 37, 35, 33, 30). pytest-xdist
#: hands whole files out in collection order (`--no-loadscope-reorder`); its own order puts files with
#: few tests last, so a slow one ran at the end on one worker while the other stood idle.
SLOWEST_FILES = (
    "test_interrupt.py",
    "test_nets_train.py",
    "test_profile_net.py",
    "test_readme.py",
    "test_demo.py",
    "test_live.py",
    "test_grey_lift.py",
    "test_bad_input.py",
    "test_scale_out.py",
    "test_abstain.py",
    "test_articulated.py",
    "test_observe.py",
    "test_train_distributed.py",
    "test_length_keys.py",
)


def pytest_collection_modifyitems(items):
    """The slowest files first, the rest in their usual order (the sort is stable)."""
    rank = {name: i for i, name in enumerate(SLOWEST_FILES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


#: The simulated hand-held capture of `handheld_rec`: frames, resolution and seed.
FRAMES, RESOLUTION, SEED = 12, "320x240", 1

#: A small geometry-aware multitask net: learns the count of synthetic chains in a few epochs on a CPU.
TINY = {
    "preset": "geo-depth-mv-multitask",
    "net": {"channels": [8, 16, 32], "fc_hidden": 64, "dropout": 0.0, "predict_angles": False},
    "train": {
        "epochs": 5,
        "batch_size": 16,
        "lr": 3e-3,
        "samples_per_epoch": None,
        "val_samples": None,
        "length_weight": 1.0,
        "threads": 1,
    },
}


def tree(root: Path) -> dict[str, str]:
    """Every path under root, hidden ones included, links not followed -> a hash of its content ("dir"
    for a folder, "link:TARGET" for a link): compare two to see what a command added, removed or changed."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            p = Path(dirpath) / name
            rel = p.relative_to(root).as_posix()
            if p.is_symlink():
                out[rel] = "link:" + os.readlink(p)
            elif p.is_dir():
                out[rel] = "dir"
            else:
                out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def stderr_lines(stderr: str) -> list[str]:
    """The lines a person sees: a progress bar redraws its line with carriage returns."""
    return [ln.split("\r")[-1] for ln in stderr.split("\n") if ln.split("\r")[-1].strip()]


def interrupt_pool(argv: list[str], cwd: Path, env: dict | None = None, workers_wanted: int = 2) -> tuple[int, str]:
    """Run `argv`, send SIGINT to its whole process group (a terminal's Ctrl-C) once its pool of
    `workers_wanted` spawned workers is up, and return (exit code, stderr) after checking that no
    worker outlived it."""
    import time

    def children(pid: int) -> list[int]:
        return [int(c) for task in Path(f"/proc/{pid}/task").iterdir() for c in (task / "children").read_text().split()]

    proc = subprocess.Popen(
        argv, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 120
        workers: list[int] = []
        while time.monotonic() < deadline and proc.poll() is None:
            # the pool's workers are spawned python processes (a resource tracker is one child more)
            workers = [c for c in children(proc.pid) if b"spawn_main" in Path(f"/proc/{c}/cmdline").read_bytes()]
            if len(workers) == workers_wanted:
                break
            time.sleep(0.1)
        assert len(workers) == workers_wanted, f"the pool of {workers_wanted} never started"
        time.sleep(0.5)  # the workers are importing or working: either way they must stay quiet
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    for pid in workers:
        for _ in range(50):
            if not Path(f"/proc/{pid}").exists() or "Z" in Path(f"/proc/{pid}/stat").read_text().split()[2]:
                break
            time.sleep(0.1)
        else:
            pytest.fail(f"worker {pid} outlived the interrupted run")
    return proc.returncode, err


def built_once(tmp_path_factory, name: str, build):
    """`build(empty_dir)`'s value, built by one process of the run: under pytest-xdist (the suite's
    default, `-n logical`) the first worker that asks builds it in the run's shared temporary folder
    while the others wait on a lock and read its pickled value. Built files are read, never changed,
    by the tests."""
    if os.environ.get("PYTEST_XDIST_WORKER") is None:
        return build(tmp_path_factory.mktemp(name))
    shared = tmp_path_factory.getbasetemp().parent / "built-once"
    shared.mkdir(exist_ok=True)
    value_file = shared / f"{name}.pickle"
    with FileLock(str(shared / f"{name}.lock")):
        if value_file.exists():
            return pickle.loads(value_file.read_bytes())
        folder = shared / name
        shutil.rmtree(folder, ignore_errors=True)  # a build that failed in another worker
        folder.mkdir()
        value = build(folder)
        value_file.write_bytes(pickle.dumps(value))
        return value


def run_cli(argv, capsys):
    """Run `spare-twin ARGV` in-process; returns (exit code, stdout, stderr)."""
    from spare_twin.cli import main

    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def refused_before_torch(cases: list[tuple[list[str], tuple[str, ...]]], cwd: Path) -> None:
    """Each `spare-twin ARGV` of `cases`, run by `spare_twin.cli.main` one after another in one new Python
    process in `cwd`, is refused before torch is imported (3-5 s of a new process): exit code 1, one line
    on stderr naming each of its words, no traceback; and nothing in `cwd` added, removed or changed.
    One process for all of a command's cases, since a new one costs a second of the suite's time each."""
    marker = "@@ next case @@"
    probe = (
        "import json, sys\nfrom spare_twin.cli import main\nresults = []\n"
        f"for argv in {[argv for argv, _ in cases]!r}:\n"
        f"    print({marker!r}, file=sys.stderr, flush=True)\n"
        "    results.append([main(argv), 'torch' in sys.modules])\n"
        "print(json.dumps(results))\n"
    )
    before = tree(cwd)
    res = subprocess.run([sys.executable, "-c", probe], cwd=cwd, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    results = json.loads(res.stdout.strip().splitlines()[-1])
    stderrs = res.stderr.split(marker + "\n")[1:]
    assert len(results) == len(stderrs) == len(cases), (res.stdout, res.stderr)
    for (argv, words), (code, torch_loaded), stderr in zip(cases, results, stderrs):
        assert (code, torch_loaded) == (1, False), (argv, code, torch_loaded, stderr)
        lines = stderr_lines(stderr)
        assert len(lines) == 1 and "Traceback" not in stderr, (argv, stderr)
        assert all(w in lines[0] for w in words), (argv, lines[0])
    assert tree(cwd) == before


def predict_json(rec, model, capsys, *extra):
    """`spare-twin predict REC --model MODEL --json`: (exit code, parsed JSON or None, stderr)."""
    code, out, err = run_cli(["predict", str(rec), "--model", str(model), "--json", *extra], capsys)
    return code, (json.loads(out) if code == 0 else None), err


@pytest.fixture(scope="session")
def object_dirs(tmp_path_factory):
    """Built object folders for n = 1..6 (one seed each), shared by the geometry and URDF tests."""
    from spare_twin.config import sample_chain
    from spare_twin.object.folder import build_object

    def build(root):
        return {n: build_object(sample_chain(n, seed=100 + n), root / f"n{n}", preview=(n == 3)) for n in range(1, 7)}

    return built_once(tmp_path_factory, "objects", build)


@pytest.fixture(scope="session")
def synthetic_data(tmp_path_factory):
    """An easy synthetic multi-view set (192 / 64 / 64 samples)."""
    from spare_twin.dataset.synthetic import SyntheticSpec, write_synthetic

    spec = SyntheticSpec(sizes=(("train", 192), ("val", 64), ("test", 64)), seed=5)
    return built_once(tmp_path_factory, "syn", lambda root: write_synthetic(root, spec))


@pytest.fixture(scope="session")
def trained(synthetic_data, tmp_path_factory):
    """One CLI training run of TINY on `synthetic_data`, shared by the training and predict tests."""
    from spare_twin.cli import main

    def build(root):
        cfg = root / "cfg.json"
        cfg.write_text(json.dumps(TINY))
        argv = ["train", "--config", str(cfg), "--data", str(synthetic_data), "--out", str(root / "run")]
        assert main([*argv, "--seed", "3"]) == 0
        return root / "run"

    return built_once(tmp_path_factory, "run", build)


@pytest.fixture(scope="session")
def printed_object(tmp_path_factory):
    """A 2-link object (the one the simulated sensor records)."""
    from spare_twin.config import sample_chain
    from spare_twin.object.folder import build_object

    return built_once(
        tmp_path_factory, "printed", lambda root: build_object(sample_chain(2, seed=7), root / "obj", preview=False)
    )


def _render(printed_object, tmp_path_factory, name: str, *flags: str) -> Path:
    """`spare-twin render` of `printed_object` into a recording built once for the run."""
    from spare_twin.cli import main

    def build(root):
        assert main(["render", str(printed_object.root), "--out", str(root / "rec"), *flags]) == 0
        return root / "rec"

    return built_once(tmp_path_factory, name, build)


@pytest.fixture(scope="session")
def handheld_rec(printed_object, tmp_path_factory):
    """`spare-twin render --path handheld --noise realsense_sr300`: FRAMES frames at RESOLUTION."""
    flags = ("--path", "handheld", "--noise", "realsense_sr300", "--resolution", RESOLUTION)
    return _render(printed_object, tmp_path_factory, "handheld", *flags, "--frames", str(FRAMES), "--seed", str(SEED))


@pytest.fixture(scope="session")
def sweep(printed_object, tmp_path_factory):
    """A hand-held sweep with its poses hidden, 16 frames at 320 x 240 (a sensor's stream): what `live`
    replays and `predict` must register itself."""
    flags = ("--path", "handheld", "--hide-poses", "--frames", "16", "--resolution", "320x240")
    return _render(printed_object, tmp_path_factory, "sweep", *flags, "--noise", "realsense_sr300", "--seed", "2")


@pytest.fixture(scope="session")
def registered_rec(handheld_rec, tmp_path_factory):
    """A copy of the hand-held recording after `spare-twin capture register` (fast settings), and its JSON."""
    import io
    from contextlib import redirect_stderr, redirect_stdout

    from spare_twin.cli import main

    def build(root):
        out = root / "rec"
        shutil.copytree(handheld_rec, out)
        buf = io.StringIO()
        argv = ["capture", "register", str(out), "--loop-gaps", "3", "--global-init", "never", "--voxel", "0.006"]
        with redirect_stdout(buf), redirect_stderr(io.StringIO()):
            assert main([*argv, "--object", "require", "--json"]) == 0
        return out, json.loads(buf.getvalue())

    return built_once(tmp_path_factory, "registered", build)


@pytest.fixture(scope="session")
def tiny_models(tmp_path_factory):
    """Two tiny count networks trained for one epoch on a tiny synthetic set: a geometry-aware voxel
    net (posed views) and the paper's Conv3D on depth images (canonical rig views)."""
    from spare_twin.dataset.synthetic import SyntheticSpec, write_synthetic
    from spare_twin.nets.presets import resolve
    from spare_twin.nets.train import train

    def build(root):
        data = write_synthetic(root / "syn", SyntheticSpec(sizes=(("train", 12), ("val", 6), ("test", 6)), seed=5))
        cfg = {
            "net": {"channels": [4, 8], "fc_hidden": 16, "dropout": 0.0},
            "train": {"epochs": 1, "batch_size": 6, "samples_per_epoch": None, "val_samples": None, "threads": 1},
        }
        models = {}
        for name, preset in (("geo", "geo-depth-mv-count"), ("conv3d", "conv3d-depth-mv-count")):
            train(resolve(preset, cfg), data, root / name, progress=False)
            models[name] = root / name / "model.pt"
        return models

    return built_once(tmp_path_factory, "tiny", build)


@pytest.fixture(scope="session")
def rig_rec(printed_object, tmp_path_factory):
    """The 2-link object in the training rig, 3 frames at the network's resolution (96 x 128)."""
    from spare_twin.recording import Recording

    return Recording.open(_render(printed_object, tmp_path_factory, "rig", "--frames", "3", "--resolution", "network"))
