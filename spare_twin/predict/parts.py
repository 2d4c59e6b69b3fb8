"""The parts a chain was printed with, as the user says (`predict --parts FILE`): the measurement's and
the profile's geometry (layer pitch, plates, socket) are theirs (`measure.chain.measure_views`).

Never read from a recording: its ground truth is what `predict` is asked to find. The networks were
all trained on the default parts (`TRAINED_PARTS`); `predict.abstain.note_parts` says so in a
network's evidence wherever the parts differ.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from pathlib import Path

from spare_twin.config import ChainSpec, PartDims
from spare_twin.errors import SpareTwinError
from spare_twin.io import read_json

#: The parts every dataset is generated with (`config.sample_chain` keeps `PartDims()`), so every
#: shipped network saw these plates only.
TRAINED_PARTS = PartDims()
#: The part dimensions that set the geometry the chain is observed and measured with
#: (`observe.profile.parts_geometry_m`), as the JSON names them.
MEASURED_FIELDS = ("link_width_mm", "link_thickness_mm", "layer_gap_mm", "foot_thickness_mm", "socket_height_mm")


def read_parts(path: str | Path) -> PartDims:
    """The parts in a JSON file: a `parts` block (`{"link_thickness_mm": 8.0}`, the rest the
    defaults; or `{"parts": {...}}`), or an object configuration (`object.json`, `spare-twin object
    --config`'s file) whose `parts` it takes, or an object folder holding its `object.json`. Anything
    else is one SpareTwinError starting "parts PATH:" (a command names its flag there)."""
    path = Path(path)
    if path.is_dir():
        if not (path / "object.json").is_file():
            raise SpareTwinError(f"parts {path}: a folder with no object.json (give a parts JSON file)")
        path = path / "object.json"
    source = f"parts {path}"
    try:
        d = read_json(path)
    except SpareTwinError as exc:  # its message starts with the path
        raise SpareTwinError(f"parts {exc}") from None
    if not isinstance(d, dict):
        raise SpareTwinError(f"{source}: expected a JSON object (part dimensions in mm, or an object configuration)")
    if "n_links" in d:  # an object configuration: checked whole, as `spare-twin object` checks it
        return ChainSpec.from_dict(d, source=source).parts
    block = d["parts"] if set(d) == {"parts"} else d
    if not isinstance(block, dict):
        raise SpareTwinError(f"{source}: parts must be a JSON object of part dimensions in mm")
    known = [f.name for f in dataclasses.fields(PartDims)]
    unknown = sorted(str(k) for k in block if k not in known)
    if unknown:
        raise SpareTwinError(f"{source}: unknown key(s) {', '.join(unknown)} (part dimensions: {', '.join(known)})")
    for key, value in block.items():
        if not _is_number(value) or not math.isfinite(float(value)):
            raise SpareTwinError(f"{source}: {key} must be a number of millimetres, got {value!r}")
        if float(value) < 0 or (float(value) == 0 and key != "press_fit_mm"):
            raise SpareTwinError(f"{source}: {key} must be positive, got {value!r}")
    return PartDims(**{k: float(v) for k, v in block.items()})


def _is_number(v) -> bool:
    if not isinstance(v, numbers.Real) or isinstance(v, bool):
        return False
    try:  # a JSON integer too large for a float is no usable number either
        float(v)
    except OverflowError:
        return False
    return True


def parts_json(parts: PartDims) -> dict:
    """The part dimensions the chain was observed and measured with (`predict --json`'s `parts`):
    `MEASURED_FIELDS`, the layer pitch they make, and whether they are the defaults (the networks' own)."""
    out: dict = {k: getattr(parts, k) for k in MEASURED_FIELDS}
    out["layer_pitch_mm"] = round(parts.layer_pitch_mm, 6)
    out["defaults"] = parts == TRAINED_PARTS
    return out


def parts_words(parts: PartDims) -> str:
    """The parts' plates in a few words: "12 mm wide, 6 mm thick plates, 6.4 mm layer pitch"."""
    return (
        f"{parts.link_width_mm:g} mm wide, {parts.link_thickness_mm:g} mm thick plates, "
        f"{parts.layer_pitch_mm:.6g} mm layer pitch"
    )
