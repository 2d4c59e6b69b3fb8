"""The chain of posed views measured: the observation (`observe.chain`) and its layer measurement
(`measure.layers`), with a registered sweep's views brought into register on the object and, where
they still fuse into no chain, its parts looked at alone (`measure_views`). Both read the chain with
the geometry of the parts it was printed with (`parts`: the default parts unless the user says)."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

from spare_twin.config import PartDims
from spare_twin.measure.layers import LayerMeasurement, LayersConfig, layers_told_apart, measure_profile
from spare_twin.observe.chain import ChainObservation, observations
from spare_twin.observe.on_object import register_on_object
from spare_twin.observe.points import PosedView
from spare_twin.observe.profile import ProfileConfig
from spare_twin.observe.views import REGISTERED_SWEEP, TRACKED_SWEEP, PosedViews, recording_views, sweep_part
from spare_twin.recording import Recording
from spare_twin.threads import side_by_side

#: What `ChainObservation.source` adds once a sweep's views were brought into register on the object.
ON_OBJECT = ", brought into register on the object"
#: `ChainObservation.source` of a sweep registered here without poses, then brought into register on the object.
ON_OBJECT_SWEEP = REGISTERED_SWEEP + ON_OBJECT
#: Parts of a registered sweep looked at again when the whole gives no chain (`measure_views`).
SWEEP_PARTS = ((0.0, 0.5), (0.5, 1.0), (0.25, 0.75))
#: Fewer registered frames than this are not split.
MIN_FRAMES_TO_SPLIT = 8
#: A part whose chain fits its points this well (RMS, metres) ends the search: the print's own
#: roughness and the sensor's noise leave 0.2-0.5 mm; a part still out of register leaves 5 mm and more.
CLEAN_PART_RMS_M = 0.002
#: Where a sweep's two registrations (as registered, and brought into register on the object) measure
#: chains of other counts, the closer's count is disputed unless the other holds its points more than
#: this many times farther (`LayerMeasurement.cost_m`; `count_told`). Over the 1,095 real captures of the
#: bench outputs kept from seeds 31254-32357 (development) the two counted otherwise 17 times, within
#: 1.25 x five times: three where the closer count was wrong (31571, 31661, 32080: 1.03-1.10 x; now no
#: answer) and two where it was right (31921, 1.08 x, whose network is sure of it: it stands; 31959,
#: 1.05 x at 9 mm RMS, no answer as before: its network was sure of the other, wrong count). Farther
#: apart, the closer count was right 9 times (1.26-14.7 x) and wrong 3 (1.38-3.66 x; one of them,
#: 31468, answered right by a network sure of more links).
MAX_DISAGREEING_COST_RATIO = 1.25


@dataclass(frozen=True)
class Geometry:
    """The observation's and the measurement's settings for one print's parts."""

    profile: ProfileConfig
    layers: LayersConfig


def measured_chain(
    rec: Recording,
    print_scale: float,
    frame: int | None = None,
    camera: str | None = None,
    progress: bool = False,
    parts: PartDims = PartDims(),
    min_arc_deg: float = 0.0,
) -> tuple[ChainObservation, LayerMeasurement]:
    """`measure_views` of a recording folder's views (`observe.views.recording_views`)."""
    seen = recording_views(rec, frame, camera, progress=progress)
    return measure_views(seen, print_scale, progress, min_arc_deg=min_arc_deg, parts=parts)


def measure_views(
    seen: PosedViews,
    print_scale: float,
    progress: bool = False,
    min_arc_deg: float = 0.0,
    parts: PartDims = PartDims(),
) -> tuple[ChainObservation, LayerMeasurement]:
    """The chain's observation in posed views and its layer measurement (`measure.layers.measure_profile`)
    with the geometry of `parts` (`ProfileConfig.for_parts`, `LayersConfig.for_parts`); the
    observation's `timings_s` gain "measurement", all summed over the tries.

    A sweep registered here is measured with its views brought into register on the object
    (`observe.on_object`): views that slipped by a degree or a few millimetres along the table blur the
    chain's 6.4 mm layers (a 2-link RealSense sweep fused 14.9 mm RMS off any chain as registered, 0.3
    mm after). Where both give a chain, the closer one is kept (`LayerMeasurement.cost_m`: RMS in the
    plane and across it): matching on the object can also pull apart a sweep that registration had in
    register (bench seed 30119, 6 links: 0.3 mm as registered, 2 links at 3.9 mm after; on the 120
    captures of seeds 30006-30125 this changed that count alone). Where the views as registered give no
    chain at all (the fused object too wide, not standing on a 12 mm column, or blurred centimetres off
    any chain), the registration is off by more than the object can pull back somewhere, and the sweep's
    parts are looked at too: its first half, its second half and its middle half, each registered on its
    own and brought into register on the object. Registration errors come in runs: a sweep's views slide
    apart along the table where the object shows little (a Kinect at a metre and more), and the half
    without that run fuses into one chain; so does the half of a sweep before (or after) the object was
    bumped. The try whose chain fits its points best (`_fit_rank`) is kept; one within
    `CLEAN_PART_RMS_M` ends the search. A tracked sweep, registered here from its tracker's poses
    (`observe.views`), is brought into register on the object the same way but not split
    (`observe.views` keeps none of its frames): the tracker holds the frames of every part where the
    whole put them (on the development captures no part of a tracked sweep read right where the whole
    did not), and a part of an empty table's sweep read its clutter as 5 links. Other views with poses
    (a rig, a sweep whose frames confirm its own poses, views given in memory) are looked at once. Views
    that go less than `min_arc_deg` round the chain are not measured (the fit is the slow part;
    `spare_twin.predict.abstain` gives no answer on them). The chain kept gives a count only where its
    layers are told apart (`measure.layers.layers_told_apart`); a sweep's two registrations that count
    otherwise, each holding its points about as closely, dispute it (`count_told`)."""
    geometry = Geometry(ProfileConfig.for_parts(parts), LayersConfig.for_parts(parts))
    found, measured = _best_try(seen, print_scale, progress, min_arc_deg, geometry)
    return found, layers_told_apart(measured, geometry.layers)


def _best_try(
    seen: PosedViews, print_scale: float, progress: bool, min_arc_deg: float, geometry: Geometry
) -> tuple[ChainObservation, LayerMeasurement]:
    """The tries of `measure_views`, and the one kept."""
    views = list(seen.views)

    def measured_as_registered():
        return _measured(views, seen.source, seen.registration_s, print_scale, geometry, min_arc_deg)

    if seen.source not in (REGISTERED_SWEEP, TRACKED_SWEEP):
        return measured_as_registered()

    def measured_on_object():
        return _on_object(views, seen.source, seen.registration_s, print_scale, geometry)

    # the two readings are independent: side by side (a goal-sized sweep's 2.9 s and 1.7 s of work)
    readings = side_by_side(lambda read: read(), [measured_on_object, measured_as_registered])
    (on_object, measured), as_registered = readings
    seconds = _add(on_object.timings_s, as_registered[0].timings_s, but="registration")
    if as_registered[1].n_links is not None or seen.frames is None or len(views) < MIN_FRAMES_TO_SPLIT:
        best, other = sorted(((on_object, measured), as_registered), key=_fit_rank)
        return dataclasses.replace(best[0], timings_s=seconds), count_told(best[1], other[1])
    # as registered the sweep fused into no chain: brought into register on the object the whole
    # sweep stands where it fits cleanly, else the closest of its parts
    why = "the whole did not fuse into one chain"
    best = None if measured.n_links is None else (on_object, measured)
    for part in SWEEP_PARTS:
        if best is not None and best[1].rms_m <= CLEAN_PART_RMS_M:
            break
        part_views = sweep_part(seen, part, progress)
        piece, m = _on_object(
            list(part_views.views), REGISTERED_SWEEP, part_views.registration_s, print_scale, geometry
        )
        seconds = _add(seconds, piece.timings_s)
        if m.n_links is not None and (best is None or _fit_rank((piece, m)) < _fit_rank(best)):
            share = f"frames {100 * part[0]:.0f}-{100 * part[1]:.0f} % of the sweep"
            best = (dataclasses.replace(piece, source=f"{piece.source}, {share}: {why}"), m)
    found, measured = best or as_registered
    return dataclasses.replace(found, timings_s=seconds), measured


def _on_object(views: list[PosedView], source: str, registration_s: float, print_scale: float, geometry: Geometry):
    """(observation, measurement) of registered views (`source`) brought into register on the object
    (`observe.on_object`); the time that takes is registration, after `registration_s` spent before."""
    t0 = time.perf_counter()
    on_object = register_on_object(views)
    registration_s += time.perf_counter() - t0
    return _measured(on_object, source + ON_OBJECT, registration_s, print_scale, geometry)


def _measured(
    views: list[PosedView],
    source: str,
    registration_s: float,
    print_scale: float,
    geometry: Geometry,
    min_arc_deg: float = 0.0,
) -> tuple[ChainObservation, LayerMeasurement]:
    """(observation, measurement) of the first thing on the table whose profile may be a chain's
    (`observe.chain.observations`), or, where it measures as no chain, of the first after it that
    stands nearer where the cameras look and measures as a chain. A cylinder or a box of clutter seen
    from one side can pass the profile's checks and outrank the chain by its points (bench seeds
    31126, 31149 and 31180: one 18-23 cm out, measured 15-18 mm RMS off any chain; the chain behind it,
    within 3 cm of the aim, 0.2-0.4 mm). Only nearer: clutter measures as a chain of 1-4 links often
    enough (13 of the 25 such things on 48 tables of seeds 30822-30845, 1.5-8 mm RMS) that a chain the
    capture is aimed at is never passed over for it. The source names a thing passed over."""
    first, measurement_s, tried = None, 0.0, 0
    for seen in observations(views, source, registration_s, print_scale, profile_cfg=geometry.profile):
        if first is not None and seen.object.off_aim_m >= first[0].object.off_aim_m:
            continue
        found, measured = _measure(seen, print_scale, geometry, min_arc_deg)
        tried += 1
        measurement_s += found.timings_s["measurement"]
        first = first or (found, measured)
        if measured.n_links is not None or _too_short_an_arc(seen, min_arc_deg):
            break  # views that go too little round one thing go too little round the others
    if measured.n_links is None:
        found, measured = first
    elif tried > 1:
        passed = "a chain-like thing nearer the aim than the first, which measured as no chain"
        found = dataclasses.replace(found, source=f"{found.source}; {passed}")
    return dataclasses.replace(found, timings_s={**found.timings_s, "measurement": round(measurement_s, 3)}), measured


def measured_at_count(
    seen: ChainObservation, print_scale: float, count: int, parts: PartDims = PartDims()
) -> LayerMeasurement:
    """The chain of an observation that `measure_views` measured with fewer links, measured again at
    `count` links (`measure.layers.measure_layers`'s `at_count`), held to layers told apart."""
    layers_cfg = LayersConfig.for_parts(parts)
    return layers_told_apart(measure_profile(seen.object, seen.profile, print_scale, layers_cfg, count), layers_cfg)


def closest_passed(m: LayerMeasurement, parts: PartDims = PartDims()) -> LayerMeasurement | None:
    """Where the reading of `m` did not settle, the closest chain its checks passed through
    (`LayerMeasurement.closest_passed`), held to layers told apart; else None."""
    if m.closest_passed is None:
        return None
    return layers_told_apart(m.closest_passed, LayersConfig.for_parts(parts))


def _too_short_an_arc(seen: ChainObservation, min_arc_deg: float) -> bool:
    return seen.arc_deg is not None and seen.arc_deg < min_arc_deg


def _fit_rank(found: tuple[ChainObservation, LayerMeasurement]) -> tuple[bool, float]:
    """Sort key of a try: a measured chain before none, then the chain closer to its points in the plane
    and across it (`LayerMeasurement.cost_m`); ties keep the first."""
    m = found[1]
    return (m.n_links is None, m.cost_m if m.n_links is not None else 0.0)


def count_told(kept: LayerMeasurement, other: LayerMeasurement) -> LayerMeasurement:
    """`kept`, the closer of a sweep's two registrations' chains (`_fit_rank`), with the other kept on it
    (`LayerMeasurement.other_registration`) where the other counts otherwise and holds its points about
    as closely (`MAX_DISAGREEING_COST_RATIO`): neither registration tells the count (`predict` then
    answers only with a network sure of the closer count or of more links)."""
    if kept.n_links is None or other.n_links is None or other.n_links == kept.n_links:
        return kept
    if other.cost_m > MAX_DISAGREEING_COST_RATIO * kept.cost_m:
        return kept
    return dataclasses.replace(kept, other_registration=other)


def _add(a: dict, b: dict, but: str | None = None) -> dict:
    """Per-step seconds of two tries summed (`but`: that step's from `a` alone)."""
    return {k: round(a[k] + (0.0 if k == but else b[k]), 3) for k in a}


def _measure(
    seen: ChainObservation, print_scale: float, geometry: Geometry, min_arc_deg: float = 0.0
) -> tuple[ChainObservation, LayerMeasurement]:
    t0 = time.perf_counter()
    if seen.reason is not None:
        measured = LayerMeasurement(None, None, None, ())
    elif _too_short_an_arc(seen, min_arc_deg):
        why = f"not measured: the views go {seen.arc_deg:g} deg round it (at least {min_arc_deg:g})"
        measured = LayerMeasurement(None, None, None, (), reason=why)
    else:
        measured = measure_profile(seen.object, seen.profile, print_scale, geometry.layers)
    timings = {**seen.timings_s, "measurement": round(time.perf_counter() - t0, 3)}
    return dataclasses.replace(seen, timings_s=timings), measured
