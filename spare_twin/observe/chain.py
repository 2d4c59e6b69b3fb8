"""Posed views as the yaw-free network's input and the measurement's: views -> object points -> chain profile.

`observe_views` goes through the same `observe.points` and `observe.profile` code as the training
samples (`spare_twin.nets.profile_samples`), whatever made the views (a rig, a hand-held sweep, a
live stream; `observe.views` reads them from a recording folder). `chains_on_table` lists, of the
things standing on the table, those that are a chain as far as their profile tells. Nothing reads an
object configuration or ground truth.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass, field, replace

import numpy as np

from spare_twin.observe.points import ObjectPoints, PointsConfig, PosedView, object_candidates
from spare_twin.observe.profile import ChainProfile, ProfileConfig, chain_profile


@dataclass(frozen=True)
class ChainObservation:
    """What the yaw-free network and the measurement are shown of the views, and how it was made."""

    object: ObjectPoints
    profile: ChainProfile
    source: str
    """Where the views came from (`observe.views.PosedViews.source`), and, once the measurement
    brought them into register on the object (`spare_twin.measure.chain`), which part of a sweep."""
    views: int
    timings_s: dict = field(default_factory=dict)
    """"registration" and "observation" seconds."""
    arc_deg: float | None = None
    """How far round the chain's base axis the cameras went: 360 less the widest gap between their
    azimuths (0 for one view); None where no chain was found."""

    @property
    def reason(self) -> str | None:
        """Why there is no chain to measure, or None."""
        return self.profile.reason

    @property
    def T_world_profile(self) -> np.ndarray:
        """The profile frame (base on the table, x = s, y = t, z up) in the views' world."""
        return self.object.T_world_table @ self.profile.T_table_profile


def chains_on_table(
    views: list[PosedView],
    print_scale: float,
    points_cfg: PointsConfig = PointsConfig(),
    profile_cfg: ProfileConfig = ProfileConfig(),
    max_candidates: int = 6,
) -> Iterator[tuple[ObjectPoints, ChainProfile]]:
    """(object, profile) of each thing on the table, best first (`object_candidates`, the first
    `max_candidates`), that is a chain as far as its profile tells (`chain_profile`); where none is,
    the first alone, with its reason. Lazily: a caller that takes the first profiles no more. A box of
    clutter beside a thin chain holds more points than the chain: where its profile gives it away it is
    passed over here; where not, the measurement tells (`spare_twin.measure.chain`)."""
    any_chain, first_refused = False, None
    for obj in object_candidates(views, points_cfg)[:max_candidates]:
        profile = chain_profile(obj, print_scale, profile_cfg)
        if profile.reason is None:
            any_chain = True
            yield obj, profile
        elif first_refused is None:
            first_refused = (obj, profile)
    if not any_chain and first_refused is not None:
        yield first_refused


def find_chain(views: list[PosedView], print_scale: float, *args, **kwargs) -> tuple[ObjectPoints, ChainProfile]:
    """The first of `chains_on_table` (its arguments)."""
    return next(chains_on_table(views, print_scale, *args, **kwargs))


def observations(
    views: list[PosedView],
    source: str,
    registration_s: float,
    print_scale: float,
    points_cfg: PointsConfig = PointsConfig(),
    profile_cfg: ProfileConfig = ProfileConfig(),
) -> Iterator[ChainObservation]:
    """The observation of each of `chains_on_table`, best first, lazily; each timed from the start
    (its "observation" seconds include those of the things before it); `registration_s`: the seconds
    already spent placing the views."""
    t0 = time.perf_counter()
    for obj, profile in chains_on_table(views, print_scale, points_cfg, profile_cfg):
        timings = {"registration": round(registration_s, 3), "observation": round(time.perf_counter() - t0, 3)}
        seen = ChainObservation(obj, profile, source, len(views), timings)
        if profile.reason is not None:
            yield seen
        else:
            yield replace(seen, arc_deg=arc_round_deg(views, seen.T_world_profile))
        t0 = time.perf_counter() - timings["observation"]  # the caller's time between is not ours


def observe_views(views: list[PosedView], source: str, registration_s: float, *args, **kwargs) -> ChainObservation:
    """The chain's observation in posed views: the first of `observations` (its arguments)."""
    return next(observations(views, source, registration_s, *args, **kwargs))


def arc_round_deg(views: list[PosedView], T_world_axis: np.ndarray) -> float:
    """How far round the z axis of `T_world_axis` the views' cameras go (degrees): 360 less the
    widest gap between their azimuths about it; 0 for one view."""
    T_axis_world = np.linalg.inv(T_world_axis)
    centres = np.array([T_axis_world[:3, :3] @ v.T_world_camera[:3, 3] + T_axis_world[:3, 3] for v in views])
    azimuths = np.sort(np.degrees(np.arctan2(centres[:, 1], centres[:, 0])))
    if len(azimuths) < 2:
        return 0.0
    gaps = np.diff(np.append(azimuths, azimuths[0] + 360.0))
    return round(float(360.0 - gaps.max()), 1)
