"""The profile levelled by the layers' comb: what the profile network reads (release 0.6.25).

Joint play leans each link 1-4 deg out of the chain's plane, and the leans add up along the chain,
so a long chain's last links sit a layer or more off their k pitches; a plane found a little off
adds to it. The profile image's layer channel (`observe.profile.draw_profile`: each cell's mean t)
then shows the top link a layer off, and the profile network, which reads where the layers sit
across the plane, counts that layer: on the captures of 69 development objects it counted right all
41 whose top layer was the count and 15 of the other 28 (docs/nets.md). What joint play does not
change is local: near any point the plates are whole pitches apart. The comb followed along the
chain (`measure.plates`, step 1 of `measure.layers`) reads that, as a zero across the plane that
moves smoothly with the leans and the plane's error and by nothing at a joint. Taken out of every
point's t, it leaves each link at about its own layer and the steps between links whole.

So the network's input is the profile drawn again with that zero taken out (`levelled_image`): its
count is still its own (the measurement's count, fit and checks are not in it), but its input is
no longer the points alone; `predict` names it so. Where no comb was followed (no base column),
the image is the profile as observed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from spare_twin.observe.points import ObjectPoints
from spare_twin.observe.profile import ChainProfile, ProfileConfig, draw_profile


@dataclass(frozen=True)
class CombZero:
    """The followed comb's zero across the chain's plane at the measured points (profile frame)."""

    sz_m: np.ndarray
    """(N, 2) float64: the measured points in the plane (s, z)."""
    zero_t_m: np.ndarray
    """(N,) float64: where the comb's layer 0 lies across the plane (t) near each of them."""

    @classmethod
    def of_reading(
        cls,
        points_stz_m: np.ndarray,
        flip: np.ndarray,
        plate_t_m: np.ndarray,
        centre_layers: np.ndarray,
        pitch_m: float,
    ) -> CombZero:
        """The zero of a reading of the points `points_stz_m` (in the measurement's frame, which is the
        profile's times `flip`): each point's plate centre `plate_t_m` less its `centre_layers` pitches."""
        zero = (plate_t_m - centre_layers * pitch_m) * flip[1]
        return cls(np.asarray(points_stz_m[:, [0, 2]] * flip[[0, 2]], np.float64), np.asarray(zero, np.float64))

    def levelled_t_m(self, s_m: np.ndarray, t_m: np.ndarray, z_m: np.ndarray) -> np.ndarray:
        """`t_m` less the zero at the nearest measured point in the plane (below the measured
        points, the foot: the base column's)."""
        if not len(self.zero_t_m):
            return t_m
        _, nearest = cKDTree(self.sz_m).query(np.stack([s_m, z_m], 1))
        return t_m - self.zero_t_m[nearest]


def levelled_image(
    obj: ObjectPoints, profile: ChainProfile, zero: CombZero | None, print_scale: float, cfg: ProfileConfig
) -> np.ndarray:
    """The profile image of the observation's points with the comb's `zero` taken out of their t (the
    profile's own image where there is no zero or no chain)."""
    if zero is None or profile.reason is not None or not len(obj.points_m):
        return profile.image
    p = profile.in_profile_frame(obj.points_m)
    t_m = zero.levelled_t_m(p[:, 0], p[:, 1], p[:, 2])
    return draw_profile(p[:, 0] / print_scale, p[:, 2] / print_scale, t_m / cfg.layer_pitch_m, cfg)
