"""Where a layer's plate centres step along it: two links the layers' rounding ran into one.

Link k is a plate in layer k, so a joint is a step of one layer pitch across the chain's plane (t)
between two plates. A structured-light sensor's smoothing (Kinect v1) spreads that step over about a
centimetre, and joint play leans the plates by a few degrees, so along a straight run of short links
the points' plate centres climb in plateaus a fraction of a pitch apart and the rounding puts two or
three links in one layer (bench seed 30545, 6 links: its layer 2 held links 2-4, the plateaus at 2.05,
2.75 and 3.35 layers, stepping where the true joints were). Where the chain was seen from both sides
of its plane, the joint's thickness finds such a layer (`measure.joints.hidden_joint`); elsewhere its
plate centres do: along the layer's fitted plate, two lines (t against the distance along it) with a
jump of half a pitch or more between them hold the centres far more closely than one line. A plate
that leans out of its layer is one line, however far it leans.

Measured on the 192 captures of bench seeds 30438-30629 (development, docs/observe.md): 30545 read 6
links for 4; no other count changed, on the real captures, their own clean renders or the rig (one
real capture's lengths moved by 0.02 paper units at most).
"""

from __future__ import annotations

import numpy as np

#: A step is looked for among the layer's points at least this far along its plate from its own joint
#: (where its parent's plate overlaps it, a layer down) ...
JOINT_CLEARANCE_M = 0.012
#: ... and this far before its plate's far end (where its child's does, a layer up).
END_CLEARANCE_M = 0.010
#: The two lines leave out the points this close to the step either side: the plate centres are
#: medians over 6 mm in the plane (`LayersConfig.radius_m`) and a Kinect's smoothing spreads a
#: joint's step over about a centimetre, so lines fitted into the ramp meet it part way.
STEP_GAP_M = 0.005
#: Each line holds at least this many of the layer's points.
MIN_SIDE_POINTS = 15
#: A step: the two lines part by at least this many layer pitches where they meet (a joint's whole
#: pitch less what smoothing and play take; a leaning plate's centres drift along one line) ...
MIN_STEP_LAYERS = 0.5
#: ... and leave at most this share of the squared residuals of one line through the same points.
MAX_RESIDUAL_SHARE = 0.5
#: Where the step is looked for: every this far along the plate.
STEP_SPACING_M = 0.001


def _line(sums: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The least-squares lines t = a + b u through point sets given by their sums (..., 6) of
    1, u, t, u^2, u t, t^2: (squared residuals, a, b)."""
    count, su, st, suu, sut, stt = np.moveaxis(sums, -1, 0)
    var_u = suu - su * su / count
    cov = sut - su * st / count
    slope = np.where(var_u > 1e-12, cov / np.maximum(var_u, 1e-12), 0.0)
    intercept = (st - slope * su) / count
    return np.maximum(stt - st * st / count - slope * cov, 0.0), intercept, slope


def _step(
    u: np.ndarray,
    t: np.ndarray,
    pitch_m: float,
    min_step_layers: float = MIN_STEP_LAYERS,
    max_share: float = MAX_RESIDUAL_SHARE,
) -> tuple[float, float] | None:
    """(where along u (sorted), share) the points' t step up by at least `min_step_layers` pitches with
    two lines holding them `share` as loosely as one, at most `max_share` (the least share), or None."""
    prefix = np.concatenate([np.zeros((1, 6)), np.cumsum(np.stack([np.ones_like(u), u, t, u * u, u * t, t * t], 1), 0)])
    at = np.arange(u[0] + STEP_GAP_M, u[-1] - STEP_GAP_M, STEP_SPACING_M)
    before = np.searchsorted(u, at - STEP_GAP_M)  # the first line: points 0 .. before - 1
    after = np.searchsorted(u, at + STEP_GAP_M, side="right")  # the second: after .. N - 1
    keep = (before >= MIN_SIDE_POINTS) & (len(u) - after >= MIN_SIDE_POINTS)
    at, before, after = at[keep], before[keep], after[keep]
    if len(at) == 0:
        return None
    first, second = prefix[before], prefix[-1] - prefix[after]
    squares_1, a_1, b_1 = _line(first)
    squares_2, a_2, b_2 = _line(second)
    one_line = _line(first + second)[0]
    step = (a_2 + b_2 * at) - (a_1 + b_1 * at)
    two_lines = squares_1 + squares_2
    stepped = (step >= min_step_layers * pitch_m) & (two_lines <= max_share * one_line)
    if not stepped.any():
        return None
    share = two_lines / np.maximum(one_line, 1e-18)
    best = np.flatnonzero(stepped)[np.argmin(share[stepped])]
    return float(at[best]), float(share[best])


def stepped_layer(
    layers_sz_m: list[np.ndarray],
    layers_t_m: list[np.ndarray],
    starts: np.ndarray,
    ends: np.ndarray,
    pitch_m: float,
) -> tuple[int, np.ndarray] | None:
    """(layer j, place (2,) in the plane) of the first layer 1..n whose plate centres `layers_t_m`
    step up by at least `MIN_STEP_LAYERS` along its fitted plate (from `starts[j]` to `ends[j]`,
    `measure.fit.plate_segments`; clear of its ends), where two lines on either side of the step hold
    them at most `MAX_RESIDUAL_SHARE` as loosely as one; None where none does."""
    for j, at, _ in layer_steps(layers_sz_m, layers_t_m, starts, ends, pitch_m, MIN_STEP_LAYERS, MAX_RESIDUAL_SHARE):
        return j, at
    return None


def layer_steps(
    layers_sz_m: list[np.ndarray],
    layers_t_m: list[np.ndarray],
    starts: np.ndarray,
    ends: np.ndarray,
    pitch_m: float,
    min_step_layers: float = 0.0,
    max_share: float = 1.0,
):
    """(layer j, place (2,) in the plane, share) of each layer 1..n's best step up (`_step`), in layer
    order: by default whatever its height, where another estimator is sure the chain has a link more
    than its layers hold (`measure.layers`'s `at_count`: each is a place the joint may hide)."""
    for j in range(1, len(layers_sz_m)):
        plate = ends[j] - starts[j]
        length = float(np.linalg.norm(plate))
        if len(layers_sz_m[j]) < 2 * MIN_SIDE_POINTS or length < JOINT_CLEARANCE_M + END_CLEARANCE_M:
            continue
        u = (layers_sz_m[j] - starts[j]) @ (plate / length)
        inside = (u >= JOINT_CLEARANCE_M) & (u <= length - END_CLEARANCE_M)
        order = np.argsort(u[inside], kind="stable")
        if len(order) < 2 * MIN_SIDE_POINTS:
            continue
        step = _step(u[inside][order], layers_t_m[j][inside][order], pitch_m, min_step_layers, max_share)
        if step is not None:
            yield j, starts[j] + step[0] * plate / length, step[1]
