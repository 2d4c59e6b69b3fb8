"""Synthetic chains of link plates as a depth sensor sees them, in the profile frame (s, t, z; t across
the chain's plane): both faces of every plate, a stadium (its centre line thickened by half a width,
rounded ends around the pins), less what another plate in front of it hides. Where two plates
overlap at a pin, the +t side sees the child's face and the -t side the parent's, so a joint stands
a layer thicker than a plate, as on a printed chain (`spare_twin.measure.joints`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spare_twin.measure.fit import distance_to_segment

HALF_WIDTH_M = 0.006
HALF_THICKNESS_M = 0.003


@dataclass(frozen=True)
class Plate:
    """A link plate: its centre line from `a` to `b` in the plane (s, z) and its centre across the
    plane, `t_at_a_m` at `a`, leaning by `lean_rad` (t grows along the line)."""

    a: np.ndarray
    b: np.ndarray
    t_at_a_m: float
    lean_rad: float = 0.0

    def along_m(self, sz: np.ndarray) -> np.ndarray:
        ab = self.b - self.a
        return (sz - self.a) @ ab / max(float(np.linalg.norm(ab)), 1e-12)

    def covers(self, sz: np.ndarray) -> np.ndarray:
        return distance_to_segment(sz, self.a, self.b) <= HALF_WIDTH_M

    def centre_t_m(self, sz: np.ndarray) -> np.ndarray:
        return self.t_at_a_m + np.sin(self.lean_rad) * self.along_m(sz)


def chain_faces(plates: list[Plate], spacing_m: float, rng=None, noise_m: float = 0.0, with_plates: bool = False):
    """(points (N, 3) s, t, z, view directions (N, 3)) of the plates' visible faces, sampled on a
    grid of `spacing_m` with Gaussian noise `noise_m` (from `rng`); `with_plates`: also each point's
    plate (N,)."""
    points, views, owners = [], [], []
    for k, plate in enumerate(plates):
        lo = np.minimum(plate.a, plate.b) - HALF_WIDTH_M
        hi = np.maximum(plate.a, plate.b) + HALF_WIDTH_M
        s, z = np.meshgrid(np.arange(lo[0], hi[0], spacing_m), np.arange(lo[1], hi[1], spacing_m))
        sz = np.stack([s.ravel(), z.ravel()], 1)
        sz = sz[plate.covers(sz)]
        centre = plate.centre_t_m(sz)
        for side in (1.0, -1.0):
            hidden = np.zeros(len(sz), bool)
            for m, other in enumerate(plates):
                if m != k:  # another plate on this face's side, over the same place, hides it
                    hidden |= other.covers(sz) & (side * (other.centre_t_m(sz) - centre) > 0)
            q = sz[~hidden]
            t = centre[~hidden] + side * HALF_THICKNESS_M
            points.append(np.stack([q[:, 0], t, q[:, 1]], 1))
            views.append(np.tile([0.0, side, 0.0], (len(q), 1)))
            owners.append(np.full(len(q), k, np.int64))
    p, v = np.concatenate(points), np.concatenate(views)
    if rng is not None and noise_m > 0:
        p = p + rng.normal(0.0, noise_m, p.shape)
    return (p, v, np.concatenate(owners)) if with_plates else (p, v)


def leaning_chain(lengths_m, angles_deg, leans_deg, pitch_m: float, seed: int = 0, noise_m: float = 0.0008):
    """(points (N, 3) s, t, z, view directions, each point's link, the joints (n, 2) in the plane): a
    chain whose links lean out of their layers about their pins, as joint play leans a print, seen
    from both sides (grid 2.5 mm, Gaussian noise `noise_m`)."""
    plates = [Plate(np.array([0.0, 0.0]), np.array([0.0, lengths_m[0]]), 0.0)]
    joint, phi, joints = np.array([0.0, lengths_m[0]]), 0.0, []
    for k, (length, angle, lean) in enumerate(zip(lengths_m[1:], angles_deg, leans_deg), start=1):
        phi += np.radians(angle)
        d = np.array([np.sin(phi), np.cos(phi)])
        t_at_pin = plates[-1].centre_t_m(joint[None])[0] + pitch_m  # a layer past its parent at the pin
        end = joint + d * (length - (HALF_WIDTH_M if k == len(angles_deg) else 0.0))
        plates.append(Plate(joint.copy(), end, t_at_pin, np.radians(lean)))
        joints.append(joint.copy())
        joint = joint + d * length
    return *chain_faces(plates, 0.0025, np.random.default_rng(seed), noise_m, with_plates=True), np.array(joints)
