"""The names `evaluate` writes under, light to import (no torch): its output's kind, and a shipped
model's name and the tasks it becomes the default for (`models/index.json`). `spare-twin evaluate`
refuses a bad `--out` or `--ship` at once, not after 5 s of imports."""

from __future__ import annotations

from collections.abc import Sequence

from spare_twin.errors import SpareTwinError

#: The output kind of `evaluate --out` (`spare_twin.output`).
EVALUATE = "evaluate"
#: The tasks a shipped model can be the default for.
INDEX_TASKS = ("predict", "count-mv", "count-tmp", "lengths-mv", "e2e-mv", "e2e-tmp")


def check_ship(name: str, tasks: Sequence[str]) -> None:
    """`ship`'s arguments are usable: `name` is a file stem, every task one of INDEX_TASKS."""
    if not name or not all(ch.isalnum() or ch in "_-." for ch in name) or name.startswith("."):
        raise SpareTwinError(f"name {name!r}: a model name is letters, digits, '_', '-' or '.' (a file stem)")
    for t in tasks:
        if t not in INDEX_TASKS:
            raise SpareTwinError(f"tasks: unknown task {t!r} (choose from {', '.join(INDEX_TASKS)})")
