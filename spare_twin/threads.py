"""Independent pieces of numpy work side by side on the machine's cores, in threads.

numpy's passes over whole arrays release the GIL, so per-frame and per-view work (a depth image's
cloud, a view's points) runs on every core without processes or copies. Each item is worked on by
itself and the results come back in the items' order, so they are the same bytes whatever the
number of threads: determinism holds.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from spare_twin.validate import usable_cores

T = TypeVar("T")
R = TypeVar("R")


def cores() -> int:
    """The threads this process should use: OMP_NUM_THREADS where it is set (a worker process told to
    use one, beside others on the same cores), else the cores it may run on."""
    try:
        told = int(os.environ.get("OMP_NUM_THREADS", "0"))
    except ValueError:
        told = 0
    available = usable_cores()
    return min(told, available) if told > 0 else available


def side_by_side(fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """[fn(x) for x in items], computed in up to `cores()` threads, in the items' order."""
    items = list(items)
    workers = min(len(items), cores())
    if workers < 2:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(fn, items))
