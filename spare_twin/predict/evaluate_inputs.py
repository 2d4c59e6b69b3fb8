"""What `evaluate` checks before it loads a network: its counts, the checkpoint's file, the data
folder, and `default_for` only with `ship`. Light to import (no torch), so `spare-twin evaluate`
refuses a missing checkpoint or data folder at once, not after 5 s of imports;
`predict.evaluate.evaluate_model` checks through the same function."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from spare_twin.errors import SpareTwinError
from spare_twin.nets.evaluate_names import EVALUATE, check_ship
from spare_twin.output import check_output
from spare_twin.validate import check_file, check_folder, check_whole


def check_evaluate(
    model_path: str | Path | None,
    data_dir: str | Path,
    batch_size: int = 16,
    max_samples: int | None = None,
    ship: str | None = None,
    default_for: Sequence[str] = (),
    out_dir: str | Path | None = None,
    force: bool = False,
) -> None:
    """`evaluate_model`'s arguments are usable: `default_for` only with `ship`, a name and tasks `ship`
    takes, `batch_size` and `max_samples` (where given) whole numbers of at least 1, the checkpoint
    `model_path` a file (where given; None is the shipped default), `data_dir` a folder and `out_dir`
    (where given) an output `evaluate` may write (`force`); else an error naming the parameter or the file."""
    if ship is None and default_for:
        raise SpareTwinError("default_for: only with ship (a model becomes a default when it is shipped)")
    if ship is not None:
        check_ship(ship, default_for)
    check_whole("batch_size", batch_size)
    if max_samples is not None:
        check_whole("max_samples", max_samples)
    if model_path is not None:
        check_file(model_path, "checkpoint")
    check_folder("data_dir", data_dir)
    if out_dir is not None:
        check_output(out_dir, EVALUATE, (model_path, data_dir), force)
