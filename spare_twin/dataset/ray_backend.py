"""The Ray backend: every sequence is one Ray task, a pure function of (seed, index, settings).

Where the files are written (`shards`):
- "driver" (default): a task returns its sequence file's bytes (a few MB) through Ray's object store and
  the driver writes them into the dataset folder. The folder needs to exist only where the driver runs,
  the driver is the only writer (its lock and atomic renames hold as in a local run), and a task killed
  half way leaves nothing behind.
- "workers": a task writes its file into the dataset folder itself, which must then be the same path on
  a file system every node mounts (NFS, Lustre, ...). It saves the bytes' trip through the driver.
`spare-twin bench dataset` measures both; on one machine their difference is within the noise, so the
default is the one that needs no shared file system.

Failures: a task whose worker process or node dies is run again by Ray (`max_retries`), and rendering
is deterministic, so the retry writes the same bytes. A killed driver takes its job's tasks with it;
running the same command again resumes from the files on disk, as it does locally.

Ray is imported only here, and only when this backend is used.
"""

from __future__ import annotations

import json
import os
import socket
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from spare_twin.dataset.backends import SequenceRenderer
from spare_twin.dataset.generate import GenConfig
from spare_twin.dataset.store import sequence_filename
from spare_twin.errors import SpareTwinError, first_line
from spare_twin.io import write_bytes_atomic

SHARDS = ("driver", "workers")
#: Times Ray runs a task again whose worker process or node died (rendering is deterministic).
MAX_RETRIES = 4

# One renderer per worker process and dataset: a Ray worker process runs many tasks of the same job.
_RENDERERS: dict[tuple[str, int], SequenceRenderer] = {}


def _renderer(cfg_json: str, seed: int) -> SequenceRenderer:
    key = (cfg_json, int(seed))
    if key not in _RENDERERS:
        for old in _RENDERERS.values():
            old.close()
        _RENDERERS.clear()
        _RENDERERS[key] = SequenceRenderer(GenConfig.from_dict(json.loads(cfg_json)), seed)
    return _RENDERERS[key]


def sequence_file_bytes(cfg_json: str, seed: int, index: int) -> bytes:
    """Task body (shards="driver"): sequence `index`'s file as bytes."""
    return _renderer(cfg_json, seed).file_bytes(index)


def write_sequence_file(cfg_json: str, seed: int, index: int, seq_dir: str) -> int:
    """Task body (shards="workers"): write sequence `index`'s file into the shared `seq_dir`."""
    _renderer(cfg_json, seed).write(index, seq_dir)
    return index


def import_ray():
    try:
        import ray
    except ImportError:
        raise SpareTwinError("backend ray: the ray package is not installed (pip install ray==2.60.0)") from None
    return ray


@dataclass
class RaySession:
    """A connection to a Ray cluster (`address`), or a Ray instance of `workers` CPUs started on this machine
    (address None) and stopped again on exit. In a process already connected to Ray, that connection is used."""

    address: str | None = None
    workers: int | None = None
    connect_s: float = 0.0

    def __enter__(self) -> RaySession:
        ray = import_ray()
        self._owned = not ray.is_initialized()
        t0 = time.perf_counter()
        if self._owned:
            kwargs = dict(include_dashboard=False, configure_logging=False, log_to_driver=False)
            try:
                if self.address is None:
                    ray.init(address="local", num_cpus=self.workers or os.cpu_count(), **kwargs)
                else:
                    _check_reachable(self.address)
                    ray.init(address=self.address, **kwargs)
            except (ConnectionError, ValueError, RuntimeError) as exc:
                first = first_line(exc)
                if self.address is None:
                    raise SpareTwinError(f"backend ray: cannot start Ray on this machine ({first})") from None
                raise SpareTwinError(f"ray_address {self.address}: cannot connect to a Ray cluster ({first})") from None
        self.connect_s = time.perf_counter() - t0
        return self

    def __exit__(self, *exc) -> None:
        if self._owned:
            import_ray().shutdown()


def _check_reachable(address: str) -> None:
    """Fail in seconds where Ray would retry for minutes: nothing listens at HOST:PORT."""
    host, sep, port = address.rpartition(":")
    if "://" in address or not sep or not port.isdigit():
        return  # "auto", ray:// client addresses: Ray's own checks
    try:
        socket.create_connection((host.strip("[]") or "127.0.0.1", int(port)), timeout=5).close()
    except OSError as exc:
        raise SpareTwinError(f"ray_address {address}: no Ray cluster answers there ({exc.strerror or exc})") from None


def cluster_cpus() -> int:
    """The CPUs of the connected Ray cluster."""
    return max(1, int(import_ray().cluster_resources().get("CPU", 1)))


def run_ray(
    todo: Iterable[int],
    cfg: GenConfig,
    seed: int,
    seq_dir: Path,
    workers: int | None = None,
    shards: str = "driver",
) -> Iterator[int]:
    """Render `todo` as Ray tasks on the connected cluster (see RaySession), at most `workers` at a time
    (default: one per CPU of the cluster); yields each index once its file is in `seq_dir`."""
    if shards not in SHARDS:
        raise SpareTwinError(f"shards {shards!r}: choose {' or '.join(SHARDS)}")
    ray = import_ray()
    todo = list(todo)
    window = workers or cluster_cpus()
    cfg_json = json.dumps(cfg.to_dict(), sort_keys=True)
    cfg_ref = ray.put(cfg_json)
    opts = dict(num_cpus=1, max_retries=MAX_RETRIES, retry_exceptions=False)
    if shards == "driver":
        task = ray.remote(**opts)(sequence_file_bytes)

        def submit(i):
            return task.remote(cfg_ref, seed, i)
    else:
        task = ray.remote(**opts)(write_sequence_file)
        seq_dir_str = os.fspath(Path(seq_dir).resolve())

        def submit(i):
            return task.remote(cfg_ref, seed, i, seq_dir_str)

    pending: dict = {}
    queue = iter(todo)
    try:
        for i in queue:
            pending[submit(i)] = i
            if len(pending) >= window:
                break
        while pending:
            [ref], _ = ray.wait(list(pending), num_returns=1)
            index = pending.pop(ref)
            try:
                result = ray.get(ref)
            except ray.exceptions.RayError as exc:
                lines = [ln for ln in str(exc).strip().splitlines() if ln.strip()]
                raise SpareTwinError(
                    f"sequence {index}: failed on the Ray cluster ({type(exc).__name__}: {lines[-1] if lines else ''})"
                ) from None
            if shards == "driver":
                write_bytes_atomic(Path(seq_dir) / sequence_filename(index), result)
            nxt = next(queue, None)
            if nxt is not None:
                pending[submit(nxt)] = nxt
            yield index
    finally:
        for ref in pending:  # a failed or abandoned run: stop its other tasks
            try:
                ray.cancel(ref, force=True)
            except Exception:  # noqa: BLE001  (already finished or gone: nothing to stop)
                pass
