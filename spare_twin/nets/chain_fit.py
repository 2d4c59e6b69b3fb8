"""The predicted chain fitted to the observed points: joint angles and link lengths measured on the
cloud, starting from the network's answer.

In the chain's plane (the profile frame of `observe.profile`: s along the plane, z up, the base axis
at s = 0) a SPARE chain is a polyline: joint 1 at height L0 on the base axis, link k running from joint
k along (sin phi_k, cos phi_k) with phi_k the sum of the first k joint angles, each link a plate 12 mm
wide around its centre line (the last one ending half a width before its tip;
`object.kinematics.link_segment_m`). The network's count fixes the polyline's shape; its lengths and
angles start a robust least-squares fit (scipy) of two terms:

- every point lies within half a link width of the polyline (no cost inside it);
- every stretch of the polyline is covered by points (the distance from samples along it to the
  nearest point), so a link cannot grow into empty space or shrink off its points.

Angles are measured, not regressed: the network's angle head is a start, and a wrong start on a
folded chain is a local minimum, so a few starts are tried (the network's, and each joint turned
half round). Deterministic (scipy, one thread, fixed starts).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

SAMPLES_PER_LINK = 16


@dataclass(frozen=True)
class ChainFit:
    lengths_pu: np.ndarray
    """(n + 1,) paper units, base first."""
    angles_rad: np.ndarray
    """(n,) relative joint angles, in the profile frame's sign."""
    rms_m: float
    """RMS of the point-to-plate distances (metres)."""


def polyline(lengths_m: np.ndarray, angles_rad: np.ndarray, half_width_m: float) -> np.ndarray:
    """(n + 2, 2) (s, z) vertices: the table under the base, joint 1 .. joint n, the last plate's end."""
    phi = np.cumsum(angles_rad)
    seg = lengths_m[1:].copy()
    seg[-1] = max(seg[-1] - half_width_m, 1e-4)
    steps = np.stack([np.sin(phi) * seg, np.cos(phi) * seg], 1)
    joint1 = np.array([[0.0, lengths_m[0]]])
    return np.concatenate([[[0.0, 0.0]], joint1, joint1 + np.cumsum(steps, 0)])


def _segment_distances(points: np.ndarray, verts: np.ndarray) -> np.ndarray:
    """(N,) distance of each point to the polyline."""
    a, b = verts[:-1], verts[1:]
    ab = b - a
    t = np.clip(np.einsum("nkd,kd->nk", points[:, None] - a[None], ab) / np.maximum((ab**2).sum(1), 1e-12), 0, 1)
    closest = a[None] + t[..., None] * ab[None]
    return np.sqrt(((points[:, None] - closest) ** 2).sum(-1)).min(1)


def _samples(verts: np.ndarray, per_link: int) -> np.ndarray:
    """`per_link` points along each moving link's centre line (a fixed count: least squares needs a
    fixed number of residuals)."""
    a, b = verts[1:-1], verts[2:]  # the moving links (the base column is there by construction)
    u = np.linspace(0, 1, per_link)[None, :, None]
    return (a[:, None] + u * (b - a)[:, None]).reshape(-1, 2)


def fit_chain(
    points_sz_m: np.ndarray,
    lengths_pu: np.ndarray,
    angles_rad: np.ndarray,
    print_scale: float,
    half_width_m: float = 0.006,
    max_points: int = 500,
    max_length_change_pu: float = 0.15,
) -> ChainFit:
    """Fit the chain to (N, 2) points in the chain's plane (metres), from the network's n + 1 lengths
    (paper units) and n angles."""
    pts = np.asarray(points_sz_m, np.float64)
    pts = pts[pts[:, 1] > 0.02]  # above the foot and the socket: the links
    if len(pts) > max_points:
        pts = pts[np.linspace(0, len(pts) - 1, max_points).astype(int)]
    tree = cKDTree(pts)
    n = len(angles_rad)
    scale = np.sqrt(len(pts) / (SAMPLES_PER_LINK * n))  # coverage weighs as much as the points, whatever their count

    def residuals(x):
        lengths_m, angles = x[: n + 1], x[n + 1 :]
        verts = polyline(lengths_m, angles, half_width_m)
        outside = np.maximum(_segment_distances(pts, verts) - half_width_m, 0.0)
        gaps, _ = tree.query(_samples(verts, SAMPLES_PER_LINK))
        return np.concatenate([outside, scale * np.maximum(gaps - half_width_m, 0.0)])

    lengths0 = np.asarray(lengths_pu, np.float64) * print_scale
    starts = [np.asarray(angles_rad, np.float64)]
    for k in range(n):  # a folded joint read the wrong way round is a local minimum: try it turned
        flipped = starts[0].copy()
        flipped[k] = -flipped[k]
        starts.append(flipped)
    # the network's lengths are right to a few hundredths of a paper unit: the fit measures within that
    # band, and a link cannot run off along a neighbour's points
    lengths0 = np.maximum(lengths0, 0.006)
    span = max_length_change_pu * print_scale
    lo = np.concatenate([np.maximum(lengths0 - span, 0.005), np.full(n, -np.inf)])
    hi = np.concatenate([lengths0 + span, np.full(n, np.inf)])
    best = None
    for a0 in starts:
        x0 = np.concatenate([lengths0, a0])
        res = least_squares(residuals, x0, bounds=(lo, hi), loss="soft_l1", f_scale=0.003, max_nfev=40)
        if best is None or res.cost < best.cost:
            best = res
    lengths_m, angles = best.x[: n + 1], best.x[n + 1 :]
    angles = (angles + np.pi) % (2 * np.pi) - np.pi
    rms = float(np.sqrt(np.mean(best.fun[: len(pts)] ** 2)))
    return ChainFit(lengths_m / print_scale, angles, rms)
