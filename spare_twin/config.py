"""Chain configuration: the SPARE object model, its sampling distribution and printing parameters.

Everything downstream (CAD, URDF, simulation, dataset labels) is a pure function of a `ChainSpec`,
so `object.json` (its JSON form) is enough to rebuild every output file bit for bit.

Units: `link_lengths_pu` are paper units (paper metres, the scale the paper's metrics use);
`print_scale` is physical metres per paper metre; part dimensions are millimetres (`*_mm`),
as in the STL files a slicer reads.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import numbers
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spare_twin.errors import SpareTwinError
from spare_twin.io import read_json

MIN_MOVING_LINKS = 1
MAX_MOVING_LINKS = 6
LABEL_SLOTS = MAX_MOVING_LINKS + 1  # the paper's 7-slot length label (base + 6 moving links)

#: The paper's link colours, as sRGB 0..1.
COLORS: dict[str, tuple[float, float, float]] = {
    "black": (0.08, 0.08, 0.08),
    "white": (0.95, 0.95, 0.95),
    "red": (0.85, 0.10, 0.10),
    "orange": (1.00, 0.50, 0.05),
    "blue": (0.10, 0.25, 0.85),
    "green": (0.10, 0.65, 0.20),
    "yellow": (0.95, 0.85, 0.10),
    "indigo": (0.29, 0.0, 0.51),
}

#: The paper's sampling distribution (paper units).
BASE_LENGTH_RANGE = (1.3, 2.0)
LINK_LENGTH_RANGE = (0.3, 1.0)
MAX_TOTAL_LENGTH = 3.0

#: The key of the n + 1 paper-unit link lengths (base first) in every file and output.
LENGTHS_KEY = "link_lengths_pu"
#: DESIGN.md's object-folder contract, which outside checks read, names object.json's paper-unit lengths
#: `link_lengths_m`, so object.json writes this key too, beside LENGTHS_KEY with the same values. The name is
#: a misnomer (the values are paper units, not metres): readers use LENGTHS_KEY, and take this key alone only
#: from a file written before 0.6.0, when every file and output named the lengths so (`with_paper_lengths`).
DESIGN_CONTRACT_LENGTHS_KEY = "link_lengths_m"


def _is_seed(seed) -> bool:
    # numpy integers count too: seeds are often derived with numpy (SeedSequence words)
    return isinstance(seed, numbers.Integral) and not isinstance(seed, bool) and seed >= 0


def _fail(field_name: str, problem: str) -> None:
    # the message starts with the parameter's name, so a command can say it as its flag (commands.common.flags)
    raise SpareTwinError(f"{field_name}: {problem}")


def _shown(value) -> str:
    """A value as a one-line message shows it (JSON spelling, cut short)."""
    try:
        text = json.dumps(value, ensure_ascii=True)
    except (TypeError, ValueError):
        text = repr(value).encode("unicode_escape").decode()
    return text if len(text) <= 40 else text[:37] + "..."


def _is_number(v) -> bool:
    if not isinstance(v, numbers.Real) or isinstance(v, bool):
        return False
    try:  # a JSON integer too large for a float is not a usable number either
        float(v)
    except OverflowError:
        return False
    return True


def _type_problems(d: dict) -> list[str]:
    """Every field of a configuration (keys as in object.json) whose value has the wrong type: float()
    and len() on hand-written JSON would otherwise fail with a Python error naming no key."""
    problems = []
    n = d.get("n_links")
    if "n_links" in d and not (isinstance(n, numbers.Integral) and not isinstance(n, bool)):
        problems.append(f"n_links: must be a whole number, got {_shown(n)}")
    for key, ok, what in (
        (LENGTHS_KEY, _is_number, "numbers"),
        ("colors", lambda c: isinstance(c, str), "colour names"),
    ):
        v = d.get(key)
        if key in d and not (isinstance(v, (list, tuple)) and all(ok(x) for x in v)):
            problems.append(f"{key}: must be a list of {what}, got {_shown(v)}")
    if "print_scale" in d and not _is_number(d["print_scale"]):
        problems.append(f"print_scale: must be a number, got {_shown(d['print_scale'])}")
    if "name" in d and not isinstance(d["name"], str):
        problems.append(f"name: must be a string, got {_shown(d['name'])}")
    seed = d.get("seed")
    if seed is not None and not (isinstance(seed, numbers.Integral) and not isinstance(seed, bool)):
        problems.append(f"seed: must be a whole number or null, got {_shown(seed)}")
    return problems


@dataclass(frozen=True)
class PartDims:
    """Dimensions of the printed parts, in millimetres (physical scale)."""

    link_width_mm: float = 12.0
    """Width of every link plate (across the link, in the plane of motion)."""
    link_thickness_mm: float = 6.0
    """Thickness of every link plate, along the joint axes."""
    layer_gap_mm: float = 0.4
    """Axial gap between neighbouring links, held by a printed spacer ring so they turn freely."""
    pin_diameter_mm: float = 4.0
    """Nominal pin shaft diameter."""
    pin_clearance_mm: float = 0.3
    """Radial clearance between the pin and its hole in the parent link (where the joint turns)."""
    press_fit_mm: float = 0.0
    """Radial clearance of the pin in the child link's hole; 0 is a press fit on FDM printers."""
    pin_head_diameter_mm: float = 7.0
    pin_head_height_mm: float = 2.0
    counterbore_extra_mm: float = 0.3
    """Extra depth and radius of the counterbore that sinks the pin head below the link face."""
    spacer_ring_diameter_mm: float = 8.0
    foot_size_mm: float = 100.0
    """Side of the square foot plate that the base post stands in."""
    foot_thickness_mm: float = 5.0
    socket_height_mm: float = 12.0
    """Height of the socket boss on the foot that holds the base post upright (above the plate)."""
    socket_wall_mm: float = 3.0
    socket_fit_mm: float = 0.15
    """Clearance per side between the base post and its socket."""

    @property
    def layer_pitch_mm(self) -> float:
        """Distance along the joint axes between the mid-planes of neighbouring links."""
        return self.link_thickness_mm + self.layer_gap_mm


@dataclass(frozen=True)
class PrinterSpec:
    """The printer the parts must fit and the rules they are checked against."""

    bed_x_mm: float = 200.0
    bed_y_mm: float = 200.0
    max_height_mm: float = 200.0
    min_wall_mm: float = 1.2
    min_clearance_mm: float = 0.1
    """Smallest radial clearance an ordinary FDM printer can hold open (below it, pins fuse)."""
    max_clearance_mm: float = 1.0
    """Largest radial clearance that still makes a usable joint."""
    pla_density_kg_m3: float = 1240.0
    infill: float = 0.2
    shell_thickness_mm: float = 0.8
    """Perimeters / top and bottom skins, used with `infill` for the mass model."""


@dataclass(frozen=True)
class ChainSpec:
    """A SPARE kinematic chain: a base (link 0) and n moving links joined by parallel revolute joints.

    Link i's length is the distance between its joint axes; for the base, table to first joint axis;
    for the last link, joint axis to tip. Every link lies in its own layer along the joint axes, so no
    two links can pass through each other whatever the joint angles.
    """

    n_links: int
    """Moving links (1..6)."""
    link_lengths_pu: tuple[float, ...]
    """n + 1 lengths in paper units, base first."""
    colors: tuple[str, ...]
    """n + 1 colour names from COLORS, base first."""
    print_scale: float = 0.08
    """Physical metres per paper metre (0.08: a 2.0 base is a 160 mm post)."""
    name: str = "spare_object"
    seed: int | None = None
    """The seed this chain was sampled with, if it was sampled."""
    parts: PartDims = field(default_factory=PartDims)
    printer: PrinterSpec = field(default_factory=PrinterSpec)

    def __post_init__(self) -> None:
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        problems = _type_problems(fields)
        for key, cls in (("parts", PartDims), ("printer", PrinterSpec)):
            if not isinstance(fields[key], cls):
                problems.append(f"{key}: must be a {cls.__name__}, got {_shown(fields[key])}")
                continue
            problems += [f"{key}.{f.name}: must be a number, got {_shown(getattr(fields[key], f.name))}"
                         for f in dataclasses.fields(cls) if not _is_number(getattr(fields[key], f.name))]  # fmt: skip
        if problems:
            raise SpareTwinError("; ".join(problems))
        # Coerce sequences so a spec built from JSON lists equals one built from tuples.
        object.__setattr__(self, "link_lengths_pu", tuple(float(x) for x in self.link_lengths_pu))
        object.__setattr__(self, "colors", tuple(self.colors))
        object.__setattr__(self, "print_scale", float(self.print_scale))
        object.__setattr__(self, "n_links", int(self.n_links))
        validate(self)

    # -- derived quantities -------------------------------------------------------------
    @property
    def link_lengths_mm(self) -> tuple[float, ...]:
        return tuple(length * self.print_scale * 1000.0 for length in self.link_lengths_pu)

    @property
    def layer_pitch_mm(self) -> float:
        return self.parts.layer_pitch_mm

    def label_lengths(self) -> np.ndarray:
        """The paper's 7-slot length label (paper units), zeros past the last link."""
        out = np.zeros(LABEL_SLOTS, dtype=np.float32)
        out[: self.n_links + 1] = self.link_lengths_pu
        return out

    # -- JSON round trip -----------------------------------------------------------------
    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d[LENGTHS_KEY] = list(self.link_lengths_pu)
        d["colors"] = list(self.colors)
        return d

    @classmethod
    def from_dict(cls, d: dict, source: str = "configuration") -> ChainSpec:
        """The spec a configuration describes; else one SpareTwinError naming `source` and every key at fault."""
        if not isinstance(d, dict):
            raise SpareTwinError(f"{source}: expected a JSON object")
        d = with_paper_lengths(d, source)
        known = {f.name for f in dataclasses.fields(cls)}
        problems = []
        unknown = sorted(_key(k) for k in set(d) - known - {"format", "derived"})
        if unknown:
            problems.append(f"unknown key(s) {', '.join(unknown)}")
        problems += [f"{k}: missing" for k in ("n_links", LENGTHS_KEY, "colors") if k not in d]
        problems += _type_problems(d)
        kwargs = {k: v for k, v in d.items() if k in known}
        for key, sub in (("parts", PartDims), ("printer", PrinterSpec)):
            if key in kwargs:
                kwargs[key], found = _sub(sub, kwargs[key], key)
                problems += found
        if problems:
            raise SpareTwinError(f"{source}: {'; '.join(problems)}")
        try:
            return cls(**kwargs)
        except SpareTwinError as exc:
            raise SpareTwinError(f"{source}: {exc}") from None

    def to_json(self) -> str:
        # repr-exact floats: json writes the shortest repr, which parses back to the same double.
        return json.dumps(self.to_dict(), indent=2, sort_keys=True) + "\n"

    @classmethod
    def from_json_file(cls, path: str | Path) -> ChainSpec:
        return cls.from_dict(read_json(path), source=str(path))


_old_key_said = False  # the note on a file from before 0.6.0 is said once per process


#: Physical metres per paper metre where a recording or `predict` is not told the print's: ChainSpec's.
DEFAULT_PRINT_SCALE = ChainSpec.print_scale


def with_paper_lengths(fields: Mapping, source: str) -> dict:
    """`fields` (object.json, a configuration, ground_truth.npz's arrays, a recording's object, ...) as a
    dict with the paper-unit lengths under LENGTHS_KEY only: the one reader of the key's older name.

    A file from before 0.6.0 names them DESIGN_CONTRACT_LENGTHS_KEY alone: still read, and the first such
    file a process reads says so in one line on stderr. object.json from 0.6.0 on holds both keys, which
    must agree: an edit to one of them alone would otherwise be ignored without a word."""
    global _old_key_said
    out = dict(fields)
    if DESIGN_CONTRACT_LENGTHS_KEY not in out:
        return out
    old = out.pop(DESIGN_CONTRACT_LENGTHS_KEY)
    if LENGTHS_KEY in out:
        if not _same_numbers(old, out[LENGTHS_KEY]):
            raise SpareTwinError(
                f"{source}: {DESIGN_CONTRACT_LENGTHS_KEY} and {LENGTHS_KEY} differ (the same paper-unit lengths "
                f"under the old and the new name: edit {LENGTHS_KEY} and remove {DESIGN_CONTRACT_LENGTHS_KEY})"
            )
        return out
    out[LENGTHS_KEY] = old
    if not _old_key_said:
        _old_key_said = True
        with contextlib.suppress(OSError, ValueError):  # a closed stderr cannot make reading fail
            print(
                f"note: {source}: old key {DESIGN_CONTRACT_LENGTHS_KEY} read as {LENGTHS_KEY} (paper units)",
                file=sys.stderr,
                flush=True,
            )
    return out


def _same_numbers(a, b) -> bool:
    try:
        return bool(np.array_equal(np.asarray(a, np.float64), np.asarray(b, np.float64)))
    except (TypeError, ValueError, OverflowError):  # not numbers: the type check names the key at fault
        return repr(a) == repr(b)


def _key(k) -> str:
    return k if isinstance(k, str) and k.isidentifier() else _shown(k)


def _sub(cls, value, key: str):
    """(the `cls` that the JSON object `value` describes, or None; the problems found, each naming key.field)."""
    if not isinstance(value, dict):
        return None, [f"{key}: must be a JSON object, got {_shown(value)}"]
    known = {f.name for f in dataclasses.fields(cls)}
    problems = [f"{key}: unknown key(s) {', '.join(sorted(_key(k) for k in set(value) - known))}"]
    problems = problems if set(value) - known else []
    problems += [f"{key}.{k}: must be a number, got {_shown(v)}" for k, v in value.items()
                 if k in known and not _is_number(v)]  # fmt: skip
    if problems:
        return None, problems
    return cls(**{k: float(v) for k, v in value.items()}), []


def min_between_axes_mm_of(parts: PartDims, printer: PrinterSpec = PrinterSpec()) -> float:
    """The shortest link between its two axes that can be printed with `parts`: between them sit the
    counterbore of one pin and the spacer ring of the other, and a wall."""
    return counterbore_diameter_mm(parts) / 2 + parts.spacer_ring_diameter_mm / 2 + printer.min_wall_mm


def validate(spec: ChainSpec) -> None:
    """Reject configurations that cannot be built or printed: one message naming every field at fault."""
    problems = _value_problems(spec)
    if problems:
        raise SpareTwinError("; ".join(problems))


def _value_problems(spec: ChainSpec) -> list[str]:
    out: list[str] = []

    def bad(field_name: str, problem: str) -> None:  # each starts with the field, so flags() can map the first
        out.append(f"{field_name}: {problem}")

    n = spec.n_links
    if not MIN_MOVING_LINKS <= n <= MAX_MOVING_LINKS:
        bad("n_links", f"{n} is out of range {MIN_MOVING_LINKS}..{MAX_MOVING_LINKS}")
    elif len(spec.link_lengths_pu) != n + 1:
        bad(LENGTHS_KEY, f"needs n_links + 1 = {n + 1} values (base first), got {len(spec.link_lengths_pu)}")
    for i, length in enumerate(spec.link_lengths_pu):
        if not math.isfinite(length) or length <= 0:
            bad(LENGTHS_KEY, f"link {i} length {length} must be positive")
            break
    if MIN_MOVING_LINKS <= n <= MAX_MOVING_LINKS and len(spec.colors) != n + 1:
        bad("colors", f"needs n_links + 1 = {n + 1} colour names, got {len(spec.colors)}")
    unknown = [c for c in spec.colors if c not in COLORS]
    if unknown:
        bad("colors", f"unknown colour {unknown[0]!r} (choose from {', '.join(COLORS)})")
    if not (math.isfinite(spec.print_scale) and spec.print_scale > 0):
        bad("print_scale", f"{spec.print_scale} must be a positive number")
    if not spec.name or not all(ch.isalnum() or ch in "_-" for ch in spec.name):
        bad("name", f"{_shown(spec.name)} must be non-empty letters, digits, '_' or '-'")
    if spec.seed is not None and not _is_seed(spec.seed):
        bad("seed", f"{spec.seed!r} must be a non-negative integer or null")
    p, pr = spec.parts, spec.printer
    for f in dataclasses.fields(p):
        v = getattr(p, f.name)
        if not math.isfinite(v) or (v < 0 if f.name in ("press_fit_mm",) else v <= 0):
            bad(f"parts.{f.name}", f"{v} must be positive")
    for f in dataclasses.fields(pr):
        v = getattr(pr, f.name)
        if f.name != "infill" and not (math.isfinite(v) and v > 0):
            bad(f"printer.{f.name}", f"{v} must be positive")
    if not 0 <= pr.infill <= 1:
        bad("printer.infill", f"{pr.infill} must be within 0..1")
    if out:  # what follows measures the design, which needs every field above in range
        return out

    if not pr.min_clearance_mm <= p.pin_clearance_mm <= pr.max_clearance_mm:
        bad(
            "parts.pin_clearance_mm",
            f"{p.pin_clearance_mm} mm cannot print as a turning joint "
            f"(needs {pr.min_clearance_mm}..{pr.max_clearance_mm} mm)",
        )
    if p.press_fit_mm >= p.pin_clearance_mm:
        bad("parts.press_fit_mm", "must be smaller than pin_clearance_mm, or the pin turns in the child too")
    for key, thickness in design_walls_mm(p).items():
        if thickness < pr.min_wall_mm - 1e-9:
            bad("parts", f"{WALL_NAMES[key]} is {thickness:.2f} mm, below the {pr.min_wall_mm} mm minimum wall")
    if (
        p.spacer_ring_diameter_mm > p.link_width_mm
        or p.spacer_ring_diameter_mm <= p.pin_diameter_mm + 2 * pr.min_wall_mm
    ):
        bad(
            "parts.spacer_ring_diameter_mm",
            "must lie between the pin (plus a minimum wall each side) and the link width",
        )
    lengths_mm = spec.link_lengths_mm
    min_between_axes_mm = min_between_axes_mm_of(p, pr)
    for i, length_mm in enumerate(lengths_mm[1:-1], start=1):
        if length_mm < min_between_axes_mm:
            bad(
                LENGTHS_KEY,
                f"link {i} is {length_mm:.1f} mm between axes at this print_scale, "
                f"below the {min_between_axes_mm:.1f} mm its joints need",
            )
            break
    if lengths_mm[-1] < p.link_width_mm / 2:
        bad(
            LENGTHS_KEY,
            f"the last link ({lengths_mm[-1]:.1f} mm) is shorter than half the link width at this print_scale",
        )
    if lengths_mm[0] < p.foot_thickness_mm + p.socket_height_mm + p.link_width_mm:
        bad(
            LENGTHS_KEY,
            f"the base ({lengths_mm[0]:.1f} mm) is too short to stand in its foot socket at this print_scale",
        )
    # Longest printed part: a link plate lying flat (its length plus the rounded ends).
    longest_mm = max(lengths_mm[0], max(lengths_mm[1:]) + p.link_width_mm / 2) + p.link_width_mm / 2
    if longest_mm > max(pr.bed_x_mm, pr.bed_y_mm) or p.foot_size_mm > min(pr.bed_x_mm, pr.bed_y_mm):
        bad(
            "print_scale",
            f"{spec.print_scale} makes a {longest_mm:.0f} mm part that does not fit the "
            f"{pr.bed_x_mm:.0f} x {pr.bed_y_mm:.0f} mm bed",
        )
    return out


#: The thinnest walls of the design, by their print_report.json key, and how an error names them.
WALL_NAMES = {
    "beside_pin_hole": "wall beside the pin hole",
    "beside_counterbore": "wall beside the counterbore",
    "under_counterbore": "floor under the counterbore",
    "pin_head_rim": "pin head rim",
    "socket_wall": "socket wall",
}


def design_walls_mm(p: PartDims) -> dict[str, float]:
    """The design's thinnest walls (mm), keyed as in WALL_NAMES; each must reach the printer's minimum."""
    return {
        "beside_pin_hole": (p.link_width_mm - (p.pin_diameter_mm + 2 * p.pin_clearance_mm)) / 2,
        "beside_counterbore": (p.link_width_mm - counterbore_diameter_mm(p)) / 2,
        "under_counterbore": p.link_thickness_mm - counterbore_depth_mm(p),
        "pin_head_rim": (p.pin_head_diameter_mm - p.pin_diameter_mm) / 2,
        "socket_wall": p.socket_wall_mm,
    }


def counterbore_diameter_mm(p: PartDims) -> float:
    return p.pin_head_diameter_mm + 2 * p.counterbore_extra_mm


def counterbore_depth_mm(p: PartDims) -> float:
    return p.pin_head_height_mm + p.counterbore_extra_mm


# -- sampling from the paper's distribution ---------------------------------------------


def sample_lengths(n_links: int, rng: np.random.Generator) -> tuple[float, ...]:
    """L'_0 ~ U[1.3, 2.0], L'_i ~ U[0.3, 1.0]; if the sum reaches 3, scale so it is exactly 3."""
    lengths = np.concatenate([rng.uniform(*BASE_LENGTH_RANGE, size=1), rng.uniform(*LINK_LENGTH_RANGE, size=n_links)])
    total = float(lengths.sum())
    if total >= MAX_TOTAL_LENGTH:
        lengths = lengths * (MAX_TOTAL_LENGTH / total)
    return tuple(float(x) for x in lengths)


def sample_chain(n_links: int | None = None, seed: int = 0, **overrides) -> ChainSpec:
    """A chain drawn from the paper's distribution; a pure function of (n_links, seed).

    With `n_links=None`, the count is drawn uniformly from 1..6 with the same generator.
    """
    if not _is_seed(seed):
        raise SpareTwinError(f"seed {seed!r}: must be a non-negative integer")
    rng = np.random.default_rng(seed)
    if n_links is None:
        n_links = int(rng.integers(MIN_MOVING_LINKS, MAX_MOVING_LINKS + 1))
    if not isinstance(n_links, int) or not MIN_MOVING_LINKS <= n_links <= MAX_MOVING_LINKS:
        _fail("n_links", f"{n_links} is out of range {MIN_MOVING_LINKS}..{MAX_MOVING_LINKS}")
    lengths = sample_lengths(n_links, rng)
    names = list(COLORS)
    colors = tuple(names[int(i)] for i in rng.integers(0, len(names), size=n_links + 1))
    kwargs = dict(name=f"spare_n{n_links}_s{seed}", seed=seed)
    kwargs.update(overrides)
    return ChainSpec(n_links=n_links, link_lengths_pu=lengths, colors=colors, **kwargs)
