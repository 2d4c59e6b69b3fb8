"""A layer measurement as fixed-size arrays, the shape of a network's output heads, so that a
DataLoader batches it and `spare_twin.predict.combine.overrule` sets it beside the network's."""

from __future__ import annotations

import numpy as np

from spare_twin.config import MAX_MOVING_LINKS
from spare_twin.measure.layers import LayerMeasurement

#: 7 length slots and 6 angle slots, as the network's heads.
LENGTH_SLOTS = MAX_MOVING_LINKS + 1


def measurement_slots(m: LayerMeasurement) -> dict[str, np.ndarray]:
    """The measurement as fixed-size arrays (a DataLoader batches them): `measured_n` (0 = none),
    `measured_lengths_pu` (7, zero past the count) and `measured_angles_rad` (6)."""
    lengths = np.zeros(LENGTH_SLOTS, np.float32)
    angles = np.zeros(MAX_MOVING_LINKS, np.float32)
    n = m.n_links or 0
    if n:
        lengths[: n + 1] = m.lengths_pu
        angles[:n] = m.angles_rad
    return {
        "measured_n": np.int64(n),
        "measured_lengths_pu": lengths,
        "measured_angles_rad": angles,
    }
