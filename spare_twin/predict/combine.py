"""The network's answer overruled by the chain measured on its points (`spare_twin.measure`).

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

from dataclasses import replace

import torch

from spare_twin.measure.layers import LayerMeasurement
from spare_twin.measure.slots import LENGTH_SLOTS, measurement_slots
from spare_twin.predict.estimate import FIELDS, Estimate

__all__ = [
    "LENGTH_SLOTS",
    "MIN_HIDDEN_LINK_POINTS",
    "MIN_HIDDEN_LINK_PROBABILITY",
    "combined",
    "measurement_slots",
    "overrule",
]

#: A hidden last link (see the module doc): the network's count probability and the points in its layer.
MIN_HIDDEN_LINK_PROBABILITY = 0.7
MIN_HIDDEN_LINK_POINTS = 2


def _found_hidden(res: dict, slots: dict) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(measured count, found, hidden) per row: the measurement found a chain; the network is
    confident of one link more, whose layer holds some points (a hidden last link, the module doc)."""
    measured = torch.as_tensor(slots["measured_n"]).reshape(-1).to(res["pred_n"].device)
    found = measured > 0
    confident = res["probabilities"].max(1).values >= MIN_HIDDEN_LINK_PROBABILITY
    next_points = torch.as_tensor(slots["measured_next_points"]).reshape(-1).to(measured.device)
    hidden = found & (res["pred_n"] == measured + 1) & confident & (next_points >= MIN_HIDDEN_LINK_POINTS)
    return measured, found, hidden


def overrule(res: dict, slots: dict) -> dict:
    """`models.decode`'s output with each row's count, lengths and angles replaced by the measured
    ones where the measurement found a chain (`slots`: `measurement_slots`, batched as tensors)."""
    measured, found, hidden = _found_hidden(res, slots)
    net_n = res["pred_n"]
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


def combined(res: dict, m: LayerMeasurement, network: Estimate, measurement: Estimate) -> tuple[Estimate, dict | None]:
    """(answer, source) of one profile-network output (`res`, a batch of one) and the measurement of
    the same points: `overrule`'s answer, each field labelled with the estimate it came from. Where
    the measurement found no chain the network's estimate stands as it is (its own abstention
    included); where the measurement's points lie on no chain there is no answer."""
    if m.reason is not None or (m.n_links is not None and measurement.n_links is None):
        return Estimate.none(measurement.reason), None  # the points lie on no chain, or too weakly
    slots = {k: torch.as_tensor(v)[None] for k, v in measurement_slots(m).items()}
    measured, found, hidden = (bool(t[0]) if t.dtype == torch.bool else int(t[0]) for t in _found_hidden(res, slots))
    if not found:
        return network, (None if network.n_links is None else {f: "network" for f in FIELDS})
    if not hidden:
        return replace(measurement, evidence=None), {f: "measurement" for f in FIELDS}
    out = overrule(res, slots)
    n = int(out["pred_n"][0])
    lengths = tuple(float(v) for v in out["lengths_e2e"][0, : n + 1])
    angles = tuple(float(v) for v in out["angles"][0, :n])
    source = {
        "n_links": "network",
        "link_lengths_pu": tuple("measurement" if k <= measured else "network" for k in range(n + 1)),
        "joint_angles_rad": tuple("measurement" if k < measured else "network" for k in range(n)),
    }
    return Estimate(n, lengths, angles), source
