"""`spare-twin bench dataset`: what generating a dataset costs, against pybullet's raw render loop.

For each worker count W, in the same run and interleaved (raw, local, ray, ray-workers-write, then the
same backwards, `rounds` times), so a machine whose load changes while it runs (a shared one) weighs on
every column alike:
- raw: W processes run pybullet's render loop alone over the same objects, motions and cameras
  (nothing converted or stored; setting up each object is not timed);
- local: `generate_dataset(backend="local", workers=W)` of W x `instances` sequences, end to end
  (starting the processes, sampling, rendering, converting, compressing, writing the files);
- ray: the same with `backend="ray"` against a Ray cluster of this machine's W CPUs started for the
  benchmark (each run connects anew, as the command does with --ray-address: a new job whose worker
  processes start cold, as the local pool's do); connecting is timed apart. "ray (workers write)" is
  the same with shards="workers".
Rates are images/s; each is also given as a ratio to raw at the same W. The Ray costs per task are
measured apart: an empty task's round trip, returning a sequence file's bytes through the object
store, and the driver's write of them. The paper preset's wall time is extrapolated from (or, with
paper="full", measured at) the largest W on the local backend.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spare_twin.dataset.backends import SequenceRenderer, start_pool
from spare_twin.dataset.build import PRESETS, generate_dataset
from spare_twin.dataset.generate import GenConfig, _seeds, load_twin_object, sequence_spec
from spare_twin.dataset.ray_backend import import_ray
from spare_twin.errors import SpareTwinError
from spare_twin.io import write_bytes_atomic
from spare_twin.sim.motion import object_motion
from spare_twin.sim.scene import sample_scene
from spare_twin.sim.twin import Lighting, projection_matrix, view_matrix
from spare_twin.validate import check_whole

SEED = 12345  # the benchmark's sequences: the same objects in every column
COLUMNS = ("raw", "local", "ray", "ray_workers_write")


@dataclass(frozen=True)
class DatasetBench:
    instances: int = 4
    """Sequences per worker in every measured run."""
    workers: tuple[int, ...] = (1, 2)
    frames: int = 100
    geometry: str = "sim"
    rounds: int = 1
    """Interleaved rounds (raw, local, ray, ray-workers-write, then backwards): 2 * rounds runs of each."""
    ray: bool = True
    paper: str = "extrapolate"

    def __post_init__(self) -> None:
        for name in ("instances", "frames", "rounds"):
            check_whole(name, getattr(self, name))
        if not self.workers:
            raise SpareTwinError("workers []: give at least one worker count")
        for w in self.workers:
            check_whole("workers", w)
        if self.paper not in ("extrapolate", "full"):
            raise SpareTwinError(f"paper {self.paper!r}: choose extrapolate or full")


@dataclass(frozen=True)
class DatasetBenchResult:
    cpu_cores: int
    geometry: str
    frames: int
    image_size_hw: list
    cameras: int
    rounds: int
    runs: list = field(default_factory=list)
    ray: dict | None = None
    paper: dict | None = None

    def to_json(self) -> dict:
        out = {k: getattr(self, k) for k in ("cpu_cores", "geometry", "frames", "image_size_hw", "cameras", "runs")}
        out.update(rounds=self.rounds, interleaved=True, paper=self.paper)
        if self.ray is not None:
            out["ray"] = self.ray
        return out


# -- the raw render loop ---------------------------------------------------------------------------
def _raw_worker(job: tuple) -> tuple[int, float]:
    """pybullet's render loop alone over sequences `indices` (objects set up untimed): (images, seconds)."""
    cfg_dict, seed, indices = job
    cfg = GenConfig.from_dict(cfg_dict)
    renderer = SequenceRenderer(cfg, seed)
    twin, rig, light = renderer.twin, cfg.rig, Lighting()
    seconds, images = 0.0, 0
    with tempfile.TemporaryDirectory(prefix="spare-twin-bench-") as work:
        for index in indices:
            spec = sequence_spec(seed, index)
            seeds = _seeds(seed, index)
            scene = sample_scene(rig, spec, cfg.randomization, np.random.default_rng(seeds["scene"]))
            obj = load_twin_object(cfg, spec, Path(work))
            twin.load(obj)
            angles = object_motion(
                obj,
                np.random.default_rng(seeds["motion"]),
                cfg.motion(),
            )
            views = [view_matrix(T) for T in scene.T_world_camera]
            projs = [projection_matrix(k, rig.width, rig.height, rig.near_m, rig.far_m) for k in scene.K]
            t0 = time.perf_counter()
            for t in range(cfg.frames):
                twin.set_joints(angles[t])
                for v in range(rig.n_cameras):
                    twin.render_raw(views[v], projs[v], rig.width, rig.height, light, cfg.segmentation)
            seconds += time.perf_counter() - t0
            images += cfg.frames * rig.n_cameras
    renderer.close()
    return images, seconds


def _raw_rate(cfg: GenConfig, workers: int, per_worker: int) -> float:
    """Summed images/s of `workers` processes running the raw loop at the same time."""
    jobs = [(cfg.to_dict(), SEED, [w * per_worker + k for k in range(per_worker)]) for w in range(workers)]
    if workers == 1:
        results = [_raw_worker(jobs[0])]
    else:
        with start_pool(workers) as pool:  # quiet on Ctrl-C, like the dataset's own pool
            results = pool.map(_raw_worker, jobs)
    return sum(images / seconds for images, seconds in results)


# -- Ray's costs per task --------------------------------------------------------------------------
def empty_task() -> None:
    return None


def bytes_task(n: int) -> bytes:
    return bytes(n)


def _ray_task_costs(address: str, shard_bytes: int, repeats: int = 20) -> dict:
    ray = import_ray()
    ray.init(address=address, include_dashboard=False, configure_logging=False, log_to_driver=False)
    try:
        empty = ray.remote(num_cpus=1)(empty_task)
        blob = ray.remote(num_cpus=1)(bytes_task)
        ray.get([empty.remote(), blob.remote(1)])  # a worker process up and the functions exported
        t0 = time.perf_counter()
        for _ in range(repeats):
            ray.get(empty.remote())
        t1 = time.perf_counter()
        for _ in range(repeats):
            data = ray.get(blob.remote(shard_bytes))
        t2 = time.perf_counter()
    finally:
        ray.shutdown()
    with tempfile.TemporaryDirectory(prefix="spare-twin-bench-") as tmp:
        t3 = time.perf_counter()
        for i in range(repeats):
            write_bytes_atomic(Path(tmp) / f"seq-{i:06d}.h5", data)
        t4 = time.perf_counter()
    return {
        "empty_task_round_trip_ms": round(1000 * (t1 - t0) / repeats, 2),
        "sequence_file_mb": round(shard_bytes / 1e6, 2),
        "return_sequence_file_ms": round(1000 * (t2 - t1) / repeats, 2),
        "driver_write_ms": round(1000 * (t4 - t3) / repeats, 2),
    }


# -- the benchmark ---------------------------------------------------------------------------------
def _local_cluster(cpus: int):
    """A one-node Ray cluster of `cpus` CPUs for the benchmark (Ray's own test utility): its address and
    the Cluster, whose shutdown() stops every process it started."""
    import_ray()
    from ray.cluster_utils import Cluster

    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": cpus, "include_dashboard": False})
    return "127.0.0.1:" + cluster.address.rsplit(":", 1)[1], cluster


def bench_dataset(b: DatasetBench, log: Callable[[str], None] = print) -> DatasetBenchResult:
    cfg = GenConfig(frames=b.frames, geometry=b.geometry)
    images_per_seq = cfg.rig.n_cameras * cfg.frames
    tmp = Path(tempfile.mkdtemp(prefix="spare-twin-bench-"))
    address, cluster = _local_cluster(max(b.workers)) if b.ray else (None, None)
    columns = [c for c in COLUMNS if b.ray or not c.startswith("ray")]
    runs, shard_sizes, connect = [], [], []
    try:
        for w in b.workers:
            n = w * b.instances
            totals = {c: [0.0, 0.0] for c in columns}  # images, seconds
            order = columns + columns[::-1]
            for k, column in enumerate(order * b.rounds):
                if column == "raw":
                    rate = _raw_rate(cfg, w, b.instances)
                    totals[column][0] += n * images_per_seq
                    totals[column][1] += n * images_per_seq / rate
                    continue
                out = tmp / f"w{w}-{column}-{k}"
                backend = "local" if column == "local" else "ray"
                shards = "workers" if column == "ray_workers_write" else "driver"
                at = address if backend == "ray" else None
                r = generate_dataset(
                    out, n, SEED, w, cfg, progress=False, backend=backend, ray_address=at, shards=shards
                )
                totals[column][0] += r["generated_images"]
                totals[column][1] += r["generate_s"]
                if backend == "ray":
                    connect.append(r["connect_s"])
                shard_sizes += [p.stat().st_size for p in (out / "sequences").glob("*.h5")]
                shutil.rmtree(out, ignore_errors=True)
            rates = {c: totals[c][0] / totals[c][1] for c in columns}
            raw = rates["raw"]
            run = {
                "workers": w,
                "raw_images_per_s": round(raw, 1),
                "end_to_end_images_per_s": round(rates["local"], 1),
                "ratio": round(rates["local"] / raw, 3),
                "raw_per_worker": round(raw / w, 1),
                "end_to_end_per_worker": round(rates["local"] / w, 1),
                "sequences_per_worker": b.instances,
            }
            line = (
                f"workers {w}: raw {raw:6.1f} img/s | local {rates['local']:6.1f} ({rates['local'] / raw:.2f} of raw)"
            )
            if b.ray:
                run.update(
                    ray_images_per_s=round(rates["ray"], 1),
                    ray_ratio=round(rates["ray"] / raw, 3),
                    ray_vs_local=round(rates["ray"] / rates["local"], 3),
                    ray_workers_write_images_per_s=round(rates["ray_workers_write"], 1),
                    ray_workers_write_ratio=round(rates["ray_workers_write"] / raw, 3),
                )
                line += (
                    f" | ray {rates['ray']:6.1f} ({rates['ray'] / raw:.2f} of raw, {rates['ray'] / rates['local']:.2f}"
                    f" of local) | ray, workers write {rates['ray_workers_write']:6.1f}"
                )
            runs.append(run)
            log(line)
        ray = None
        if b.ray:
            ray = _ray_task_costs(address, int(np.mean(shard_sizes)))
            ray["connect_s"] = round(float(np.median(connect)), 2)
            per_task_s = (ray["return_sequence_file_ms"] + ray["driver_write_ms"]) / 1000
            ray["driver_bound_images_per_s"] = round(images_per_seq / per_task_s, 0)
            log(
                f"ray per task: empty round trip {ray['empty_task_round_trip_ms']} ms, returning a "
                f"{ray['sequence_file_mb']} MB sequence file {ray['return_sequence_file_ms']} ms, driver write "
                f"{ray['driver_write_ms']} ms (one driver absorbs up to {ray['driver_bound_images_per_s']:.0f} "
                f"img/s); connecting {ray['connect_s']} s"
            )
    finally:
        if cluster is not None:
            cluster.shutdown()
        shutil.rmtree(tmp, ignore_errors=True)
    paper = _paper(b, cfg, runs, tmp)
    log(
        f"paper preset ({paper['images']} images, {paper['workers']} workers): {paper['wall_s'] / 60:.1f} min "
        f"{'measured' if paper['measured'] else 'extrapolated from the local end-to-end rate'}"
    )
    return DatasetBenchResult(
        cpu_cores=os.cpu_count(),
        geometry=b.geometry,
        frames=b.frames,
        image_size_hw=[cfg.rig.height, cfg.rig.width],
        cameras=cfg.rig.n_cameras,
        rounds=b.rounds,
        runs=runs,
        ray=ray,
        paper=paper,
    )


def _paper(b: DatasetBench, cfg: GenConfig, runs: list, tmp: Path) -> dict:
    preset = PRESETS["paper"]
    images = preset.instances * cfg.rig.n_cameras * preset.frames
    wmax = max(b.workers)
    if b.paper == "full":
        with tempfile.TemporaryDirectory(prefix="spare-twin-bench-") as d:
            cfg_full = GenConfig(geometry=b.geometry)
            r = generate_dataset(Path(d) / "paper", preset.instances, preset.seed, wmax, cfg_full, progress=True)
        rate = r["images"] / r["wall_s"]
        return {"workers": wmax, "images": r["images"], "wall_s": round(r["wall_s"], 1), "measured": True,
                "images_per_s": round(rate, 1)}  # fmt: skip
    best = next(r for r in runs if r["workers"] == wmax)
    return {"workers": wmax, "images": images, "wall_s": round(images / best["end_to_end_images_per_s"], 1),
            "measured": False}  # fmt: skip
