"""The network's answer overruled by the chain measured on its points (`observe.layers`).

The yaw-free network reads a 64 x 80 profile image; the measurement reads every point and the
layer each lies in, so where it finds a chain its count, lengths and angles are the answer and the
network's stand only where it finds none (too few points off the base layer). One exception: a last
link hidden behind the others leaves a few points in its layer, too few to count; where the network
is confident of exactly one link more than the measurement and that layer holds some points, the
count is the network's, the last link's length and angle its too. Measured on the
held-out seed-1 test split and on hand-held-like views (docs/observe.md): the network alone counted
0.80 of them right, the measurement 0.97..1.00. `predict` and `evaluate` use this one function, so
the figures `evaluate` gives are those of `predict`.
"""

from __future__ import annotations

import numpy as np
import torch

from spare_twin.config import MAX_MOVING_LINKS
from spare_twin.observe.layers import LayerMeasurement

#: 7 length slots and 6 angle slots, as the network's heads.
LENGTH_SLOTS = MAX_MOVING_LINKS + 1
#: A hidden last link (see the module doc): the network's count probability and the points in its layer.
MIN_HIDDEN_LINK_PROBABILITY = 0.7
MIN_HIDDEN_LINK_POINTS = 2


def measurement_slots(m: LayerMeasurement) -> dict[str, np.ndarray]:
    """The measurement as fixed-size arrays (a DataLoader batches them): `measured_n` (0 = none),
    `measured_lengths_pu` (7, zero past the count) and `measured_angles_rad` (6)."""
    lengths = np.zeros(LENGTH_SLOTS, np.float32)
    angles = np.zeros(MAX_MOVING_LINKS, np.float32)
    n = m.n_links or 0
    if n:
        lengths[: n + 1] = m.lengths_pu
        angles[:n] = m.angles_rad
    next_points = m.points_per_layer[n + 1] if n and n + 1 < len(m.points_per_layer) else 0
    return {
        "measured_n": np.int64(n),
        "measured_lengths_pu": lengths,
        "measured_angles_rad": angles,
        "measured_next_points": np.int64(next_points),
    }


def overrule(res: dict, slots: dict) -> dict:
    """`models.decode`'s output with each row's count, lengths and angles replaced by the measured
    ones where the measurement found a chain (`slots`: `measurement_slots`, batched as tensors)."""
    measured = torch.as_tensor(slots["measured_n"]).reshape(-1).to(res["pred_n"].device)
    found = measured > 0
    net_n = res["pred_n"]
    confident = res["probabilities"].max(1).values >= MIN_HIDDEN_LINK_PROBABILITY
    next_points = torch.as_tensor(slots["measured_next_points"]).reshape(-1).to(measured.device)
    hidden = found & (net_n == measured + 1) & confident & (next_points >= MIN_HIDDEN_LINK_POINTS)
    slot = torch.arange(LENGTH_SLOTS, device=measured.device)[None]
    measured_slots = slot <= measured[:, None]  # the base and the measured links
    out = dict(res)
    out["pred_n"] = torch.where(found & ~hidden, measured, net_n)
    lengths = torch.as_tensor(slots["measured_lengths_pu"]).reshape(len(found), -1).to(res["lengths_e2e"])
    mixed = torch.where(measured_slots, lengths, res["lengths_e2e"])
    out["lengths_e2e"] = torch.where(hidden[:, None], mixed, torch.where(found[:, None], lengths, res["lengths_e2e"]))
    if "angles" in res:
        angles = torch.as_tensor(slots["measured_angles_rad"]).reshape(len(found), -1).to(res["angles"])
        mixed = torch.where(measured_slots[:, 1:], angles, res["angles"])
        out["angles"] = torch.where(hidden[:, None], mixed, torch.where(found[:, None], angles, res["angles"]))
    return out
