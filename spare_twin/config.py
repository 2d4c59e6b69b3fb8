"""Chain configuration: the SPARE object model, its sampling distribution and printing parameters.

Everything downstream (CAD, URDF, simulation, dataset labels) is a pure function of a `ChainSpec`,
so `object.json` (its JSON form) is enough to rebuild every output file bit for bit.

Units: `link_lengths_pu` are paper units (paper metres, the scale the paper's metrics use);
`print_scale` is physical metres per paper metre; part dimensions are millimetres (`*_mm`),
as in the STL files a slicer reads.
"""

from __future__ import annotations

import dataclasses
import json
import math
import numbers
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spare_twin.errors import SpareTwinError

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


def _is_seed(seed) -> bool:
    # numpy integers count too: seeds are often derived with numpy (SeedSequence words)
    return isinstance(seed, numbers.Integral) and not isinstance(seed, bool) and seed >= 0


def _fail(field_name: str, problem: str) -> None:
    raise SpareTwinError(f"invalid chain configuration: {field_name}: {problem}")


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
        # Coerce sequences so a spec built from JSON lists equals one built from tuples.
        object.__setattr__(self, "link_lengths_pu", tuple(float(x) for x in self.link_lengths_pu))
        object.__setattr__(self, "colors", tuple(str(c) for c in self.colors))
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
        # object.json names the paper-unit lengths `link_lengths_m` (docs/design.md); the key keeps its place.
        d = {("link_lengths_m" if k == "link_lengths_pu" else k): v for k, v in dataclasses.asdict(self).items()}
        d["link_lengths_m"] = list(self.link_lengths_pu)
        d["colors"] = list(self.colors)
        return d

    @classmethod
    def from_dict(cls, d: dict, source: str = "configuration") -> ChainSpec:
        if not isinstance(d, dict):
            raise SpareTwinError(f"{source}: expected a JSON object")
        known = {f.name for f in dataclasses.fields(cls)} - {"link_lengths_pu"} | {"link_lengths_m"}
        unknown = sorted(set(d) - known - {"format", "derived"})
        if unknown:
            raise SpareTwinError(f"{source}: unknown key(s) {', '.join(unknown)}")
        missing = [k for k in ("n_links", "link_lengths_m", "colors") if k not in d]
        if missing:
            raise SpareTwinError(f"{source}: missing key(s) {', '.join(missing)}")
        kwargs = {("link_lengths_pu" if k == "link_lengths_m" else k): v for k, v in d.items() if k in known}
        try:
            if "parts" in kwargs:
                kwargs["parts"] = _sub(PartDims, kwargs["parts"], f"{source}: parts")
            if "printer" in kwargs:
                kwargs["printer"] = _sub(PrinterSpec, kwargs["printer"], f"{source}: printer")
            return cls(**kwargs)
        except SpareTwinError as exc:
            raise SpareTwinError(f"{source}: {exc}") from None
        except TypeError as exc:  # wrong value types from hand-written JSON
            raise SpareTwinError(f"{source}: {exc}") from None

    def to_json(self) -> str:
        # repr-exact floats: json writes the shortest repr, which parses back to the same double.
        return json.dumps(self.to_dict(), indent=2, sort_keys=True) + "\n"

    @classmethod
    def from_json_file(cls, path: str | Path) -> ChainSpec:
        path = Path(path)
        try:
            d = json.loads(path.read_text())
        except FileNotFoundError:
            raise SpareTwinError(f"{path}: no such file") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise SpareTwinError(f"{path}: not valid JSON ({exc})") from None
        return cls.from_dict(d, source=str(path))


def _sub(cls, value, source):
    if not isinstance(value, dict):
        raise SpareTwinError(f"{source}: expected a JSON object")
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(value) - known)
    if unknown:
        raise SpareTwinError(f"{source}: unknown key(s) {', '.join(unknown)}")
    for k, v in value.items():
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            raise SpareTwinError(f"{source}: {k} must be a number")
    return cls(**{k: float(v) for k, v in value.items()})


def validate(spec: ChainSpec) -> None:
    """Reject configurations that cannot be built or printed, naming the offending field."""
    n = spec.n_links
    if not isinstance(n, int) or isinstance(n, bool):
        _fail("n_links", f"must be an integer, got {n!r}")
    if not MIN_MOVING_LINKS <= n <= MAX_MOVING_LINKS:
        _fail("n_links", f"{n} is out of range {MIN_MOVING_LINKS}..{MAX_MOVING_LINKS}")
    if len(spec.link_lengths_pu) != n + 1:
        _fail("link_lengths_m", f"needs n_links + 1 = {n + 1} values (base first), got {len(spec.link_lengths_pu)}")
    for i, length in enumerate(spec.link_lengths_pu):
        if not math.isfinite(length) or length <= 0:
            _fail("link_lengths_m", f"link {i} length {length} must be positive")
    if len(spec.colors) != n + 1:
        _fail("colors", f"needs n_links + 1 = {n + 1} colour names, got {len(spec.colors)}")
    for c in spec.colors:
        if c not in COLORS:
            _fail("colors", f"unknown colour {c!r} (choose from {', '.join(COLORS)})")
    if not (isinstance(spec.print_scale, (int, float)) and math.isfinite(spec.print_scale) and spec.print_scale > 0):
        _fail("print_scale", f"{spec.print_scale} must be a positive number")
    if not spec.name or not all(ch.isalnum() or ch in "_-" for ch in spec.name):
        _fail("name", f"{spec.name!r} must be non-empty letters, digits, '_' or '-'")
    if spec.seed is not None and not _is_seed(spec.seed):
        _fail("seed", f"{spec.seed!r} must be a non-negative integer or null")

    p, pr = spec.parts, spec.printer
    for f in dataclasses.fields(p):
        v = getattr(p, f.name)
        if not math.isfinite(v) or (v < 0 if f.name in ("press_fit_mm",) else v <= 0):
            _fail(f"parts.{f.name}", f"{v} must be positive")
    if not pr.min_clearance_mm <= p.pin_clearance_mm <= pr.max_clearance_mm:
        _fail(
            "parts.pin_clearance_mm",
            f"{p.pin_clearance_mm} mm cannot print as a turning joint "
            f"(needs {pr.min_clearance_mm}..{pr.max_clearance_mm} mm)",
        )
    if p.press_fit_mm >= p.pin_clearance_mm:
        _fail("parts.press_fit_mm", "must be smaller than pin_clearance_mm, or the pin turns in the child too")
    for key, thickness in design_walls_mm(p).items():
        if thickness < pr.min_wall_mm - 1e-9:
            _fail("parts", f"{WALL_NAMES[key]} is {thickness:.2f} mm, below the {pr.min_wall_mm} mm minimum wall")
    if (
        p.spacer_ring_diameter_mm > p.link_width_mm
        or p.spacer_ring_diameter_mm <= p.pin_diameter_mm + 2 * pr.min_wall_mm
    ):
        _fail(
            "parts.spacer_ring_diameter_mm",
            "must lie between the pin (plus a minimum wall each side) and the link width",
        )
    for f in dataclasses.fields(pr):
        v = getattr(pr, f.name)
        if f.name != "infill" and not (math.isfinite(v) and v > 0):
            _fail(f"printer.{f.name}", f"{v} must be positive")
    if not 0 <= pr.infill <= 1:
        _fail("printer.infill", f"{pr.infill} must be within 0..1")
    lengths_mm = spec.link_lengths_mm
    # Between two axes of one link sit the counterbore of one pin and the spacer ring of the other.
    min_between_axes_mm = counterbore_diameter_mm(p) / 2 + p.spacer_ring_diameter_mm / 2 + pr.min_wall_mm
    for i, length_mm in enumerate(lengths_mm[1:-1], start=1):
        if length_mm < min_between_axes_mm:
            _fail(
                "link_lengths_m",
                f"link {i} is {length_mm:.1f} mm between axes at this print_scale, "
                f"below the {min_between_axes_mm:.1f} mm its joints need",
            )
    if lengths_mm[-1] < p.link_width_mm / 2:
        _fail(
            "link_lengths_m",
            f"the last link ({lengths_mm[-1]:.1f} mm) is shorter than half the link width at this print_scale",
        )
    if lengths_mm[0] < p.foot_thickness_mm + p.socket_height_mm + p.link_width_mm:
        _fail(
            "link_lengths_m",
            f"the base ({lengths_mm[0]:.1f} mm) is too short to stand in its foot socket at this print_scale",
        )
    # Longest printed part: a link plate lying flat (its length plus the rounded ends).
    longest_mm = max(lengths_mm[0], max(lengths_mm[1:]) + p.link_width_mm / 2) + p.link_width_mm / 2
    if longest_mm > max(pr.bed_x_mm, pr.bed_y_mm) or p.foot_size_mm > min(pr.bed_x_mm, pr.bed_y_mm):
        _fail(
            "print_scale",
            f"{spec.print_scale} makes a {longest_mm:.0f} mm part that does not fit the "
            f"{pr.bed_x_mm:.0f} x {pr.bed_y_mm:.0f} mm bed",
        )


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
