"""Each estimate held to what its estimator can answer: no answer, with a reason, is better than a
wrong one. A network's count needs a clear winner among its classes and an input like the ones it
was trained on; the measurement's needs its points to lie on a chain."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from spare_twin.config import MAX_MOVING_LINKS, MAX_TOTAL_LENGTH, PartDims
from spare_twin.measure.layers import MAX_PAST_LAST_LAYER_FRACTION, LayerMeasurement
from spare_twin.observe.chain import ChainObservation
from spare_twin.predict.estimate import Estimate, MeasurementEvidence, NetworkEvidence
from spare_twin.predict.parts import TRAINED_PARTS, parts_words

#: A network's count stands only where its most probable class has at least this probability.
MIN_COUNT_PROBABILITY = 0.5
#: Fewer points on the links than this (the layers' points, base included) are too few to count a
#: chain by. Set on the 3 mm merge measured until release 0.6.19, at 100: a simulated hand-held capture
#: gave 800-1,500, the training rig's 96 x 128 views 800-900; single real frames of a shelf with no
#: chain, 29 and 69, on which the profile network said 6 links at p = 0.96 and 0.98. The layers are
#: now measured on the 2 mm merge (`PointsConfig.fine_voxel_m`), which holds (3 / 2)² as many points
#: on the same surface (1,600-2,900 on hand-held captures, about 1,800 in the rig).
MIN_CHAIN_POINTS = 225
#: Views that go less far round the chain than this (degrees about its base axis) see its plates from
#: one side: the profile network was trained on captures from at least 3 neighbouring cameras of an
#: 8-camera ring (90 deg and more), and the layer measurement was developed on such sweeps. Single
#: real frames and runs of up to 10 frames of a shelf (a 12 deg arc) measured chains of 4-6 links.
MIN_ARC_DEG = 60.0
#: A SPARE chain's lengths sum to at most `config.MAX_TOTAL_LENGTH` (3 paper units). A measured chain
#: whose lengths sum past this many times that is no chain's reading: its layers misread, or points
#: off the chain joined to it (held-out seed 31176: 1 link, a 120 deg sweep registered from its frames
#: alone, measured as 4 links summing to 5.64 at 9.9 mm RMS). Over the 759 answers of release
#: 0.6.30's measurement on the 480 development recordings and on seeds 31110-31205 (every side),
#: those counted right summed to 3.13 at the 99th percentile and 4.2 at most (clean renders of 30839
#: and 31187, a link stretched).
MAX_LENGTH_SUM_SHARE = 1.5


def _floats(values) -> tuple[float, ...]:
    return tuple(float(v) for v in values)


def network_estimate(
    res: dict,
    row: int,
    net,
    n_links: int | None = None,
    yaw_hypotheses_deg: tuple[float, ...] | None = None,
    yaw_deg: float | None = None,
) -> Estimate:
    """Row `row` of `models.decode`'s output as the network's estimate: its argmax count (or the
    given `n_links` for a lengths-only model), lengths and angles, its class probabilities as
    evidence; no count where those are not finite or no class reaches `MIN_COUNT_PROBABILITY`."""
    probabilities = _floats(res["probabilities"][row]) if "probabilities" in res else None
    evidence = NetworkEvidence(probabilities, yaw_hypotheses_deg, yaw_deg)
    if probabilities is not None:
        if not all(math.isfinite(p) for p in probabilities):
            return Estimate.none("the network's count probabilities are not finite numbers", evidence)
        k = int(np.argmax(probabilities))
        if probabilities[k] < MIN_COUNT_PROBABILITY:
            why = (
                f"the network's count evidence is too weak: its most probable count ({k + 1}) has p = "
                f"{probabilities[k]:.2f}, below {MIN_COUNT_PROBABILITY}"
            )
            return Estimate.none(why, evidence)
    n, lengths, angles = None, None, None
    if "pred_n" in res:
        n = int(res["pred_n"][row])
        if "lengths_e2e" in res:
            lengths = _floats(res["lengths_e2e"][row, : n + 1])
    elif "lengths_known" in res:
        n = int(n_links)
        lengths = _floats(res["lengths_known"][row, : n + 1])
    if "angles" in res and n:
        angles = _floats(res["angles"][row, :n])
    if n is None:
        return Estimate.none(f"{net.arch}: the model gives no count", evidence)
    if any(not math.isfinite(v) for v in (lengths or ()) + (angles or ())):
        return Estimate.none("the network's lengths or angles are not finite numbers", evidence)
    return Estimate(n, lengths, angles, evidence)


def note_parts(network: Estimate, parts: PartDims) -> Estimate:
    """The network's estimate, its evidence saying so where the chain was printed with other parts
    than the network was trained on (`predict.parts.TRAINED_PARTS`): the profile is drawn with the
    given parts' layer pitch, but the network never saw such plates, and its estimate is not held
    back for it (the measurement, which reads them, answers where it finds a chain)."""
    if parts == TRAINED_PARTS or not isinstance(network.evidence, NetworkEvidence):
        return network
    note = f"trained on the default parts only ({parts_words(TRAINED_PARTS)}), not these ({parts_words(parts)})"
    return dataclasses.replace(network, evidence=dataclasses.replace(network.evidence, other_parts=note))


def too_little_arc(arc_deg: float) -> str:
    """The reason for no answer from views that go `arc_deg` (< `MIN_ARC_DEG`) round the chain."""
    return f"the views go {arc_deg:g} deg round it, too little to tell its layers apart (at least {MIN_ARC_DEG:g} deg)"


def not_a_chain(obs: ChainObservation, m: LayerMeasurement) -> str | None:
    """Why the observed points are no chain to answer for, from the views and the measurement's
    evidence (for the network's estimate as for the measurement's: both read the same points), or None."""
    if obs.arc_deg is not None and obs.arc_deg < MIN_ARC_DEG:
        return too_little_arc(obs.arc_deg)
    total = int(sum(m.points_per_layer))
    if total < MIN_CHAIN_POINTS:
        return f"too few points on the chain to count its links ({total}; at least {MIN_CHAIN_POINTS})"
    past = int(m.points_per_layer[-1]) if len(m.points_per_layer) > MAX_MOVING_LINKS + 1 else 0
    if past > MAX_PAST_LAST_LAYER_FRACTION * total and not m.past_is_last_plate:
        return f"{past} of its {total} points lie past the sixth link's layer: it is thicker than any chain"
    return None


def hold_network(network: Estimate, obs: ChainObservation, m: LayerMeasurement) -> Estimate:
    """The network's estimate, or no answer where the points it read are no chain (`not_a_chain`)."""
    why = not_a_chain(obs, m)
    if why is None or network.n_links is None:
        return network
    return Estimate.none(f"no chain to count: {why}", network.evidence)


def count_not_told(m: LayerMeasurement) -> str:
    """The measurement's reason for no answer where a sweep's two registrations dispute its count
    (`LayerMeasurement.count_disputed`)."""
    return f"no count measured: {m.count_disputed}"


def measurement_estimate(obs: ChainObservation, m: LayerMeasurement) -> Estimate:
    """The layer measurement as an estimate, its RMS and points per layer as evidence; no answer
    where its points lie on no chain (its own `reason`, or `not_a_chain`) or a sweep's two
    registrations dispute its count (`count_not_told`)."""
    if obs.reason is not None:
        return Estimate.none(f"no chain in view: {obs.reason}")
    evidence = MeasurementEvidence(m.rms_m, tuple(int(p) for p in m.points_per_layer))
    why = not_a_chain(obs, m) if m.reason is None or obs.arc_deg < MIN_ARC_DEG else None
    if why is not None:
        return Estimate.none(f"no chain measured: {why}", evidence)
    if m.reason is not None:
        return Estimate.none(f"no chain measured: {m.reason}", evidence)
    if m.n_links is None:
        return Estimate.none("no chain measured: too few points off the base layer to count a link", evidence)
    total_pu = float(np.sum(m.lengths_pu))
    if total_pu > MAX_LENGTH_SUM_SHARE * MAX_TOTAL_LENGTH:
        reason = (
            f"no chain measured: the {m.n_links} links measured sum to {total_pu:.2f} paper units with the "
            f"base, more than {MAX_LENGTH_SUM_SHARE:g} x any chain's {MAX_TOTAL_LENGTH:g}: its layers were misread"
        )
        return Estimate.none(reason, evidence)
    if m.count_disputed is not None:
        return Estimate.none(count_not_told(m), evidence)
    angles = None if m.angles_rad is None else _floats(m.angles_rad)
    return Estimate(int(m.n_links), _floats(m.lengths_pu), angles, evidence)
