"""Where a dataset's sequences are rendered: this process, a pool of local processes, or a Ray cluster
(ray_backend.py). Every backend runs the same `SequenceRenderer`, so a sequence file's bytes depend only on
(seed, index, settings), never on the backend or the number of workers.

A backend's `run(todo)` yields the index of each sequence as its file lands in the dataset folder
(written under a temporary name and renamed), in any order; the driver (build.py) counts them for its
progress bar and rebuilds the manifest from the files at the end.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import tempfile
import threading
from collections.abc import Iterable, Iterator
from pathlib import Path

from spare_twin.dataset.generate import GenConfig, Sequence, render_sequence
from spare_twin.dataset.store import sequence_filename, write_sequence
from spare_twin.errors import SpareTwinError
from spare_twin.sim.twin import Twin

BACKENDS = ("local", "ray")


class SequenceRenderer:
    """Renders the sequences of one dataset in one process; its pybullet client lives as long as it does."""

    def __init__(self, cfg: GenConfig, seed: int):
        import cv2  # noqa: F401  (imported here so the first sequence's time is rendering, not imports)
        import h5py  # noqa: F401

        self.cfg, self.seed = cfg, int(seed)
        self.twin = Twin()

    def render(self, index: int) -> Sequence:
        with tempfile.TemporaryDirectory(prefix="spare-twin-gen-") as work:
            return render_sequence(self.cfg, self.seed, index, self.twin, Path(work))

    def write(self, index: int, seq_dir: str | Path) -> None:
        """Render sequence `index` into its file in `seq_dir`."""
        write_sequence(Path(seq_dir) / sequence_filename(index), self.render(index), fps=self.cfg.fps)

    def file_bytes(self, index: int) -> bytes:
        """The bytes of sequence `index`'s file, written to a scratch folder and read back (the very bytes
        `write` leaves in the dataset folder: HDF5 stores no file name or time)."""
        seq = self.render(index)
        with tempfile.TemporaryDirectory(prefix="spare-twin-shard-") as scratch:
            path = Path(scratch) / sequence_filename(index)
            write_sequence(path, seq, fps=self.cfg.fps)
            return path.read_bytes()

    def close(self) -> None:
        self.twin.close()


def check_workers(workers: int | None) -> None:
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise SpareTwinError(f"workers {workers}: must be a whole number, at least 1")


# -- local processes -----------------------------------------------------------------------------
_POOL: dict = {}


def start_pool(workers: int, initializer=None, initargs: tuple = ()):
    """A pool of `workers` spawned processes (pybullet clients must not be forked) that stay quiet on Ctrl-C.

    SIGINT is blocked while they start: they inherit the block through exec, so a Ctrl-C while they
    import prints no traceback, and their initializer then ignores it; in the driver it stays pending
    meanwhile, and is answered as soon as the pool stands (never lost)."""
    ctx = mp.get_context("spawn")
    main = threading.current_thread() is threading.main_thread()
    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT}) if main else None
    try:
        return ctx.Pool(workers, initializer=_initialize_quietly, initargs=(initializer, *initargs))
    finally:
        if main:
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)


def _initialize_quietly(initializer, *initargs) -> None:
    """A pool worker leaves Ctrl-C to the driver: the terminal sends SIGINT to the whole process group,
    and the driver alone answers it (one line, exit 130) and terminates the pool."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # blocked by start_pool; ignored from now
    if initializer is not None:
        initializer(*initargs)


def _pool_init(cfg_dict: dict, seed: int, seq_dir: str) -> None:
    _POOL["renderer"] = SequenceRenderer(GenConfig.from_dict(cfg_dict), seed)
    _POOL["seq_dir"] = seq_dir


def _pool_work(index: int) -> int:
    _POOL["renderer"].write(index, _POOL["seq_dir"])
    return index


def run_local(todo: Iterable[int], cfg: GenConfig, seed: int, seq_dir: Path, workers: int = 1) -> Iterator[int]:
    """Render `todo` into `seq_dir` in this process (workers = 1) or in a pool of `workers` processes."""
    todo = list(todo)
    if workers == 1 or len(todo) <= 1:
        renderer = SequenceRenderer(cfg, seed)
        try:
            for index in todo:
                renderer.write(index, seq_dir)
                yield index
        finally:
            renderer.close()
        return
    pool = start_pool(workers, _pool_init, (cfg.to_dict(), seed, os.fspath(seq_dir)))
    with pool:  # on leaving, also by an interrupt: the workers are terminated
        yield from pool.imap_unordered(_pool_work, todo, chunksize=1)
