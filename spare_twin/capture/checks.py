"""Range checks for the capture tools' settings: one-line errors that start with the field's name, so a
command can say its own flag instead (`spare_twin.commands.common.flags`)."""

from __future__ import annotations

import math

from spare_twin.errors import SpareTwinError
from spare_twin.validate import check_whole


def _shown(value) -> str:
    return repr(value) if isinstance(value, str) else str(value)


def is_number(value) -> bool:
    """A finite int or float (bools are not numbers here)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def positive(name: str, value, upper: float | None = None) -> None:
    """`value` is a finite number > 0 (and <= `upper` when given)."""
    if not is_number(value) or value <= 0:
        raise SpareTwinError(f"{name} {_shown(value)}: must be a positive number")
    if upper is not None and value > upper:
        raise SpareTwinError(f"{name} {_shown(value)}: must be at most {upper:g}")


def fraction(name: str, value) -> None:
    """`value` is a finite number in [0, 1]."""
    if not is_number(value) or not 0 <= value <= 1:
        raise SpareTwinError(f"{name} {_shown(value)}: must be a number from 0 to 1")


def whole(name: str, value, minimum: int) -> None:
    """`value` is an int (not a bool) of at least `minimum`."""
    check_whole(name, value, minimum)
