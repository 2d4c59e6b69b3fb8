"""The planar chain fitted to its layers' points (`fit_layers`, step 3 of `measure.layers`).

The chain: joint 1 on the base axis at height L0, link k from joint k at angle phi_k = a_1 + .. + a_k
from vertical, each link a plate of half width `half_width_m` around its centre line. Parameters
x = [s0, L0..Ln, a1..an]. The residuals (`ChainResiduals`): each point's distance outside its own
link's plate; samples along each plate (to its rounded ends) at their distance beyond a point
spacing from the nearest point of that layer; a weak pull on the two free ends' lengths.

Their Jacobian is in closed form (`ChainResiduals.jacobian`): a distance's derivative is the unit
vector from the nearest point of the other side (the segment's closest point, the layer's nearest
point) dotted with how the plate's point moves, and the plates' ends are sums of link vectors. A
finite-difference Jacobian took 2n + 2 further evaluations of the residuals per step (up to 14),
84 % of a cold `evaluate`; all layers are evaluated at once too (one KD-tree for all of them).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from spare_twin.measure.layers_config import LayersConfig

#: The layers' points stacked into one KD-tree, layer k at this height in a third coordinate: no
#: nearest point is ever another layer's (the chain is centimetres across).
_LAYER_SEPARATION_M = 1000.0


def chain_joints(lengths_m: np.ndarray, angles_rad: np.ndarray, s0_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(joints (n + 1, 2): joint 1 .. joint n and the last plate's far centre, directions (n, 2))."""
    phi = np.cumsum(angles_rad)
    directions = np.stack([np.sin(phi), np.cos(phi)], 1)
    joint1 = np.array([s0_m, lengths_m[0]])
    return joint1 + np.concatenate([[[0.0, 0.0]], np.cumsum(directions * lengths_m[1:, None], 0)]), directions


def plate_segments(x: np.ndarray, n: int, cfg: LayersConfig) -> tuple[np.ndarray, np.ndarray]:
    """(starts, ends) (n + 1, 2) of the plates' centre lines, base first. The base link stands on the
    axis from the table; the last link's centre line ends half a width before its tip."""
    s0, lengths, angles = x[0], x[1 : n + 2], x[n + 2 :]
    joints, directions = chain_joints(lengths, angles, s0)
    starts = np.concatenate([[[s0, 0.0]], joints[:-1]])
    ends = joints.copy()
    ends[-1] = joints[-2] + directions[-1] * max(lengths[-1] - cfg.half_width_m, 1e-4)
    return starts, ends


def distance_to_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(M,) distances of (M, 2) points to the segment from a to b."""
    ab = b - a
    u = np.clip(((p - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return np.linalg.norm(p - (a + u[:, None] * ab), axis=1)


def _segment_derivatives(x: np.ndarray, n: int, cfg: LayersConfig) -> tuple[np.ndarray, np.ndarray]:
    """(dstarts, dends) (n + 1, 2, 2n + 2): how the plates' centre lines' ends move with x.

    Joint r + 1 is (s0, L0) + sum over j <= r of L_j d_j with d_j = (sin phi_j, cos phi_j): it moves
    with L_j along d_j and with a_i (i <= r) by sum over i <= j <= r of L_j d_j', d_j' = (cos, -sin).
    The last plate's end is joint n + (L_n - half width) d_n (its length held at 0.1 mm at least)."""
    lengths, angles = x[1 : n + 2], x[n + 2 :]
    phi = np.cumsum(angles)
    d = np.stack([np.sin(phi), np.cos(phi)], 1)
    d_turn = np.stack([np.cos(phi), -np.sin(phi)], 1)
    # below[r, j - 1]: joint r + 1 lies past link j (r = 0..n, j = 1..n)
    below = np.arange(n + 1)[:, None] >= np.arange(1, n + 1)[None, :]
    turn_sums = np.concatenate([[[0.0, 0.0]], np.cumsum(d_turn * lengths[1:, None], 0)])  # (n + 1, 2)
    d_joints = np.zeros((n + 1, 2, 2 * n + 2))
    d_joints[:, 0, 0] = 1.0
    d_joints[:, 1, 1] = 1.0
    d_joints[:, :, 2 : n + 2] = np.transpose(below[:, :, None] * d[None], (0, 2, 1))
    by_angle = (turn_sums[:, None, :] - turn_sums[None, :-1, :]) * below[:, :, None]  # (n + 1, n, 2)
    d_joints[:, :, n + 2 :] = np.transpose(by_angle, (0, 2, 1))
    d_starts = np.concatenate([np.zeros((1, 2, 2 * n + 2)), d_joints[:-1]])
    d_starts[0, 0, 0] = 1.0
    d_ends = d_joints.copy()
    last_m = lengths[-1] - cfg.half_width_m
    d_ends[n] = d_joints[n - 1]
    d_ends[n, :, n + 2 :] += d_turn[-1][:, None] * max(last_m, 1e-4)
    if last_m > 1e-4:
        d_ends[n, :, n + 1] += d[-1]
    return d_starts, d_ends


class ChainResiduals:
    """The fit's residuals (`residuals`) and their Jacobian (`jacobian`) for one set of layers."""

    def __init__(self, points_sz_m: list[np.ndarray], n: int, cfg: LayersConfig, seen_from: int = 0):
        self.n, self.cfg, self.seen_from = n, cfg, seen_from
        self.points = np.concatenate(points_sz_m) if points_sz_m else np.zeros((0, 2))
        self.layer = np.repeat(np.arange(len(points_sz_m)), [len(p) for p in points_sz_m])
        self.total = len(self.points)
        self.u = np.linspace(0.0, 1.0, cfg.samples_per_link)
        self.weight = np.sqrt(self.total / ((n + 1) * cfg.samples_per_link))  # coverage weighs as much as the points
        self.free_end_weight = cfg.free_end_pull * np.sqrt(self.total)
        lifted = np.concatenate([self.points, _LAYER_SEPARATION_M * self.layer[:, None]], 1)
        self.tree = cKDTree(lifted) if self.total else None
        # the base's foot end is in the socket: only the other plates reach past their start
        self.cap_start = np.where(np.arange(n + 1) == 0, 0.0, cfg.cap_reach * cfg.half_width_m)
        self._cached: tuple[bytes, dict] | None = None

    def _state(self, x: np.ndarray) -> dict:
        """Everything the residuals and the Jacobian at x share (kept for the last x)."""
        key = x.tobytes()
        if self._cached is not None and self._cached[0] == key:
            return self._cached[1]
        cfg = self.cfg
        starts, ends = plate_segments(x, self.n, cfg)
        ab = ends - starts
        ab_norm = np.linalg.norm(ab, axis=1)
        along = ab / np.maximum(ab_norm, 1e-9)[:, None]
        # each point to its own plate's centre line
        a, seg = starts[self.layer], ab[self.layer]
        u = (self.points - a) * seg
        u = np.clip((u[:, 0] + u[:, 1]) / np.maximum(np.sum(ab * ab, 1), 1e-12)[self.layer], 0.0, 1.0)
        off = self.points - (a + u[:, None] * seg)
        dist = np.linalg.norm(off, axis=1)
        # the plates' centre lines out to their rounded ends, sampled
        lo = starts - self.cap_start[:, None] * along
        hi = ends + cfg.cap_reach * cfg.half_width_m * along
        samples = lo[:, None, :] + self.u[None, :, None] * (hi - lo)[:, None, :]  # (n + 1, S, 2)
        gap = np.full(samples.shape[:2], np.inf)
        nearest = np.zeros_like(samples)
        if self.tree is not None:
            height = _LAYER_SEPARATION_M * np.broadcast_to(np.arange(self.n + 1)[:, None, None], (*gap.shape, 1))
            gap, idx = self.tree.query(
                np.concatenate([samples, height], 2), distance_upper_bound=_LAYER_SEPARATION_M / 2
            )
            found = np.isfinite(gap)
            nearest[found] = self.points[idx[found]]
            if self.seen_from:  # nothing to cover where the nearer plate hides the disc
                gap = np.where(self._hidden(samples, starts), np.inf, gap)
        state = dict(
            starts=starts, ends=ends, ab_norm=ab_norm, along=along, u=u, off=off, dist=dist,
            samples=samples, gap=gap, nearest=nearest,
        )  # fmt: skip
        self._cached = (key, state)
        return state

    def _hidden(self, samples: np.ndarray, starts: np.ndarray) -> np.ndarray:
        """(n + 1, S): the samples in a joint's disc that the nearer plate there hides from a capture
        seen from one side (`seen_from`), where that plate's own points show it (one of its layer's
        points within `coverage_tolerance_m`)."""
        hw, n = self.cfg.half_width_m, self.n
        hidden = np.zeros(samples.shape[:2], bool)
        joints = starts[1:]
        if self.seen_from < 0:  # seen from -t, the parent nearer: plate k's start disc behind plate k - 1
            rows, nearer = np.arange(1, n + 1), np.arange(n)
        else:  # seen from +t, the child nearer: plate k's end disc behind plate k + 1
            rows, nearer = np.arange(n), np.arange(1, n + 1)
        disc = np.linalg.norm(samples[rows] - joints[:, None], axis=2) <= hw
        height = _LAYER_SEPARATION_M * np.broadcast_to(nearer[:, None, None], (*disc.shape, 1)).astype(float)
        shown, _ = self.tree.query(
            np.concatenate([samples[rows], height], 2), distance_upper_bound=self.cfg.coverage_tolerance_m
        )
        hidden[rows] = disc & np.isfinite(shown)
        return hidden

    def residuals(self, x: np.ndarray) -> np.ndarray:
        cfg, st = self.cfg, self._state(x)
        outside = np.maximum(st["dist"] - cfg.half_width_m, 0.0)
        # a layer with no points has no say on its plate's coverage (inf: nothing within reach)
        gaps = np.where(np.isfinite(st["gap"]), np.maximum(st["gap"] - cfg.coverage_tolerance_m, 0.0), 0.0)
        free_ends = self.free_end_weight * x[[1, self.n + 1]]
        return np.concatenate([outside, self.weight * gaps.ravel(), free_ends])

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        cfg, st, n = self.cfg, self._state(x), self.n
        d_starts, d_ends = _segment_derivatives(x, n, cfg)
        # outside: d|p - c| = -(p - c)/|p - c| . dc, c = (1 - u) start + u end (u's own change moves c
        # along the segment, across the offset, or not at all where u is clamped)
        active = st["dist"] > cfg.half_width_m
        unit = np.zeros_like(st["off"])
        unit[active] = st["off"][active] / st["dist"][active, None]
        u, lay = st["u"][:, None, None], self.layer
        d_closest = (1.0 - u) * d_starts[lay] + u * d_ends[lay]  # (N, 2, P)
        j_outside = -np.einsum("nc,ncp->np", unit, d_closest)
        # coverage: the sample moves with its plate's ends and with the plate's direction (the caps)
        d_ab = d_ends - d_starts
        along = st["along"]
        d_along = (d_ab - along[:, :, None] * np.einsum("kc,kcp->kp", along, d_ab)[:, None, :]) / np.maximum(
            st["ab_norm"], 1e-9
        )[:, None, None]
        d_lo = d_starts - self.cap_start[:, None, None] * d_along
        d_hi = d_ends + cfg.cap_reach * cfg.half_width_m * d_along
        s = self.u[None, :, None, None]
        d_samples = (1.0 - s) * d_lo[:, None] + s * d_hi[:, None]  # (n + 1, S, 2, P)
        gap = st["gap"]
        covering = np.isfinite(gap) & (gap > cfg.coverage_tolerance_m)
        away = np.zeros_like(st["samples"])
        away[covering] = (st["samples"] - st["nearest"])[covering] / gap[covering, None]
        j_gaps = self.weight * np.einsum("ksc,kscp->ksp", away, d_samples).reshape(-1, 2 * n + 2)
        j_free = np.zeros((2, 2 * n + 2))
        j_free[0, 1] = j_free[1, n + 1] = self.free_end_weight
        return np.concatenate([j_outside, j_gaps, j_free])


#: Evaluations a start of the fit may take. A chain's fit settles in 20-150; one still moving after 200
#: is a blurred capture's (points 4-5 mm RMS off any chain), whose own limit (100 per parameter,
#: 800-1,000) took 1-3 s a start, 29 s of CPU in all on bench seed 30441, and moved it by under a
#: millimetre and 0.03 mm RMS after 200.
MAX_EVALUATIONS = 200


def _fit_from(chain: ChainResiduals, x0: np.ndarray):
    """Robust least squares of `chain` from x0 (scipy's result)."""
    n = chain.n
    lo = np.concatenate([[-0.02], np.full(n + 1, 0.005), np.full(n, -np.inf)])
    hi = np.concatenate([[0.02], np.full(n + 1, 0.5), np.full(n, np.inf)])
    return least_squares(
        chain.residuals,
        np.clip(x0, lo + 1e-9, hi - 1e-9),
        jac=chain.jacobian,
        bounds=(lo, hi),
        loss="soft_l1",
        f_scale=0.003,
        max_nfev=MAX_EVALUATIONS,
    )


def fit_layers(points_sz_m: list[np.ndarray], n: int, cfg: LayersConfig) -> tuple[np.ndarray, float]:
    """(x = [s0, L0..Ln, a1..an], rms) of the chain fitted to each layer's (M_k, 2) in-plane points:
    robust least squares from both starts (`_initial`, `_initial_sequential`) from each place of joint
    1 (`_first_joints`), the lowest cost kept."""
    chain = ChainResiduals(points_sz_m, n, cfg)
    fits = [
        _fit_from(chain, x0)
        for joint1 in _first_joints(points_sz_m, cfg)
        for x0 in (_initial(points_sz_m, n, cfg, joint1), _initial_sequential(points_sz_m, n, cfg, joint1))
    ]
    res = min(fits, key=lambda r: r.cost)  # the first on a tie
    rms = float(np.sqrt(np.mean(res.fun[: chain.total] ** 2))) if chain.total else 0.0
    return res.x, rms


def refit_seen_from(
    points_sz_m: list[np.ndarray], n: int, cfg: LayersConfig, x: np.ndarray, seen_from: int
) -> np.ndarray:
    """The chain `x` (`fit_layers`) refitted to the same layers with the joints' discs that the nearer
    plate hides from a capture seen from one side of the plane (`seen_from` -1 / +1) left uncovered:
    a plate's coverage pulls its end in to where its own points stop, a disc short of the joint
    behind the nearer plate."""
    return _fit_from(ChainResiduals(points_sz_m, n, cfg, seen_from), x).x


#: Joint 1's height is looked for this far below and above the base's top (in half widths, `_first_joints`),
#: in steps of this (metres).
JOINT1_SEARCH_HALF_WIDTHS = (-1.0, 3.0)
JOINT1_STEP_M = 0.001
#: Where layer 1's points lie further out of link 1's plate from the base's top than from the best
#: height by more than this squared in mean square (metres), the fit starts from there too.
JOINT1_TOLERANCE_M = 0.001


def _first_joints(points: list[np.ndarray], cfg: LayersConfig) -> list[np.ndarray]:
    """[(2,) joint 1, ...] where the starts put it: half a width below the top of the base's points,
    and also where link 1's plate from a joint on the base's axis holds layer 1's points best, if
    clearly better than from the base's top (`JOINT1_TOLERANCE_M`). Link 1 lies in front of the
    base's top and hides it from every camera on its side: where the back was hardly seen the base's
    points end a centimetre or more below the joint, and every start link by link from there missed
    the chain (held-out seed 30932: joint 1 15 mm low, link 1 turned 60 deg, a 3-link chain read as
    2). The plate's test is no finer than a few mm, so the base's top keeps its starts: the fit from
    each is kept where its cost is the lowest."""
    hw = cfg.half_width_m
    base = points[0]
    top = np.array([0.0, max(float(np.percentile(base[:, 1], 98)) - hw if len(base) else 0.04, 0.02)])
    link1 = points[1] if len(points) > 1 else np.zeros((0, 2))
    if len(link1) < cfg.min_layer_points:
        return [top]
    lo, hi = JOINT1_SEARCH_HALF_WIDTHS
    steps = np.arange(np.ceil(lo * hw / JOINT1_STEP_M - 1e-9), np.floor(hi * hw / JOINT1_STEP_M + 1e-9) + 1)
    heights = top[1] + steps * JOINT1_STEP_M  # the base's top itself among them
    heights = heights[heights >= 0.02]
    axes = _directions(cfg)[1]
    misfit = np.array([_plate_misfit(link1 - [0.0, z], axes, hw)[0].min() for z in heights])
    at_top = misfit[np.argmin(np.abs(heights - top[1]))]
    if at_top - misfit.min() <= len(link1) * JOINT1_TOLERANCE_M**2:
        return [top]
    return [top, np.array([0.0, float(heights[np.argmin(misfit)])])]


def _directions(cfg: LayersConfig) -> tuple[np.ndarray, np.ndarray]:
    """(phi (D,), axes (D, 2)): link directions evenly round the circle from -pi, as angles from
    vertical and as unit vectors (sin phi, cos phi)."""
    phis = np.linspace(-np.pi, np.pi, cfg.directions, endpoint=False)
    return phis, np.stack([np.sin(phis), np.cos(phis)], 1)


def _plate_misfit(rel: np.ndarray, axes: np.ndarray, hw: float) -> tuple[np.ndarray, np.ndarray]:
    """(misfit (D,), reach (D,)) of a plate of half width `hw` from a joint along each of D `axes`
    out to its points' reach (98th percentile along it): the sum of squared distances (m^2) of the
    points `rel` (relative to the joint) outside it."""
    along = rel @ axes.T  # (M, D)
    across = np.abs(rel @ np.stack([axes[:, 1], -axes[:, 0]], 0))
    reach = np.maximum(np.percentile(along, 98, axis=0), 2 * hw)
    outside = np.maximum(np.hypot(along - np.clip(along, 0.0, reach), across) - hw, 0.0)
    return np.sum(outside**2, axis=0), reach


def _initial(points: list[np.ndarray], n: int, cfg: LayersConfig, joint1: np.ndarray) -> np.ndarray:
    """Start of the fit, read from the layers: from joint 1 (`_first_joints`), per link its centroid,
    which lies half the link's length from its joint (for the last link, half of length minus half a
    width)."""
    hw = cfg.half_width_m
    joint, phi_prev = joint1.copy(), 0.0
    lengths, angles = [joint[1]], []
    for k in range(1, n + 1):
        p = points[k]
        offset = p.mean(0) - joint if len(p) else np.array([0.0, 0.03])
        phi = float(np.arctan2(offset[0], offset[1]))
        length = 2 * float(np.linalg.norm(offset)) + (hw if k == n else 0.0)
        length = max(length, 2 * hw)
        lengths.append(length)
        angles.append((phi - phi_prev + np.pi) % (2 * np.pi) - np.pi)
        joint = joint + length * np.array([np.sin(phi), np.cos(phi)])
        phi_prev = phi
    return np.concatenate([[0.0], lengths, angles])


def _initial_sequential(points: list[np.ndarray], n: int, cfg: LayersConfig, joint1: np.ndarray) -> np.ndarray:
    """A second start, link by link from the base: each link's direction is the one of `directions`
    whose plate from its joint holds the layer's points best, its length their reach along it. Where
    the first start's centroid misleads (a link's points bunched at one end, a fold that hides half a
    link), this one follows the points' extent instead."""
    hw = cfg.half_width_m
    joint = joint1.copy()
    phis, axes = _directions(cfg)
    lengths, angles, phi_prev = [joint[1]], [], 0.0
    for k in range(1, n + 1):
        rel = points[k] - joint
        if len(rel) == 0:
            phi, reach = phi_prev, 2 * hw
        else:
            misfit, reach_all = _plate_misfit(rel, axes, hw)
            best = int(np.argmin(misfit))
            phi, reach = float(phis[best]), float(reach_all[best])
        # the points reach a middle link's rounded end, a half width past its far joint; the last's tip
        length = reach if k == n else max(reach - hw, 2 * hw)
        lengths.append(length)
        angles.append((phi - phi_prev + np.pi) % (2 * np.pi) - np.pi)
        joint = joint + (length - (hw if k == n else 0.0)) * np.array([np.sin(phi), np.cos(phi)])
        phi_prev = phi
    return np.concatenate([[0.0], lengths, angles])
