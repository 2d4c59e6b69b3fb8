"""The network's answer overruled by the chain measured on its points (`spare_twin.measure`).

The yaw-free network reads a 64 x 80 profile image; the measurement reads every point and the
layer each lies in, so where it finds a chain its count, lengths and angles are the answer and the
network's stand only where it finds none (too few points off the base layer). Measured on the
held-out seed-1 test split and on hand-held-like views (docs/observe.md): the network alone counted
0.80 of them right, the measurement 0.97..1.00. `predict` answers with `combined`; `evaluate`'s
batches with `overrule`, the same choice without `predict`'s abstentions (the rig's test split is
scored on every instance), so its figures are those of `predict` wherever `predict` answers.

Releases 0.6.6-0.6.11 gave no answer where the two counted otherwise and the measured chain fitted
its points looser than 1.5 mm RMS (a blurred capture, where either might be the one that is right).
On hand-held captures the network alone counts 0.67-0.71 right, and with the measurement of release
0.6.10 on, its dissent was no evidence: on 252 captures with every effect (the 180 development
captures of `dataset --handheld --seed 1` and the real sides of bench seeds 30318-30389, now
development) that rule turned 9 right counts and 1 wrong one into no answer (docs/sim2real.md). Both
estimates are still in `predict`'s output, the network's beside the answer.

Until release 0.6.4 the network's count stood where it was confident of exactly one link more than
the measurement (a last link hidden behind the others). On the bench's captures with a real print's
and sensor's effects that rule made three right counts wrong and no wrong one right (seeds 30034,
30051, 30098 of 96), and on the rig's test split it changed nothing (docs/observe.md).
"""

from __future__ import annotations

from dataclasses import replace

import torch

from spare_twin.measure.layers import LayerMeasurement
from spare_twin.measure.slots import LENGTH_SLOTS, measurement_slots
from spare_twin.predict.estimate import FIELDS, Estimate

__all__ = ["LENGTH_SLOTS", "combined", "measurement_slots", "overrule"]


def overrule(res: dict, slots: dict) -> dict:
    """`models.decode`'s output with each row's count, lengths and angles replaced by the measured
    ones where the measurement found a chain (`slots`: `measurement_slots`, batched as tensors)."""
    measured = torch.as_tensor(slots["measured_n"]).reshape(-1).to(res["pred_n"].device)
    found = measured > 0
    out = dict(res)
    out["pred_n"] = torch.where(found, measured, res["pred_n"])
    lengths = torch.as_tensor(slots["measured_lengths_pu"]).reshape(len(found), -1).to(res["lengths_e2e"])
    out["lengths_e2e"] = torch.where(found[:, None], lengths, res["lengths_e2e"])
    if "angles" in res:
        angles = torch.as_tensor(slots["measured_angles_rad"]).reshape(len(found), -1).to(res["angles"])
        out["angles"] = torch.where(found[:, None], angles, res["angles"])
    return out


def combined(m: LayerMeasurement, network: Estimate, measurement: Estimate) -> tuple[Estimate, dict | None]:
    """(answer, source) of the profile network's estimate and the measurement `m` of the same points: the
    measurement's answer where it found a chain, each field labelled with the estimate it came from.
    Where the measurement found no chain the network's estimate stands as it is (its own abstention
    included); where the measurement's points lie on no chain there is no answer."""
    if m.reason is not None or (m.n_links is not None and measurement.n_links is None):
        return Estimate.none(measurement.reason), None  # the points lie on no chain, or too weakly
    if m.n_links is None:
        return network, (None if network.n_links is None else {f: "network" for f in FIELDS})
    return replace(measurement, evidence=None), {f: "measurement" for f in FIELDS}
