"""Moved: the combination of a network's answer with the measurement is `spare_twin.predict.combine`
(above nets), the measurement as arrays `spare_twin.measure.slots`. Kept importable until nothing
imports it from here."""

from spare_twin.measure.slots import LENGTH_SLOTS, measurement_slots  # noqa: F401
from spare_twin.predict.combine import overrule  # noqa: F401
