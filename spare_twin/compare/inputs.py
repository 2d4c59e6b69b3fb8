"""What `compare`, its batch and the demo check before any work: their inputs (an object folder, a
recording, a checkpoint file, a folder of pairs) and their outputs (the twin's recording, the Rerun
file, the table's folder, the demo's folder). Light to import (no torch, no renderer): the commands
refuse a missing folder or an output that is not theirs before they load the stages (5 s of a new
process); `sim_vs_real.compare`, `batch.compare_batch` and `demo.run_demo` check through the same functions."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from spare_twin.errors import SpareTwinError
from spare_twin.object.files import object_files
from spare_twin.output import RRD, check_output
from spare_twin.recording import Recording
from spare_twin.validate import check_file

#: The output kind of the twin's recording (the marker `spare_twin.output` writes in it).
SIM_TWIN = "compare sim twin"
#: Output kind (`spare_twin.output`) of a batch's table folder.
TABLE = "compare batch"
#: The output kind of the demo's folder.
DEMO = "demo"


@dataclass(frozen=True)
class CompareInputs:
    """A comparison's inputs and outputs, checked (`check_compare`)."""

    real: Recording
    """The real recording, opened."""
    sim_dir: Path
    """Where the twin's recording goes: as given, else `<real>_sim_twin` beside the real recording."""
    inputs: tuple
    """What the outputs are made from (the object folder, the real recording, the checkpoint)."""


def check_compare(
    object_dir: str | Path,
    real_dir: str | Path,
    model: str | Path | None = None,
    rrd: str | Path | None = None,
    sim_dir: str | Path | None = None,
    force: bool = False,
) -> CompareInputs:
    """`compare`'s inputs are there (the object folder's files, the recording, the checkpoint `model`'s
    file where one is given) and its outputs may be written (`sim_dir`; `rrd` where given; `force`
    replaces what is not an earlier one); else a one-line error naming the folder or the file."""
    object_files(object_dir)
    real = Recording.open(real_dir)
    if model is not None:
        check_file(model, "checkpoint")
    sim_dir = Path(sim_dir) if sim_dir else Path(real.root).with_name(Path(real.root).name + "_sim_twin")
    inputs = (object_dir, real.root, model)
    check_output(sim_dir, SIM_TWIN, inputs, force)
    if rrd is not None:
        check_output(rrd, RRD, (*inputs, sim_dir), force)
    return CompareInputs(real, sim_dir, inputs)


def pairs_in(root: str | Path) -> list[Path]:
    """The `<name>/` folders of `root` that hold both `object/` and `real/`, sorted by name."""
    root = Path(root)
    if not root.is_dir():
        return []
    return sorted(d for d in root.iterdir() if (d / "object").is_dir() and (d / "real").is_dir())


def check_batch(
    root: str | Path, table_dir: str | Path, model: str | Path | None = None, force: bool = False
) -> list[Path]:
    """`compare_batch`'s pairs (`pairs_in`: at least one), the checkpoint `model`'s file where one is
    given, and the table's folder `table_dir` (`force` replaces what is not an earlier table); returns
    the pairs."""
    pairs = pairs_in(root)
    if not pairs:
        raise SpareTwinError(f"batch {root}: no <name>/object and <name>/real folders in it")
    if model is not None:
        check_file(model, "checkpoint")
    check_output(table_dir, TABLE, (root, model), force)
    return pairs


def check_demo(out: str | Path, model: str | Path | None = None, force: bool = False) -> None:
    """`run_demo`'s checkpoint file (where `model` is given) and its folder `out`: absent, empty or an
    earlier demo (`force` replaces anything else)."""
    if model is not None:
        check_file(model, "checkpoint")
    check_output(out, DEMO, (model,), force)
