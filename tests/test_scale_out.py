"""Dataset generation on a Ray cluster: a local cluster (a head reached on 127.0.0.1 and two worker nodes
of one CPU each) writes the same bytes as the local backend, extends a dataset, survives a killed worker
process and resumes after a killed driver. The cluster lives for this module only."""

import hashlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import psutil
import pytest
from conftest import run_cli
from ray.cluster_utils import Cluster

from spare_twin.dataset.build import generate_dataset
from spare_twin.dataset.generate import GenConfig

CFG = GenConfig(frames=5)
SEED, K = 4, 6


def _hashes(root: Path) -> dict:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted((root / "sequences").glob("*.h5"))}


@pytest.fixture(scope="module")
def cluster():
    c = Cluster(initialize_head=True, head_node_args={"num_cpus": 0, "include_dashboard": False})
    try:
        workers = [c.add_node(num_cpus=1) for _ in range(2)]
        c.wait_for_nodes()
        yield "127.0.0.1:" + c.address.rsplit(":", 1)[1], workers
    finally:
        c.shutdown()


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    root = tmp_path_factory.mktemp("local") / "data"
    generate_dataset(root, K, seed=SEED, workers=1, cfg=CFG, progress=False)
    return root


def test_ray_writes_the_local_bytes_and_extends(cluster, reference, tmp_path):
    address, _ = cluster
    ref = _hashes(reference)
    out = tmp_path / "ray"
    r = generate_dataset(out, 4, SEED, 2, CFG, progress=False, backend="ray", ray_address=address)
    assert r["generated"] == 4 and r["complete"] and r["backend"] == "ray"
    assert _hashes(out) == {k: v for k, v in ref.items() if k < "seq-000004"}
    r = generate_dataset(out, K, SEED, 2, CFG, progress=False, backend="ray", ray_address=address)
    assert (r["generated"], r["already_present"]) == (2, 4)
    assert _hashes(out) == ref
    assert json.loads((out / "manifest.json").read_text()) == json.loads((reference / "manifest.json").read_text())


def _kill_one_running_task(raylets: list[int], killed: list[int], stop: threading.Event) -> None:
    """SIGKILL the first worker process seen running a sequence task (a child of one of our raylets)."""
    while not stop.is_set() and not killed:
        for raylet in raylets:
            for child in psutil.Process(raylet).children():
                try:
                    title = child.cmdline()
                except psutil.Error:
                    continue
                if title and title[0].startswith("ray::sequence_file_bytes"):
                    os.kill(child.pid, signal.SIGKILL)
                    killed.append(child.pid)
                    return
        time.sleep(0.01)


def test_ray_survives_a_killed_worker(cluster, reference, tmp_path):
    address, nodes = cluster
    raylets = [n.all_processes["raylet"][0].process.pid for n in nodes]
    killed: list[int] = []
    stop = threading.Event()
    killer = threading.Thread(target=_kill_one_running_task, args=(raylets, killed, stop))
    killer.start()
    try:
        out = tmp_path / "ray"
        r = generate_dataset(out, K, SEED, 2, CFG, progress=False, backend="ray", ray_address=address)
    finally:
        stop.set()
        killer.join()
    assert killed, "no running task was seen to kill"
    assert not psutil.pid_exists(killed[0]) or psutil.Process(killed[0]).status() == psutil.STATUS_ZOMBIE
    assert r["complete"] and _hashes(out) == _hashes(reference)  # Ray ran the killed task again


def test_ray_resumes_after_a_killed_driver(cluster, reference, tmp_path):
    address, _ = cluster
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "spare_twin", "dataset", "--out", str(out), "--instances", str(K)]
    cmd += ["--seed", str(SEED), "--frames", str(CFG.frames), "--backend", "ray", "--ray-address", address]
    proc = subprocess.Popen([*cmd, "--workers", "2"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 90
        while time.time() < deadline and len(list((out / "sequences").glob("seq-*.h5"))) < 2:
            time.sleep(0.01)
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    done = len(list((out / "sequences").glob("seq-*.h5")))
    assert 2 <= done < K, "the run finished before it could be killed"
    assert (out / ".lock").exists()  # the dead driver's
    r = generate_dataset(out, K, SEED, 2, CFG, progress=False, backend="ray", ray_address=address)
    assert r["already_present"] == done and r["complete"]
    assert _hashes(out) == _hashes(reference)
    assert not list((out / "sequences").glob(".*tmp*")) and not (out / ".lock").exists()


def test_ray_cli_errors_are_one_line_and_write_nothing(tmp_path, capsys):
    out = tmp_path / "d"
    code, _, err = run_cli(["dataset", "--out", str(out), "--instances", "1", "--ray-address", "127.0.0.1:1"], capsys)
    assert code == 1 and "--backend ray" in err
    argv = ["dataset", "--out", str(out), "--instances", "1", "--backend", "ray", "--ray-address", "127.0.0.1:1"]
    code, _, err = run_cli(argv, capsys)
    assert code == 1 and "--ray-address 127.0.0.1:1" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()
