"""The network's answer overruled by the chain measured on its points (`spare_twin.measure`).

The yaw-free network reads a 64 x 80 profile image; the measurement reads every point and the
layer each lies in, so where it finds a chain its count, lengths and angles are the answer and the
network's stand only where it finds none (too few points off the base layer) or the network is sure
of more links (below). Measured on the held-out seed-1 test split and on hand-held-like views
(docs/observe.md): the network alone counted 0.80 of them right, the measurement 0.97..1.00.
`predict` answers with `combined`; `evaluate`'s batches with `overrule`, the same choice without
`predict`'s abstentions (the rig's test split is scored on every instance), so its figures are
those of `predict` wherever `predict` answers, but for one thing: where the network's count stands
over a lower measured one, `predict` measures the chain again at the network's count (below) and
`evaluate`, whose batches carry the measurement's slots and not the points, keeps the network's
lengths (3 of the rig's 3,000 test instances, 1177, 1178 and 1180: `predict`'s E_L there 0.031,
0.414 and 0.009 against the network's 0.060, 0.084 and 0.074).

Since release 0.6.36 the lengths and angles where the network's count stands over the measured one
are those of the chain measured again at that count (`measure.layers` with `at_count`: a layer
split where its plate centres step up the likeliest, `MEASURED_AT_NETWORK_COUNT` in `source`), not
the network's: on the eight such captures of the development recordings (bench seeds 30870-31493,
every side, and the rig's test split) the network's lengths were 0.06-0.08 paper units squared off
(E_L) in the rig and 0.006-0.048 on the bench; measured again, 0.006-0.031 on six of them, 0.008 for
0.006 on one (31277's clean render) and 0.414 on the rig's instance 1178, whose measured chain was
44 mm too long before any split.

Releases 0.6.6-0.6.11 gave no answer where the two counted otherwise and the measured chain fitted
its points looser than 1.5 mm RMS (a blurred capture, where either might be the one that is right).
On hand-held captures the network alone counts 0.67-0.71 right, and with the measurement of release
0.6.10 on, its dissent was no evidence: on 252 captures with every effect (the 180 development
captures of `dataset --handheld --seed 1` and the real sides of bench seeds 30318-30389, now
development) that rule turned 9 right counts and 1 wrong one into no answer (docs/sim2real.md). Both
estimates are still in `predict`'s output, the network's beside the answer.

Since release 0.6.26 the network's count stands where it is sure of it (`NETWORK_OVERRULES_P`) and
the measurement counts otherwise or cannot tell its layers apart (`LayerMeasurement.layers_blurred`);
where the points lie on no chain, nothing stands. The network that earned it reads the levelled profile
with its mirror image (`measure.level`, `models.decode_mirrored`): 0.94-0.98 alone on hand-held
captures where release 0.6.10's read 0.67-0.71. On 838 development recordings (the real, clean-render
and rig sides of bench seeds 30438-30565 (69 objects) and 30678-30869) it was that sure of another
count 4 times and right each time (30563, 30842 real; 30441, 30821 clean renders), and sure of its count
where the layers blurred 3 times, right each time (30867 real and clean renders, 30773 rig); the
network's confident wrong answers there were on points that lie on no chain (30762 real: 6 links at
p = 0.99 for 1, the points 16 mm off any chain), which stay unanswered. Below 0.95 it is not safe:
it dissented 4 times at 0.84-0.88 and was wrong 3 of them (30809, 30856 real; 30461 clean renders).

Release 0.6.33 asked the network to be surer (0.99) to take a link away than to add one. Since
release 0.6.34 a network sure of fewer links than the measurement found layers for leaves no
answer: `predict` answers nothing and names the disagreement, and `evaluate`'s batches keep the
measured count. The measurement's own failure is to count too few (two links in
one layer, a short or dark last link with no layer of its own); a layer it counted holds that
link's points. Over every bench recording kept (seeds 30006-31349, every side), the networks at
>= 0.95 counted fewer links than the measurement 52 times and were right 5 (the measurement right
47); the network shipped since 30822 did so 4 times on bench rounds and twice on the diagnostic
tables of 30822-30845: right at p 0.991 and 0.997 (30842, 30829 real), wrong at 0.950, 0.955,
0.966 and 0.9986 (30995 rig, 30843, 31261 and 31327 real). Where two estimates that are right this
often disagree this surely the evidence does not hold: no answer costs the two right ones and takes
away four wrong ones. On the held-out rounds after (seeds 31350-31541, 576 recordings) it fired once,
on a clean render, where the network's 2 at p = 0.997 was right and the measured 4 wrong (31477).
Since release 0.6.42 that holds only where the measured chain's last layer is thin: it holds under
a third of the points of its other moving layers (their median, `MAX_DISPUTED_LAYER_SHARE`); over
a full last layer the measured count stands. The measurement's wrong extra link is a few stray points
read a layer up; a layer as full as the others is a link the network missed. Over every bench
recording kept since release 0.6.32 (seeds 31254-32069, every side) the network was sure of fewer
links than the measurement 9 times. The measured last layer held 0.08, 0.15 and 0.20 of the others'
points where the network was right (31675, 31477, 31750, capture's clean renders: still no answer).
Where it was wrong the share was 0.23 once (31327 real: still no answer, the measured 2 right) and
0.51-1.04 five times (31261, 31647, 31763, 31903 real; 31913 clean render): the measured count now
answers those, right each time.

Counting more links than the measurement at >= 0.95 the network was right each time (3 of 3 with the
shipped network before the rounds of seeds 31350-31541, each where the measurement merged two links' layers; 2 of 2
in them), and it stands.

Since release 0.6.45 a count a sweep's two registrations dispute (as registered and brought into
register on the object, each measuring a chain of another count, the looser within 1.25 x of the
closer: `measure.chain.count_told`) is answered only by a network sure of the closer registration's
count or of more links (as it stands over any measured count), else not at all. On the 1,095 real
captures kept from bench seeds 31254-32357 (development) this took three wrong counts away (31571,
31661, 32080: the closer registration's count wrong, the network unsure) and kept 31921's right one
(its network sure of the closer count); 31959 stays unanswered (its network sure of the looser,
lower count, wrong, where 0.6.42's rule left no answer before).

Since release 0.6.46 a layer just above the measured chain that did not count (at least 12 points,
too few for a link or spread narrower than a plate's width: `measure.layers.count_links`) and lies
mostly off the last link's plate (`MAX_ABOVE_ON_LAST_PLATE`) leaves no answer where the network
reads one link more: two weak signs of a link the count missed. On the 1,296 real captures kept
from bench seeds 31254-32549 (development) such a layer came with a count 24 times. Off the plate 3
times, each a link the count missed: 31841 and 32489 (0.68 and 0.58 on the plate; 6 links counted
5, the network reading 6 at p = 0.59 and 0.60: now no answer) and 32080 (0.73; 5 counted 3, no
answer already). On it (0.86-1.0) 21 times: no link 19 times, a link twice (31996, 32357, whose
counts stand, wrong).
Among the stored answers of every side of seeds 31254-32549 one more lay off the plate: 32080's
clean render (0.69), where it was no link and the network read the measured 5: that count stands.

Since release 0.6.48 a layer reading that did not settle (its checks ended on a chain more than
`measure.layers.MAX_LOOSENING` times looser than the closest one they passed through) answers with
that closest chain where the network is sure of its count: the count then rests on two estimators
that agree, the lengths and angles on the closest chain. In the 62 bench outputs kept (seeds
20000-33413, development, every side: 10,224 recordings) the measurement's final reading did not
settle 5 times: the closest chain's count was right 3 times, and the network was sure of it twice
(33017 real, 31559 rig: both now right); the network was unsure (32189, clean render; 33377 real) or
sure of another count (31133, clean render) elsewhere, and those stay unanswered.

Until release 0.6.4 the network's count stood where it was confident of exactly one link more than
the measurement (a last link hidden behind the others). On the bench's captures with a real print's
and sensor's effects that rule made three right counts wrong and no wrong one right (seeds 30034,
30051, 30098 of 96), and on the rig's test split it changed nothing (docs/observe.md).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from spare_twin.measure.layers import LayerMeasurement
from spare_twin.measure.slots import LENGTH_SLOTS, measurement_slots
from spare_twin.predict.abstain import count_not_told
from spare_twin.predict.estimate import FIELDS, Estimate, NetworkEvidence

__all__ = [
    "CLOSEST_PASSED",
    "LENGTH_SLOTS",
    "MEASURED_AT_NETWORK_COUNT",
    "NETWORK_OVERRULES_P",
    "combined",
    "measurement_slots",
    "network_count_over",
    "overrule",
]

#: The network's count stands against a measured count it exceeds, or where the measurement cannot
#: tell its layers apart, when its most probable count has at least this probability; sure of fewer
#: links than were measured, it leaves no answer (module docstring).
NETWORK_OVERRULES_P = 0.95
#: A network sure of fewer links than were measured leaves no answer only where the measured chain's
#: last layer holds less than this share of the median points of its other moving layers (module
#: docstring: where it was right the share was 0.08-0.20, where it was wrong 0.23-1.04).
MAX_DISPUTED_LAYER_SHARE = 1.0 / 3.0
#: A layer just above the measured chain that did not count (`LayerMeasurement.above_on_last_plate`)
#: with under this share of its points on the last link's plate may be a link of its own seen in few
#: points: where the network reads that link more, the count is not told (module docstring). As
#: `LayersConfig.max_top_inside_parent`: a top layer this much on its parent's plate is the parent's.
MAX_ABOVE_ON_LAST_PLATE = 0.8
#: The source of the lengths and angles of a chain measured again at the count the network is sure
#: of, over the measurement's lower one (`combined`).
MEASURED_AT_NETWORK_COUNT = "measurement at the network's count"
#: The source of the lengths and angles of the closest chain a layer reading that did not settle
#: passed through, where the network is sure of its count (`combined`).
CLOSEST_PASSED = "measurement's closest chain (its reading did not settle)"


def overrule(res: dict, slots: dict) -> dict:
    """`models.decode`'s output with each row's count, lengths and angles replaced by the measured
    ones where the measurement found a chain and the network is not sure of more links (`slots`:
    `measurement_slots`, batched as tensors). Where `predict` would answer nothing because the
    network is sure of fewer links, the measured count stands: every instance is scored. Where the
    network's count stands, its lengths and angles stay (`predict` measures the points again there,
    or answers the closest chain of a reading that did not settle; the slots hold neither)."""
    measured = torch.as_tensor(slots["measured_n"]).reshape(-1).to(res["pred_n"].device)
    sure = res["probabilities"].max(1).values >= NETWORK_OVERRULES_P
    found = (measured > 0) & ~(sure & (res["pred_n"] > measured))
    out = dict(res)
    out["pred_n"] = torch.where(found, measured, res["pred_n"])
    lengths = torch.as_tensor(slots["measured_lengths_pu"]).reshape(len(found), -1).to(res["lengths_e2e"])
    out["lengths_e2e"] = torch.where(found[:, None], lengths, res["lengths_e2e"])
    if "angles" in res:
        angles = torch.as_tensor(slots["measured_angles_rad"]).reshape(len(found), -1).to(res["angles"])
        out["angles"] = torch.where(found[:, None], angles, res["angles"])
    return out


def network_count_over(m: LayerMeasurement, network: Estimate, measurement: Estimate) -> int | None:
    """The network's count where it stands over a lower count the measurement found on points that
    lie on a chain (`combined`): the count the chain is measured again at (`measure.chain.measured_at_count`);
    else None."""
    if m.layers_blurred or m.reason is not None or m.n_links is None or measurement.n_links is None:
        return None
    return network.n_links if _sure(network) and network.n_links > measurement.n_links else None


def combined(
    m: LayerMeasurement,
    network: Estimate,
    measurement: Estimate,
    at_network_count: Estimate | None = None,
    closest_passed: Estimate | None = None,
) -> tuple[Estimate, dict | None]:
    """(answer, source) of the profile network's estimate and the measurement `m` of the same points,
    each field labelled with the estimate it came from: the measurement's answer where it found a
    chain, unless the network is sure of more links (`NETWORK_OVERRULES_P`: the network's count, and
    the lengths and angles of the chain measured again at it, `at_network_count`, where that found
    one) or of fewer (then no answer); where the measurement found no chain the network's estimate as
    it is (its own abstention included), and where it cannot tell the chain's layers apart the
    network's only where it is sure; where a sweep's two registrations dispute the count
    (`LayerMeasurement.count_disputed`), the network's only where it is sure of the closer count or of
    more links; where the layers' reading did not settle, the closest chain it passed through
    (`closest_passed`) where the network is sure of its count; where a layer above the measured chain
    lies off its last plate and the network reads one link more (`MAX_ABOVE_ON_LAST_PLATE`), and
    where the points lie on no chain, no answer."""
    everything_network = None if network.n_links is None else {f: "network" for f in FIELDS}
    if m.layers_blurred:
        return (network, everything_network) if _sure(network) else (Estimate.none(measurement.reason), None)
    if m.count_disputed is not None and measurement.reason == count_not_told(m):
        # a sweep's two registrations count otherwise: a network sure of the closer one's count tells
        # it, as one sure of more links stands over any measured count; one sure of fewer does not
        if _sure(network) and network.n_links >= m.n_links:
            return network, everything_network
        return Estimate.none(measurement.reason), None
    if closest_passed is not None and _sure(network) and network.n_links == closest_passed.n_links:
        # a reading that did not settle passed through a chain of the count the network is sure of:
        # two estimators of their own agree on it (module docstring)
        source = {f: "network" if f == "n_links" else CLOSEST_PASSED for f in FIELDS}
        return replace(closest_passed, evidence=None), source
    if m.reason is not None or (m.n_links is not None and measurement.n_links is None):
        return Estimate.none(measurement.reason), None  # the points lie on no chain, or too weakly
    if network_count_over(m, network, measurement) is not None:
        if at_network_count is not None and at_network_count.n_links == network.n_links:
            source = {f: "network" if f == "n_links" else MEASURED_AT_NETWORK_COUNT for f in FIELDS}
            return replace(at_network_count, evidence=None), source
        return network, everything_network
    if m.n_links is None:
        return network, everything_network
    if _sure(network) and network.n_links < measurement.n_links and _thin_last_layer(m):
        return Estimate.none(_disagreement(network, m)), None
    if network.n_links == m.n_links + 1 and _link_above(m):
        return Estimate.none(_link_above_reason(network, m)), None
    return replace(measurement, evidence=None), {f: "measurement" for f in FIELDS}


def _sure(network: Estimate) -> bool:
    """Whether the network gives a count it is sure of (`NETWORK_OVERRULES_P`)."""
    evidence = network.evidence
    if network.n_links is None or not isinstance(evidence, NetworkEvidence) or evidence.probabilities is None:
        return False
    return max(evidence.probabilities) >= NETWORK_OVERRULES_P


def _last_layer_share(m: LayerMeasurement) -> float:
    """The measured chain's last layer's points over the median of its other moving layers' points."""
    others = [int(k) for k in m.points_per_layer[1 : m.n_links]]
    return int(m.points_per_layer[m.n_links]) / max(float(np.median(others)), 1.0)


def _thin_last_layer(m: LayerMeasurement) -> bool:
    """Whether the measured chain's last layer is thin enough to be stray points read a layer up
    (`MAX_DISPUTED_LAYER_SHARE`); a chain of one link has no other layer to weigh it by."""
    return m.n_links >= 2 and _last_layer_share(m) < MAX_DISPUTED_LAYER_SHARE


def _link_above(m: LayerMeasurement) -> bool:
    """Whether a layer above the measured chain that did not count lies mostly off its last plate
    (`MAX_ABOVE_ON_LAST_PLATE`): a plate of its own, not the last one's points read a layer up."""
    return m.above_on_last_plate is not None and m.above_on_last_plate < MAX_ABOVE_ON_LAST_PLATE


def _link_above_reason(network: Estimate, m: LayerMeasurement) -> str:
    return (
        f"the measurement counted {m.n_links} link(s), under a layer too thin to count of which"
        f" {1 - m.above_on_last_plate:.0%} lies off the last link's plate, and the network reads"
        f" {network.n_links}: the count is not told"
    )


def _disagreement(network: Estimate, m: LayerMeasurement) -> str:
    p = max(network.evidence.probabilities)
    return (
        f"the network is sure of {network.n_links} link(s) (p = {p:.3f}) where the measurement found"
        f" {m.n_links}, whose last layer holds {_last_layer_share(m):.2f} of the points of the others:"
        " the two disagree"
    )
