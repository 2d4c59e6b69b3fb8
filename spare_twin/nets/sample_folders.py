"""Folders of ready profile samples (the profile network's training input beside the rig's datasets):
their format, kinds and split codes, and whether a run may write one (`check_samples_folder`). Light
to import, so that a command can check a folder before it loads torch.

Two commands write them, in the same format (`samples.npz`: `x`, `n`, `lengths`, `angles`, `split`;
`manifest.json`): `spare-twin dataset --handheld` (captures drawn the bench's way and observed as
`predict` observes them, `bench.handheld_samples`) and `spare-twin dataset --analytic-profiles`
(profiles drawn straight from the printed chain's geometry, `nets.profile_analytic`).
"""

from __future__ import annotations

from pathlib import Path

from spare_twin.errors import SpareTwinError
from spare_twin.io import read_json
from spare_twin.output import check_output

#: The format of a folder of profile samples (its name is older than the analytic samples).
HANDHELD_FORMAT = "spare-twin hand-held profile samples 1"
#: The output kinds (the commands that write them).
HANDHELD_KIND = "dataset --handheld"
ANALYTIC_KIND = "dataset --analytic-profiles"
#: `split` codes in a sample folder's samples.npz.
SPLIT_CODES = {"train": 0, "val": 1}


def check_samples_folder(out: str | Path, kind: str, seed: int, what: str, force: bool = False) -> None:
    """A run of `kind` with dataset seed `seed` may write `out`: absent, empty or a folder of `kind`
    (`force` replaces anything else), and one already there has `seed` (`force` replaces one of another
    seed); else an error saying the folder holds `what` of another seed. Checked before `writing`
    starts a partial copy of the folder, and before the drawing's modules are loaded."""
    check_output(out, kind, (), force)
    earlier = Path(out) / "manifest.json"
    if not force and earlier.is_file() and (held := read_json(earlier).get("seed")) != seed:
        raise SpareTwinError(f"out {out}: holds {what} of seed {held}, not {seed}")
