"""What a real print and a real sensor add to a capture: one typed configuration, `CaptureEffects`.

Each effect is a named switch (`EFFECTS`) with its ranges beside it; everything it draws comes from a
seeded stream of its own (`effect_rng`), so switching one effect on or off never changes what another
draws, and a render without effects is byte-identical to one made before effects existed. The
defaults (every effect on, ranges from datasheets and papers: docs/sensor_effects.md) are the bench's;
`spare-twin render` starts from `NO_EFFECTS` and switches on what `--effects` names.

Where each effect is applied:
- object physics (`joint_play`, `print_error`): a perturbed copy of the object's URDF per capture
  (`spare_twin.sim.print_physics`);
- the sensor (`shadows`, `flying_pixels`, `dark_plastic`): on each clean depth image, before the
  depth-noise model (`spare_twin.sim.active_sensor`); `principal_point`: the camera's intrinsics;
- the hand and the desk (`hand`, `pose_error`, `clutter`): the hand-held path, the poses a tracker
  reports, the objects on the table (`spare_twin.sim.render_effects`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from spare_twin.config import COLORS
from spare_twin.errors import SpareTwinError
from spare_twin.io import read_json

#: The effects, in the order they are documented; each is a bool field of `CaptureEffects`.
EFFECTS = (
    "joint_play",
    "print_error",
    "shadows",
    "flying_pixels",
    "dark_plastic",
    "principal_point",
    "hand",
    "pose_error",
    "clutter",
)

#: Sub-streams of the render seed, one per effect (never the motion's, path's or noise's streams).
_STREAM = {name: 0xEF00 + i for i, name in enumerate(EFFECTS)}


def effect_rng(seed: int, effect: str, *more: int) -> np.random.Generator:
    """The generator of one effect for one render seed (and, for per-frame draws, camera and frame)."""
    return np.random.default_rng([seed, _STREAM[effect], *more])


def _range(v) -> bool:
    return (
        isinstance(v, tuple)
        and len(v) == 2
        and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)
        and v[0] <= v[1]
    )


@dataclass(frozen=True)
class CaptureEffects:
    """The physical effects of a printed object, an active depth sensor, a hand and a desk.

    Every effect is on by default (the sim-to-real bench's setting); `NO_EFFECTS` is the plain render.
    Ranges (lo, hi) are drawn uniformly; a range with lo == hi is a fixed value."""

    # -- the printed object -------------------------------------------------------------------------
    joint_play: bool = True
    """Each pin joint's radial clearance lets its link tilt out of the chain's plane and shift in it."""
    joint_tilt_deg: tuple[float, float] = (1.0, 4.0)
    """Magnitude of each link's tilt out of the chain's plane (random sign), degrees."""
    joint_shift_mm: float = 0.3
    """Largest in-plane shift of each joint centre (the pin's radial clearance), millimetres."""
    print_error: bool = True
    """The print is not the CAD: a whole-object scale error, and the object standing off level."""
    scale_error: tuple[float, float] = (-0.005, -0.002)
    """Relative scale error of the whole object (PLA shrinks 0.2-0.5 %)."""
    level_error_deg: tuple[float, float] = (0.0, 0.5)
    """How far the object stands off level (random direction), degrees."""
    # -- the active depth sensor --------------------------------------------------------------------
    shadows: bool = True
    """No depth where the projector (or second imager) cannot see: a band beside each depth edge on the
    side away from it."""
    baseline_m: float | None = None
    """Projector / second-imager offset along the image's +x axis, metres; None: the noise model's
    sensor's own (`SENSOR_BASELINE_M`), 5 cm for a clean render."""
    flying_pixels: bool = True
    """Along depth edges, readings between the foreground and the background (mixed pixels)."""
    flying_prob: float = 0.6
    """Chance that a pixel on either side of a depth edge reads a mixed depth."""
    flying_band_px: float = 1.5
    """Width of the mixed band on each side of an edge, in pixels at 640 wide (scaled to the image)."""
    dark_plastic: bool = True
    """Dark filament absorbs the projector's infrared: its links return only part of their pixels."""
    dark_colors: tuple[str, ...] = ("black", "indigo")
    """The filament colours that read as dark."""
    dark_return: tuple[float, float] = (0.3, 0.6)
    """Fraction of a dark link's pixels that still read a depth (drawn once per capture)."""
    principal_point: bool = True
    """The principal point off the image centre (a real sensor's calibration)."""
    principal_offset_px: float = 8.0
    """Largest offset of the principal point on each axis, in pixels at 640 wide (scaled)."""
    # -- the hand and the desk ----------------------------------------------------------------------
    hand: bool = True
    """A hand-held camera's distance and height vary more along the sweep, and it rolls more."""
    radius_wander_m: float = 0.10
    """Peak slow change of the camera's horizontal distance (the plain path: 5 cm)."""
    height_wander_m: float = 0.10
    """Peak slow change of the camera's height (the plain path: 6 cm)."""
    roll_deg: float = 12.0
    """Peak slow roll about the optical axis (the plain path: 4 degrees)."""
    pose_error: bool = True
    """A tracker's poses are approximate: the recorded hand-held poses are off the true ones (the true
    ones stay in the ground truth)."""
    pose_error_deg: float = 0.3
    """Std of each recorded pose's rotation error, degrees."""
    pose_error_mm: float = 3.0
    """Std of each recorded pose's position error per axis, millimetres."""
    clutter: bool = True
    """Other objects on the table, some a few centimetres from the chain."""
    clutter_count: tuple[int, int] = (2, 5)
    """How many boxes and cylinders stand on the table (at least `--clutter N` where that is more)."""
    clutter_gap_m: float = 0.03
    """Least horizontal gap between an item and the chain's footprint (the plain desk: 2 cm, 12 cm out)."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):  # JSON gives lists: ranges are tuples
            v = getattr(self, f.name)
            if isinstance(v, list):
                object.__setattr__(self, f.name, tuple(v))

    # -- switches ------------------------------------------------------------------------------------
    @property
    def on(self) -> tuple[str, ...]:
        """The effects switched on, in `EFFECTS` order."""
        return tuple(name for name in EFFECTS if getattr(self, name))

    @property
    def active(self) -> bool:
        return bool(self.on)

    def only(self, names) -> CaptureEffects:
        """The same ranges with exactly the effects `names` on."""
        names = set(names)
        return dataclasses.replace(self, **{name: name in names for name in EFFECTS})

    def validate(self, param: str = "effects") -> None:
        """One-line errors naming `param` and the field at fault."""

        def bad(field: str, why: str) -> SpareTwinError:
            return SpareTwinError(f"{param}: {field} {getattr(self, field)!r}: {why}")

        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name in EFFECTS:
                if not isinstance(v, bool):
                    raise bad(f.name, "must be true or false")
            elif f.name == "dark_colors":
                if not isinstance(v, tuple) or any(c not in COLORS for c in v):
                    raise bad(f.name, f"must be colour names among {', '.join(COLORS)}")
            elif f.name == "baseline_m":
                if v is not None and not (_number(v) and abs(v) <= 0.5):
                    raise bad(f.name, "must be a number of metres within -0.5..0.5, or null")
            elif f.name == "clutter_count":
                if not (_range(v) and all(isinstance(x, int) for x in v) and 0 <= v[0] and v[1] <= 8):
                    raise bad(f.name, "must be two whole numbers lo <= hi within 0..8")
            elif isinstance(f.default, tuple):
                if not _range(v):
                    raise bad(f.name, "must be two finite numbers lo <= hi")
            elif not (_number(v) and v >= 0):
                raise bad(f.name, "must be a non-negative number")
        limits = {
            "joint_tilt_deg": (0, 15),
            "scale_error": (-0.1, 0.1),
            "level_error_deg": (0, 10),
            "dark_return": (0, 1),
        }
        for field, (lo, hi) in limits.items():
            v = getattr(self, field)
            if v[0] < lo or v[1] > hi:
                raise bad(field, f"must lie within {lo}..{hi}")
        for field, hi in (("flying_prob", 1.0), ("joint_shift_mm", 5.0), ("pose_error_deg", 10.0)):
            if getattr(self, field) > hi:
                raise bad(field, f"must be at most {hi}")

    def to_dict(self) -> dict:
        """JSON form: the switches that are on and the ranges of those (what a recording's source keeps)."""
        d = dataclasses.asdict(self)
        return {"on": list(self.on), **{k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items()}}

    @classmethod
    def from_dict(cls, d: dict, source: str = "effects") -> CaptureEffects:
        """From `to_dict`'s form or a recording's `source.effects` (its "on" and "drawn" are ignored:
        the switches are the bool fields); a missing field keeps its default."""
        if not isinstance(d, dict):
            raise SpareTwinError(f"{source}: expected a JSON object")
        d = {k: v for k, v in d.items() if k not in ("on", "drawn")}
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(str(k) for k in set(d) - known)
        if unknown:
            raise SpareTwinError(f"{source}: unknown key(s) {', '.join(unknown)}")
        effects = cls(**d)
        effects.validate(source)
        return effects


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


#: No effect at all: the plain render (every existing recording's bytes).
NO_EFFECTS = CaptureEffects().only(())
#: Every effect with its default ranges: the sim-to-real bench's setting.
ALL_EFFECTS = CaptureEffects()


def parse_effects(text: str, param: str = "effects", base: CaptureEffects = ALL_EFFECTS) -> CaptureEffects:
    """`all`, `none`, or a comma-separated list of effect names -> `base`'s ranges with those on; or a
    JSON file (`CaptureEffects.from_dict`: switches and ranges, e.g. a recording's `source.effects`)."""
    text = str(text).strip()
    if text.endswith(".json"):
        return CaptureEffects.from_dict(read_json(text), source=text)
    if text == "all":
        return base.only(EFFECTS)
    if text in ("none", ""):
        return base.only(())
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise SpareTwinError(f"{param} {unknown[0]!r}: no such effect (choose all, none or from {', '.join(EFFECTS)})")
    return base.only(names)
