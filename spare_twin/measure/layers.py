"""The chain measured on its points, layer by layer: link count, link lengths and joint angles.

A SPARE chain's links are plates in layers along the joint axes, link k in layer k (6.4 mm pitch,
`observe.profile`): across the chain's plane (t) every point says which link it is on. So, in the
profile frame (s along the plane, t across it, z up, the base axis at s = t = 0):

1. **labels**: each point's layer is its neighbourhood's median plate centre (in the plane, within
   `radius_m`) over the pitch, rounded, once the shear of t along s is taken out (`_layer_shear`).
   The median is what makes this hold under a structured-light sensor's noise of several
   millimetres, where a single point's t is often a layer off; where two plates overlap (at a joint)
   a point may take either label, and lies inside both plates anyway. A second reading follows the
   comb along the chain from the base (`measure.plates`: joint play leans the links off one comb).
   Where the two count otherwise, the one that puts no two separate pieces of the chain in one layer
   is kept (`split_layers`), and between two such, the one whose chain lies closer to its points in
   the plane and across it (`LayerMeasurement.cost_m`: a layer holding two links holds the whole
   pitch's step between them, which no one plate's plane fits); with one count, the one whose chain
   fits clearly closer (`ONE_COUNT_RMS_SHARE`), else the one piece a layer, else the comb's. In each
   reading, a layer's stray fragments, small pieces apart from its plate among the points of the layer
   next to it, go to that layer first (`measure.fragments`). The followed comb's zero is kept on the measurement: it
   levels the profile network's input (`measure.level`).
2. **count**: the highest layer holding at least `min_layer_points` points (links are at least
   2.5 cm long: hundreds of points at the rig's resolution, dozens in a coarse capture) and
   `min_layer_fraction` of them, or just above it, fewer points spanning a plate's width
   (`min_thin_layer_width`: a dark top link, not a strip of its parent read a layer up).
3. **fit**: a planar chain of that count (joint 1 on the base axis at height L0, link k from joint k
   at angle phi_k = a_1 + .. + a_k from vertical, a plate 12 mm wide around its centre line) fitted
   by robust least squares (scipy) with each point held to its own link only: a point outside its
   plate costs its distance, and samples along each plate (to its rounded ends) cost their distance
   to the nearest point of that layer beyond a point spacing. Both ends of a joint are held by the
   two plates meeting there, from opposite sides, so a length is measured, not guessed. Two starts,
   both read from the layers from joint 1 (the base's top, and where link 1's plate holds its points
   clearly better: `fit._first_joints`), the lowest cost kept: each link's points' centroid lies half
   its length from its joint (`fit._initial`), and link by link from the base, each turned to where
   its plate holds its layer's points best (`fit._initial_sequential`). No network is needed, and folded chains do not
   trap the fit. A weak pull on the two free ends (the base's top, the last link's tip) keeps the
   shortest chain that holds the points, where the coverage tolerance alone let them drift out.
   The fit, its starts and its residuals' Jacobian (in closed form) are `measure.fit`.
4. **no link, or a link more**: a top layer that is its parent's points read a layer up
   (`measure.merges`: `top_layer_is_stray`), a layer that is the far end of its parent's plate cut off by the joint's
   lean (`is_cut`) and a link between joints too short to print (`unprintable_link`) are merged into
   the layer below. Where the chain was seen from both sides of its plane, a joint is told by its
   thickness (`measure.joints`: at a pin two plates overlap, a layer thicker than one plate; a cut
   plate is one plate thick there; read where the two layers meet if a layer read as a cut sits a
   whole layer above its parent, `MIN_LINK_RISE_LAYERS`: the joint was fitted off its pin), and a
   layer as thick as a joint somewhere along it holds two links and is split there first; elsewhere
   a cut plate is told by its plate centres' step where the two layers meet (`cut_plate`: a
   fraction of a layer, not a joint's whole layer), and a layer whose plate centres step by half a
   pitch or more along it is split there (`measure.steps`: a Kinect's smoothing ran a straight run
   of short links into one layer), and so is a last layer whose points two plates meeting at a bend
   hold far closer than one (`measure.bends`: a short or dark last link read in its parent's layer).
5. **no measure**: points that lie centimetres (RMS, `max_rms_m`) off the best chain are no chain
   to measure, and the measurement says why (a capture blurred by views out of register); so is a
   reading whose checks end on a chain far looser than the closest one they passed through
   (`MAX_LOOSENING`): its evidence contradicts itself; and so is a chain whose layers' plate centres
   spread across the plane as far as a link's step to the next layer (`layers_told_apart`, applied to
   the chain `measure.chain` keeps): its layers, and its count, are not told apart.

Deterministic: medians, sorted KD-tree queries and scipy's least squares with fixed starts.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from spare_twin.config import MAX_MOVING_LINKS
from spare_twin.measure.bends import bent_layer, beyond_bend
from spare_twin.measure.fit import fit_layers, plate_segments, refit_seen_from
from spare_twin.measure.fragments import adopt_fragments, counted_pieces, pieces
from spare_twin.measure.joints import Thickness, chain_sides, hidden_joint, joint_excess_layers, seen_from_side
from spare_twin.measure.layers_config import LayersConfig
from spare_twin.measure.level import CombZero
from spare_twin.measure.medians import grouped_medians
from spare_twin.measure.merges import is_cut, share_on_plate, top_layer_is_stray, unprintable_link, width_m
from spare_twin.measure.plates import local_comb_layers
from spare_twin.measure.steps import layer_steps, stepped_layer
from spare_twin.observe.points import ObjectPoints
from spare_twin.observe.profile import ChainProfile


@dataclass(frozen=True)
class LayerMeasurement:
    """The chain as its points show it."""

    n_links: int | None
    """Moving links (the highest well-populated layer); None when the points show no link."""
    lengths_pu: np.ndarray | None
    """(n + 1,) paper units, base first."""
    angles_rad: np.ndarray | None
    """(n,) relative joint angles in the profile frame's sign."""
    points_per_layer: tuple[int, ...]
    """How many link points each layer 0, 1, .. holds (for the reader of a wrong count)."""
    rms_m: float | None = None
    """RMS distance of the points outside their plates."""
    reason: str | None = None
    """Why a chain the layers count cannot be measured (its points do not lie on one); then
    `n_links` is None."""
    t_rms_m: float | None = None
    """RMS spread of the points' plate centres across the plane about each layer's own slanted
    plane (`layer_t_rms_m`): how well the layers hold one plate each."""
    layers_blurred: bool = False
    """True where the points lie on a chain but its layers are not told apart (`layers_told_apart`):
    no count, though the points are no reason to refuse another estimator's (`predict.combine`)."""
    closest_passed: LayerMeasurement | None = field(default=None, repr=False, compare=False)
    """Where the reading did not settle (`MAX_LOOSENING`): the closest chain its checks passed through,
    which the other reading's chain of that count may be compared with (`_chosen_reading`)."""
    comb_zero: CombZero | None = field(default=None, repr=False, compare=False)
    """The followed comb's zero across the plane, which levels the profile network's input
    (`measure.level`); None where no comb was followed."""
    labels: np.ndarray | None = field(default=None, repr=False, compare=False)
    """(N,) int64: the layer (0..n) of each point measured, as the chain settled, in the order
    `measure_layers` measured them; None where no chain was fitted."""
    past_on_last_plate: float | None = None
    """The share of the points read past the sixth link's layer that lie on the last link's plate in
    the chain's plane (`MIN_PAST_ON_LAST_PLATE`); None where no point was read past it."""

    above_on_last_plate: float | None = None
    """The share of the points of the layer just above the last that lie on the last link's plate in
    the chain's plane, where that layer holds at least `LayersConfig.min_layer_points` but did not
    count (too few for a link, or spanning less than a plate's width: `count_links`); else None. Off
    the plate they may be a link of their own seen in few points (`predict.combine`)."""

    other_registration: LayerMeasurement | None = field(default=None, repr=False, compare=False)
    """A sweep's other registration's chain, where it counts otherwise and holds its points about as
    closely (`measure.chain.count_told`): the count is disputed (`count_disputed`)."""

    @property
    def count_disputed(self) -> str | None:
        """Why the count is not told, where a sweep's two registrations dispute it (`other_registration`),
        else None."""
        other = self.other_registration
        if other is None or self.n_links is None:
            return None
        return (
            f"its two registrations count {self.n_links} and {other.n_links} links and hold their points about"
            f" as closely ({1000 * self.cost_m:.2f} and {1000 * other.cost_m:.2f} mm): its count is not told"
        )

    @property
    def past_is_last_plate(self) -> bool:
        """Whether the points read past the sixth link's layer are the last link's plate, carried
        there by the joints' play (`MIN_PAST_ON_LAST_PLATE`), not an object thicker than any chain."""
        return self.past_on_last_plate is not None and self.past_on_last_plate >= MIN_PAST_ON_LAST_PLATE

    @property
    def cost_m(self) -> float | None:
        """How far the chain is from its points in the plane and across it (RMS, `rms_m` and
        `t_rms_m` together): what tells two readings of other counts apart (`measure_layers`)."""
        if self.rms_m is None:
            return None
        return float(np.hypot(self.rms_m, self.t_rms_m or 0.0))


def plate_centres_t(
    s_m: np.ndarray, t_m: np.ndarray, z_m: np.ndarray, view_t: np.ndarray | None, cfg: LayersConfig
) -> np.ndarray:
    """(N,) each point's plate centre across the plane: the median of its in-plane neighbourhood on
    the same side of the chain. A point seen from +t lies on a plate's +t face, half a thickness past
    its centre (and the other way round); where two plates overlap at a joint, those seen from either
    side are each one plate's face."""
    side = np.zeros(len(t_m), np.int64)
    if view_t is not None:
        side = chain_sides(view_t, cfg.min_side_cosine)
    centre_t = t_m - side * cfg.half_thickness_m
    centre_t = _align_sides(s_m, z_m, centre_t, side, cfg)
    sz = np.stack([s_m, z_m], 1)
    median_t = np.empty(len(t_m))
    for value in (-1, 0, 1):
        mine = np.flatnonzero(side == value)
        if len(mine):
            pool = mine if value != 0 else np.arange(len(t_m))  # an edge-on point asks all its neighbours
            neighbours = cKDTree(sz[pool]).query_ball_point(sz[mine], cfg.radius_m, return_sorted=True)
            median_t[mine] = grouped_medians(centre_t[pool], neighbours)  # each point is its own neighbour
    return median_t


def layer_readings(
    s_m: np.ndarray,
    t_m: np.ndarray,
    z_m: np.ndarray,
    view_t: np.ndarray | None,
    cfg: LayersConfig,
    centre_t_m: np.ndarray | None = None,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """The readings of the points' layers, each (labels, centre_layers): each point's (N,) int64 layer
    and its plate centre in layers, from the points' plate centres (`centre_t_m`, or
    `plate_centres_t`). First the layers read off one comb of the layer pitch (shear taken out),
    rounded; then, with `cfg.follow_comb` and a base column, off the comb followed along the chain
    from that column (`measure.plates`: joint play leans the links off one comb)."""
    median_t = plate_centres_t(s_m, t_m, z_m, view_t, cfg) if centre_t_m is None else centre_t_m
    sz = np.stack([s_m, z_m], 1)
    column = (z_m > cfg.min_height_m) & (z_m < cfg.min_height_m + 0.02) & (np.abs(s_m) < cfg.half_width_m * 2)
    readings = [_one_comb(s_m, median_t, column, cfg)]
    if cfg.follow_comb:
        followed = local_comb_layers(sz, median_t, column, cfg.layer_pitch_m, cfg.radius_m)
        if followed is not None:
            readings.append(followed)
    return readings


def read_layers(
    p: np.ndarray, view_t: np.ndarray | None, cfg: LayersConfig, flip: np.ndarray | None = None
) -> tuple[list[tuple[np.ndarray, np.ndarray]], CombZero | None]:
    """`layer_readings` of the points `p` (s, t, z: the links at larger t than the base, the profile
    frame times `flip`) and the followed comb's zero as read, before any fragment moves: the profile
    network's input is levelled by it (`measure.level`; None where no comb was followed)."""
    centre_t_m = plate_centres_t(p[:, 0], p[:, 1], p[:, 2], view_t, cfg)
    readings = layer_readings(p[:, 0], p[:, 1], p[:, 2], view_t, cfg, centre_t_m)
    if len(readings) < 2:
        return readings, None
    flip = np.ones(3) if flip is None else flip
    return readings, CombZero.of_reading(p, flip, centre_t_m, readings[1][1], cfg.layer_pitch_m)


def _one_comb(
    s_m: np.ndarray, median_t: np.ndarray, column: np.ndarray, cfg: LayersConfig
) -> tuple[np.ndarray, np.ndarray]:
    """(labels, centre_layers) read off one comb of the layer pitch, its shear along s taken out."""
    median_t = median_t - _layer_shear(s_m, median_t, cfg) * s_m
    # the base link is layer 0 by definition: its column above the socket sets t's zero (the profile's
    # base axis is the foot's centre, a millimetre or two off the plate's); the layers' common phase
    # says where within a pitch the zero lies, the column which layer it is
    wave = 2 * np.pi / cfg.layer_pitch_m
    zero = float(np.angle(np.sum(np.exp(1j * wave * median_t)))) / wave
    if column.sum() >= cfg.min_layer_points:
        zero += cfg.layer_pitch_m * np.rint((np.median(median_t[column]) - zero) / cfg.layer_pitch_m)
    centre_layers = (median_t - zero) / cfg.layer_pitch_m
    return np.rint(centre_layers).astype(np.int64), centre_layers


def _layer_shear(s_m: np.ndarray, t_m: np.ndarray, cfg: LayersConfig) -> float:
    """The shear g (t per s) that stacks the points' plate centres best onto a 6.4 mm comb: the
    argmax of the coherence |mean(exp(2 pi i (t - g s) / pitch))| less `shear_prior` * |g|. A plane
    direction a few degrees off (the face normals of a noisy Kinect capture) shears t along s by a
    layer or more across the chain; the comb's coherence sees the whole shear at once, where fitting
    each point's offset from its rounded layer cannot tell a shear of one layer from none. The prior
    keeps an upright chain (little extent in s, so no say about g) unsheared."""
    wave = 2 * np.pi / cfg.layer_pitch_m
    shears = np.linspace(-cfg.max_shear, cfg.max_shear, cfg.shear_steps)
    phases = np.exp(1j * wave * t_m)
    coherence = np.abs(np.exp(-1j * wave * np.outer(shears, s_m)) @ phases) / max(len(t_m), 1)
    return float(shears[int(np.argmax(coherence - cfg.shear_prior * np.abs(shears)))])


def _align_sides(s_m, z_m, centre_t, side, cfg: LayersConfig) -> np.ndarray:
    """`centre_t` with the two sides' readings moved half their disagreement towards each other. A
    plate seen from both sides gives one centre from each; where they disagree by more than noise,
    the views of one side are offset from the other's (a hand-held sweep's registration drifts
    between the start and the end of its arc) and each plate would split into two layers."""
    front, back = np.flatnonzero(side > 0), np.flatnonzero(side < 0)
    if min(len(front), len(back)) < cfg.min_layer_points:
        return centre_t
    sz = np.stack([s_m, z_m], 1)
    back_tree = cKDTree(sz[back])
    pairs = back_tree.query_ball_point(sz[front], cfg.radius_m, return_sorted=True)
    paired = np.fromiter(map(len, pairs), np.int64, len(pairs)) > 0
    gaps = centre_t[front[paired]] - grouped_medians(centre_t[back], [g for g in pairs if len(g)])
    if len(gaps) < cfg.min_layer_points:
        return centre_t
    gap = float(np.median(gaps))
    return centre_t - side * gap / 2


def count_links(
    labels: np.ndarray, cfg: LayersConfig, sz_m: np.ndarray | None = None
) -> tuple[int | None, tuple[int, ...]]:
    """(n, points per layer 0..): the highest layer with enough points, and with the points' (N, 2)
    places in the plane `sz_m`, the layer just above it where it holds a plate's width of points
    (`LayersConfig.min_thin_layer_width`). On the 480 real captures of bench seeds 31350-31829 the
    layers above the count with 12 points or more but under the share spanned 12.0-34 mm where they were
    a link (31739, 31817: 6 links read as 5; 31403, 31529, 31731) and 2.3-10.5 mm where they were not."""
    counts = np.bincount(np.clip(labels, 0, MAX_MOVING_LINKS + 1), minlength=MAX_MOVING_LINKS + 2)
    enough = max(cfg.min_layer_points, cfg.min_layer_fraction * len(labels))
    populated = np.nonzero(counts[1 : MAX_MOVING_LINKS + 1] >= enough)[0]
    n = int(populated.max()) + 1 if len(populated) else None
    if sz_m is not None and n is not None and n < MAX_MOVING_LINKS and counts[n + 1] >= cfg.min_layer_points:
        if width_m(sz_m[labels == n + 1]) >= cfg.min_thin_layer_width * 2 * cfg.half_width_m:
            n += 1
    return n, tuple(int(c) for c in counts)


def _links_ahead(p: np.ndarray, view_t: np.ndarray, sign_known: bool, cfg: LayersConfig) -> np.ndarray:
    """(3,) +-1 factors on (s, t, z) that put the links at larger t than the base link: every moving
    link is a layer or more past it. Read from the plate centres (faces moved half a thickness by the
    side they were seen from) of the points off the base's column (beyond two plate widths of the
    axis) against the column's. Where the profile read a sign (`sign_known`), it is turned only where
    those points lie more than half a pitch behind the column: the profile reads its sign from the
    faces of everything above the base's first 4.5 cm, and a tall base with a short link at its top
    (bench seed 30462: 1.74 and 0.30 paper units, seen more from one side) outweighed the link. Where
    it read none and no link leaves the column, the column's top against its foot."""
    centre_t = p[:, 1] - chain_sides(view_t, cfg.min_side_cosine) * cfg.half_thickness_m
    column = np.abs(p[:, 0]) < cfg.half_width_m
    off = np.abs(p[:, 0]) > 2 * cfg.half_width_m
    if off.sum() >= MIN_OFF_COLUMN_POINTS and column.sum() >= MIN_OFF_COLUMN_POINTS:
        ahead_m = float(np.median(centre_t[off]) - np.median(centre_t[column]))
        behind = ahead_m < (-cfg.layer_pitch_m / 2 if sign_known else 0.0)
    elif sign_known:
        behind = False
    else:
        low = p[:, 2] < np.percentile(p[:, 2], 15)
        high = p[:, 2] > np.percentile(p[:, 2], 70)
        behind = np.median(p[high, 1]) < np.median(p[low, 1])
    if not behind:
        return np.ones(3)
    # a sign read wrong turns the profile half round about the base axis (s too, so that the joint
    # angles keep the object's sign); one not read stays a mirror image in s, as found
    return np.array([-1.0 if sign_known else 1.0, -1.0, 1.0])


#: Points off the base's column that tell a chain's sign (`_links_ahead`).
MIN_OFF_COLUMN_POINTS = 20


def measure_layers(
    points_stz_m: np.ndarray,
    print_scale: float,
    sign_known: bool = True,
    cfg: LayersConfig = LayersConfig(),
    view_dirs: np.ndarray | None = None,
    at_count: int | None = None,
) -> LayerMeasurement:
    """Count, lengths and angles of the chain from its (N, 3) points in the profile frame (s, t, z)
    (`observe.profile.ChainProfile`; `sign_known` its flag) and, where known, the (N, 3) unit
    directions towards the cameras that saw them, in the same frame. `at_count`: the lengths and
    angles of a chain of that many links, where another estimator is sure of more links than the
    layers count (`_at_count`)."""
    p = np.asarray(points_stz_m, np.float64)
    v = np.zeros_like(p) if view_dirs is None else np.asarray(view_dirs, np.float64)
    keep = p[:, 2] > cfg.min_height_m
    p, v = p[keep], v[keep]
    if len(p):
        flip = _links_ahead(p, v[:, 1], sign_known, cfg)
        p, v = p * flip, v * flip
    if len(p) > cfg.max_points:
        pick = np.linspace(0, len(p) - 1, cfg.max_points).astype(np.int64)
        p, v = p[pick], v[pick]
    if len(p) < cfg.min_layer_points:
        return LayerMeasurement(None, None, None, ())
    readings, zero = read_layers(p, None if view_dirs is None else v[:, 1], cfg, flip)
    readings = [adopt_fragments(p[:, [0, 2]], *reading, cfg.radius_m, cfg.min_layer_points) for reading in readings]
    thickness = None
    if view_dirs is not None and cfg.joint_thickness:
        thickness = Thickness(p[:, [0, 2]], p[:, 1], chain_sides(v[:, 1], cfg.min_side_cosine), cfg.layer_pitch_m)
        if not thickness.holds(2 * cfg.half_thickness_m):
            thickness = None
    seen_from = 0 if view_dirs is None else seen_from_side(v[:, 1], cfg.min_side_cosine)
    m = replace(_chosen_reading(p, readings, print_scale, cfg, thickness, seen_from), comb_zero=zero)
    if at_count is None or m.n_links is None or m.n_links >= at_count:
        return m
    return _at_count(p, readings, m, at_count, print_scale, cfg, seen_from)


def _at_count(
    p: np.ndarray,
    readings: list[tuple[np.ndarray, np.ndarray]],
    m: LayerMeasurement,
    count: int,
    print_scale: float,
    cfg: LayersConfig,
    seen_from: int,
) -> LayerMeasurement:
    """The chain on points `p` measured at `count` links, more than `m` counted (another estimator is
    sure of them), or no count with the reason. The measurement's own failure is to count too few:
    two links in one layer, whose step of a pitch across the plane a Kinect's smoothing and joint
    play flattened below `measure.steps`'s threshold (bench seed 31468: links 2 and 3 of 5 at 2.5 deg
    in one layer), or a short last link merged into its parent as a cut plate (31485, a clean render:
    4 links read as 3). So, a link at a time from the layers as `m` settled: each layer split where its
    plate centres step up the likeliest (`steps.layer_steps`), each split fitted, and the chain
    closest to its points in the plane and across it kept (`LayerMeasurement.cost_m`: a layer still
    holding two links holds the step between them); where no layer holds enough points for a step,
    the layers a reading read (`readings`) where it counted that many. The readings' layers only then:
    a reading's rounding cuts a collinear pair where their plate centres cross half a pitch, not where
    they step (30899, a clean render: the last joint 20 mm out, where the likeliest step put it 3 mm
    out). No count where neither holds a link more, or the chain of `count` links is no chain (too
    loose, a link too short to print)."""
    plate_t_m = readings[0][1] * cfg.layer_pitch_m
    sz = p[:, [0, 2]]
    labels, n, x = m.labels, m.n_links, None
    while n < count:
        layers = [sz[labels == k] for k in range(n + 1)]
        if x is None:  # the settled chain's fit is not kept on `m`; a split's is, from the last round
            x = fit_layers(layers, n, cfg)[0]
        starts, ends = plate_segments(x, n, cfg)
        layers_t = [plate_t_m[labels == k] for k in range(n + 1)]
        candidates = []
        for j, at, _ in layer_steps(layers, layers_t, starts, ends, cfg.layer_pitch_m):
            # as `_measure_reading` splits: the layer's points beyond `at`, and every layer above, move up one
            above = (labels > j) | ((labels == j) & ((sz - at) @ (at - starts[j]) > 0))
            candidates.append(np.where(above, labels + 1, labels))
        if not candidates:
            candidates = [np.clip(read, 0, n + 1) for read, _ in readings if count_links(read, cfg)[0] == n + 1]
        if not candidates:
            why = f"no layer of the {n} links measured steps up where a link {n + 1} could begin"
            return LayerMeasurement(None, None, None, m.points_per_layer, reason=why)
        n += 1
        fits = [(fit_layers([sz[c == k] for k in range(n + 1)], n, cfg), c) for c in candidates]
        costs = [np.hypot(rms, layer_t_rms_m(sz, plate_t_m, c, n)) for (_, rms), c in fits]
        (x, rms), labels = fits[int(np.argmin(costs))]
    per_layer = count_links(labels, cfg)[1]
    if rms > cfg.max_rms_m or unprintable_link(x, n, cfg) is not None:
        why = (
            f"its points split into {count} links fit no chain of them ({1000 * rms:.1f} mm RMS, or a link"
            " too short to print)"
        )
        return LayerMeasurement(None, None, None, per_layer, rms, reason=why)
    x = _refit_seen_from(p, labels, n, cfg, x, seen_from)
    # every point is read in layers 0..count here: none lies beyond the chain (`_with_points_beyond`)
    return _chain(p, labels, n, x, rms, per_layer, print_scale, plate_t_m)


def _chosen_reading(
    p: np.ndarray,
    readings: list,
    print_scale: float,
    cfg: LayersConfig,
    thickness: Thickness | None,
    seen_from: int = 0,
) -> LayerMeasurement:
    """The chain of the reading that read the plates right, where the two readings (`layer_readings`)
    differ."""
    # one plate-centre t for every reading (the comb's, its shear out): their layers' spreads compare
    plate_t_m = readings[0][1] * cfg.layer_pitch_m
    # both readings, and each read twice where a layer was kept, pass through many of the same layers:
    # each fitted once (a 5-link Kinect sweep: 26 fits, 15 of them different, 5.3 s)
    fits: dict[tuple[int, bytes], tuple[np.ndarray, float]] = {}
    as_designed = _measure_reading_both(p, *readings[0], print_scale, cfg, thickness, plate_t_m, seen_from, fits=fits)
    if len(readings) == 1 or np.array_equal(readings[1][0], readings[0][0]):  # the rig: one reading
        return as_designed
    followed = _measure_reading_both(p, *readings[1], print_scale, cfg, thickness, plate_t_m, seen_from, fits=fits)
    if followed.n_links is None or as_designed.n_links is None:
        # a reading that did not settle passed through a chain: where it counts as the other reading
        # does and holds the points clearly closer, it places the joints (bench seed 30880, 5 links:
        # the comb's reading passed through the right chain at 1.3 mm RMS and its checks took it to 4
        # links at 2.6 mm; the followed reading's 5 at 2.56 mm had its joints 62 deg off)
        for unsettled, other in ((as_designed, followed), (followed, as_designed)):
            passed = unsettled.closest_passed
            if (
                passed is not None
                and passed.n_links == other.n_links
                and passed.rms_m <= ONE_COUNT_RMS_SHARE * other.rms_m
            ):
                return passed
        return as_designed if followed.n_links is None else followed
    # a reading past the last layer a chain can have misread the comb; one with two pieces in one layer
    # misread a plate, which tells counts apart, but with one count the closer chain places its joints
    past = [past_last_layer(labels) for labels, _ in readings]
    if past[0] != past[1]:
        return followed if past[0] else as_designed
    if followed.n_links == as_designed.n_links:
        closer, looser = sorted((as_designed, followed), key=lambda m: m.rms_m)
        if closer.rms_m <= ONE_COUNT_RMS_SHARE * looser.rms_m:
            return closer
    else:  # other counts: a reading much further from its points than the other's misread them
        closer, looser = sorted((as_designed, followed), key=lambda m: (m.cost_m, m.n_links))
        if looser.cost_m > closer.cost_m and looser.cost_m >= SPLIT_OVERRULED_COST_RATIO * closer.cost_m:
            return closer
    split = [split_layers(p[:, [0, 2]], labels, cfg) for labels, _ in readings]
    if split[0] != split[1]:
        return as_designed if split[0] < split[1] else followed
    if followed.n_links == as_designed.n_links:  # a near tie keeps the comb's
        return as_designed
    # other counts, neither reading splitting a link: the chain closer to its points in the plane and
    # across it (`LayerMeasurement.cost_m`). In the plane alone a link too many or too few fits about
    # as closely (bench seed 30538, 5 links: 4 at 1.01 mm, 5 at 1.05 mm); across it, a layer that holds
    # two links holds the step between them (0.76 against 0.53 mm). A tie: the fewer links
    return min((as_designed, followed), key=lambda m: (m.cost_m, m.n_links))


#: Where the two readings count the same links, the one whose chain holds its points at least this much
#: closer (RMS) places the joints, whatever the split-layer check says (it tells counts apart): the
#: other put a piece of one link in another's layer, and its fit put the joint between them where it
#: is not (bench seed 30421, 2 links: RMS 3.3 mm against 0.15 mm, the last link measured 18 mm for
#: 29 mm; 30879, 4 links: the comb's reading at 2.24 mm had two pieces in one layer, the followed one's
#: at 2.69 mm its joints 65 deg off). A near tie keeps the comb's. 0.65 (followed only) until 0.6.27.
#: Run end to end on the 480 real and clean-render recordings of seeds 30678-30917 (with
#: `closest_passed`), no count changed and 22 answers moved, 30879 65 -> 4 deg (docs/observe.md);
#: 1.0 (no margin) put a synthetic capture's joints 4.5 deg off
#: (`test_noise_shear_and_sides_out_of_register`, 0.682 against 0.668 mm).
ONE_COUNT_RMS_SHARE = 0.9
#: Where the two readings count otherwise, the one whose chain lies at least this many times as far
#: from its points (`LayerMeasurement.cost_m`) loses, before the one-piece-a-layer check
#: (`split_layers`) is asked: a piece of a plate in another layer costs a reading little, a misread
#: count much. Bench seed 32438 (3 links, real): the comb's reading split a layer once and held its
#: 3 links at 2.8 mm, the followed reading's 2 at 4.9 mm stood. Over 576 real development captures
#: (seeds 32358-32933) the readings counted otherwise in 75 pairs: the ratio chose right in 66 where
#: the split check first chose right in 64, and lost none (docs/observe.md).
SPLIT_OVERRULED_COST_RATIO = 1.7
#: A SPARE chain has links in layers 0..6 only; where more than this share of the points lie past the
#: sixth link's layer, the reading (or the object) is thicker than any chain (`past_last_layer`;
#: `predict.abstain` then gives no answer): 0 on simulated captures read right, 30-44 % on single
#: real frames of a shelf where the layers still counted 5 or 6 links.
MAX_PAST_LAST_LAYER_FRACTION = 0.05
#: ... unless at least this share of those points lie on the measured last link's plate in the
#: chain's plane (`LayerMeasurement.past_on_last_plate`): that plate, carried past its own layer by
#: the joints' play, leaning 1-4 deg each and adding up along a 6-link chain. Held-out 32093 (6 links,
#: D435, tracked) and 31997 (6 links, Kinect, tracked), now development: 570 of 3,500 and 322 of
#: 2,633 points past the sixth layer, 100 % and 86 % of them on link 6's plate; a chain of 6 links at
#: 0.34 and 2.0 mm RMS, no answer until release 0.6.43. Over the 2,300 other bench recordings kept
#: since seed 31254 none had more than 2.5 % of its points past the sixth layer.
MIN_PAST_ON_LAST_PLATE = 0.8
#: A reading whose checks (a split at a hidden joint, a cut plate or a stray top layer merged) end on a
#: chain holding its points more than this many times looser (RMS) than the closest chain they passed
#: through did not settle: its evidence contradicts itself, and it gives no count. Rig view of bench
#: seed 30485 (6 links, a 115 deg fold at the first joint, one frame): splits and merges went round
#: from 5 links at 4.0 mm through 5 at 2.3 mm down to 1 link at 6.1 mm, and `predict` answered 1. On
#: the 144 recordings of seeds 30438-30485 (development), 420 readings, the next loosest ended 1.9, 1.8
#: and twice 1.6 times looser than their closest chain, each a reading that lost to the other one.
MAX_LOOSENING = 2.0
#: A measured chain whose layers' plate centres spread across the plane (`layer_t_rms_m`) by more than
#: this many layer pitches (RMS) gives no count (`layers_told_apart`): a line through a whole pitch's
#: step leaves a quarter of it, so its layers spread, on average, as far as one that holds two links.
#: On the 575 recordings of seeds 30438-30629 (development: real, clean renders, rig) the answers'
#: layers spread 0.1-1.5 mm where their count was right; the three answers past 1.6 mm were wrong (real
#: 30628, 5 links read as 4 at 1.72 mm; clean renders 30537 and 30441, 1.63 and 1.62 mm).
MAX_LAYER_SPREAD_PITCHES = 0.25


def layers_told_apart(m: LayerMeasurement, cfg: LayersConfig) -> LayerMeasurement:
    """`m`, or no count, with the reason and its evidence kept, where its layers' plate centres spread
    across the chain's plane by more than `MAX_LAYER_SPREAD_PITCHES`: its layers are not told apart,
    and neither is its count (bench seed 30643, a 2-link sweep brought into register from its frames
    alone: 4 links at 9.0 mm in the plane, its layers spread 3.8 mm)."""
    if m.n_links is None or m.t_rms_m is None or m.t_rms_m <= MAX_LAYER_SPREAD_PITCHES * cfg.layer_pitch_m:
        return m
    reason = (
        f"its layers' plate centres spread {1000 * m.t_rms_m:.1f} mm (RMS) across the chain's plane, as "
        "far as a link's step to the next layer: its layers are not told apart (a blurred capture)"
    )
    return replace(m, n_links=None, lengths_pu=None, angles_rad=None, reason=reason, layers_blurred=True)


def past_last_layer(labels: np.ndarray) -> bool:
    """Whether more than `MAX_PAST_LAST_LAYER_FRACTION` of the points lie past the last link's layer
    a chain can have (`config.MAX_MOVING_LINKS`): the comb held still while joint play's leans climbed
    along the chain (bench seed 30094, 5 links: 95 of 1,481 points read past layer 6, the followed
    comb's reading 5 clean layers)."""
    return bool((labels > MAX_MOVING_LINKS).sum() > MAX_PAST_LAST_LAYER_FRACTION * len(labels))


def split_layers(sz_m: np.ndarray, labels: np.ndarray, cfg: LayersConfig) -> int:
    """How many more pieces than links the layers 1..n of a reading hold (n as the reading counts
    them, before any layer is found to be no link): pieces of a layer not joined in the plane
    (within `radius_m`), each of at least `fragments.MIN_PIECE_POINTS` points and `MIN_PIECE_SHARE`. A link
    is one plate, so each of its layers is one piece; a reading that puts two separate parts of the
    chain in one layer has read a plate across a layer boundary (the comb held still while joint
    play's leans climbed along a straight run of short links: bench seed 30068, 3 links read as 1)."""
    n = count_links(labels, cfg, sz_m)[0] or 0
    labels = np.clip(labels, 0, n)
    extra = 0
    for k in range(1, n + 1):
        mine = labels == k
        if mine.sum() >= 2:
            extra += max(counted_pieces(np.bincount(pieces(sz_m[mine], cfg.radius_m)), int(mine.sum())) - 1, 0)
    return extra


def _measure_reading_both(*reading, fits: dict | None = None) -> LayerMeasurement:
    """`_measure_reading` of the same arguments (`reading`), where a layer a whole layer up on a joint
    fitted one plate thick is read where it meets its parent (`merges.is_cut`, `merges.MIN_LINK_RISE_LAYERS`).
    Where that kept a layer, the reading is measured without it too: where both count and count
    otherwise, the count with the layer kept stands; with one count, the closer fit. A layer kept
    whose split from its parent was misread fits looser than merging it and splitting at the hidden
    joint (the rig's test split, instances 450, 508, 1647, 2113, 2758: the same count, RMS 1.0-6.3
    mm kept against 0.9-6.0 mm merged, lengths further off)."""
    kept: list[int] = []
    read_again = _measure_reading(*reading, kept, fits)  # `reading` ends with `seen_from`
    if not kept:
        return read_again
    plain = _measure_reading(*reading, None, fits)
    if plain.n_links is None or read_again.n_links is None:
        return plain
    if read_again.n_links != plain.n_links:
        return read_again
    return read_again if read_again.rms_m < plain.rms_m else plain


def _measure_reading(
    p: np.ndarray,
    labels: np.ndarray,
    centre_layers: np.ndarray,
    print_scale: float,
    cfg: LayersConfig,
    thickness: Thickness | None,
    plate_t_m: np.ndarray,
    seen_from: int = 0,
    kept: list[int] | None = None,
    fits: dict | None = None,
) -> LayerMeasurement:
    """The chain of points `p` (s, t, z) with one reading of their layers: counted, fitted and
    checked (a top layer that is no link, a plate cut in two by its lean, a link too short to
    print, and where `thickness` sees them, joints no thicker than a plate and a plate as thick as a
    joint: `measure.joints`; a layer whose plate centres `plate_t_m` step along it: `measure.steps`),
    its lengths and angles refitted without the discs hidden from a capture seen from one side
    (`seen_from`, `fit.refit_seen_from`),
    or why it is no chain. `fits`: the fits of these points made so far, shared (`_fit`)."""
    n, per_layer = count_links(labels, cfg, p[:, [0, 2]])
    if n is None:
        return LayerMeasurement(None, None, None, per_layer)
    split_before: set[bytes] = set()
    # a layer split at a hidden joint and merged back comes round to the same layers again: their fit
    # is kept (a blurred capture's fit runs to the fit's limit of evaluations: bench seed 30441)
    fitted: dict[tuple[int, bytes], tuple[np.ndarray, float]] = {}
    while True:
        labels_n = np.clip(labels, 0, n)
        layers = [p[labels_n == k][:, [0, 2]] for k in range(n + 1)]
        key = (n, labels_n.tobytes())
        if key not in fitted:
            fitted[key] = _fit(layers, n, cfg, key, fits)
        x, rms = fitted[key]
        centres = [centre_layers[labels_n == k] for k in range(n + 1)]
        starts, ends = plate_segments(x, n, cfg)
        # a layer as thick as a joint somewhere along it holds two links: split it first, as a plate
        # fitted to two links puts the joints after it where they are not
        split = None
        if n < MAX_MOVING_LINKS and len(split_before) < MAX_MOVING_LINKS:
            if thickness is not None:
                split = hidden_joint(thickness, layers, starts)
            if split is None:  # or where its plate centres step by a joint's
                layers_t = [plate_t_m[labels_n == k] for k in range(n + 1)]
                split = stepped_layer(layers, layers_t, starts, ends, cfg.layer_pitch_m)
            if split is None and cfg.bends:  # or where its points bend in the plane
                split = bent_layer(layers, starts, ends, cfg.half_width_m)
        if split is not None:
            j, at = split[:2]  # its points beyond the pin, and every layer above, move up one
            sz = p[:, [0, 2]]
            if len(split) == 3:  # a bend: each point to the nearer of the two plates meeting there
                beyond = beyond_bend(sz, starts[j], at, split[2])
            else:
                beyond = (sz - at) @ (at - starts[j]) > 0
            above = (labels > j) | ((labels_n == j) & beyond)
            split_labels = np.where(above, labels + 1, labels)
            if split_labels.tobytes() not in split_before:  # else split there and merged back since
                split_before.add(split_labels.tobytes())
                labels, centre_layers = split_labels, np.where(above, centre_layers + 1, centre_layers)
                per_layer = count_links(labels, cfg)[1]
                n += 1
                continue
        excess = np.full(n, np.nan) if thickness is None else joint_excess_layers(thickness, starts)
        if n > 1 and (
            top_layer_is_stray(x, layers, centres[n], n, cfg)
            or is_cut(layers, centres, excess, n, thickness, cfg.half_width_m, kept)
        ):
            n -= 1
            labels = np.minimum(labels, n)  # as the fit reads them: a later split renumbers what is there
            continue
        # the top layer settled first: a tilted plate cut in two lower down reads as a link of its own,
        # often one too short to print
        cut = unprintable_link(x, n, cfg) or next(
            (k for k in range(2, n) if is_cut(layers, centres, excess, k, thickness, cfg.half_width_m, kept)), None
        )
        if cut is None:
            break
        above = labels >= cut  # its layer joins its parent's, and every layer above moves down one
        labels = np.where(above, labels - 1, labels)
        centre_layers = np.where(above, centre_layers - 1, centre_layers)
        per_layer = count_links(labels, cfg)[1]  # the evidence as renumbered
        n -= 1
    if rms > cfg.max_rms_m:
        reason = (
            f"the points lie {1000 * rms:.0f} mm (RMS) off the best chain of {n} links: "
            "a blurred capture (its views out of register), or no chain"
        )
        return LayerMeasurement(None, None, None, per_layer, rms, reason)
    (best_n, best_labels), (best_x, best_rms) = min(fitted.items(), key=lambda item: item[1][1])
    if rms > MAX_LOOSENING * best_rms:
        reason = (
            f"the layers' reading did not settle: its checks took a chain of {best_n} links at "
            f"{1000 * best_rms:.1f} mm (RMS) to {n} at {1000 * rms:.1f} mm"
        )
        best_labels_n = np.frombuffer(best_labels, labels_n.dtype)
        best_x = _refit_seen_from(p, best_labels_n, best_n, cfg, best_x, seen_from)
        passed = _chain(
            p, best_labels_n, best_n, best_x, best_rms, count_links(best_labels_n, cfg)[1], print_scale, plate_t_m
        )
        return LayerMeasurement(None, None, None, per_layer, rms, reason, closest_passed=passed)
    x = _refit_seen_from(p, labels_n, n, cfg, x, seen_from)
    m = _chain(p, labels_n, n, x, rms, per_layer, print_scale, plate_t_m)
    return _with_points_beyond(m, p, labels, x, cfg)


def _fit(layers: list[np.ndarray], n: int, cfg: LayersConfig, key: tuple[int, bytes], fits: dict | None):
    """`fit.fit_layers` of the layers read as `key` (the count, the points' labels), from `fits` (fits
    of the same points already made, which this adds to) where it holds them: the same layers give the
    same fit, so the answer does not depend on what was fitted before."""
    if fits is None:
        return fit_layers(layers, n, cfg)
    if key not in fits:
        fits[key] = fit_layers(layers, n, cfg)
    return fits[key]


def _refit_seen_from(
    p: np.ndarray, labels_n: np.ndarray, n: int, cfg: LayersConfig, x: np.ndarray, seen_from: int
) -> np.ndarray:
    """The settled chain `x` of a reading refitted where the capture saw it from one side (`seen_from`:
    `fit.refit_seen_from`), else `x`. The checks read the plates that cover every disc, so the count
    stays theirs; only lengths and angles come from the refit."""
    if not seen_from:
        return x
    return refit_seen_from([p[labels_n == k][:, [0, 2]] for k in range(n + 1)], n, cfg, x, seen_from)


def _chain(
    p: np.ndarray,
    labels_n: np.ndarray,
    n: int,
    x: np.ndarray,
    rms: float,
    per_layer: tuple[int, ...],
    print_scale: float,
    plate_t_m: np.ndarray,
) -> LayerMeasurement:
    """The measurement of the chain `x` fitted at `rms` to points `p` read in layers `labels_n` (0..n)."""
    angles = (x[n + 2 :] + np.pi) % (2 * np.pi) - np.pi
    t_rms = layer_t_rms_m(p[:, [0, 2]], plate_t_m, labels_n, n)
    return LayerMeasurement(n, x[1 : n + 2] / print_scale, angles, per_layer, rms, t_rms_m=t_rms, labels=labels_n)


def _with_points_beyond(
    m: LayerMeasurement, p: np.ndarray, labels: np.ndarray, x: np.ndarray, cfg: LayersConfig
) -> LayerMeasurement:
    """`m` with the shares of the points beyond its chain `x` that lie on its last plate: those read
    past the sixth link's layer, and those of the layer just above the last where it holds at least
    `min_layer_points` (labels: every point's layer as the chain settled, those above it included)."""
    n = m.n_links
    above = labels == n + 1
    return replace(
        m,
        past_on_last_plate=_on_last_plate(p, labels > MAX_MOVING_LINKS, x, n, cfg),
        above_on_last_plate=_on_last_plate(p, above, x, n, cfg) if above.sum() >= cfg.min_layer_points else None,
    )


def _on_last_plate(p: np.ndarray, beyond: np.ndarray, x: np.ndarray, n: int, cfg: LayersConfig) -> float | None:
    """The share of the points `beyond` (a mask of `p`) that lie on the last plate of the chain `x` in
    the plane (within its half width and the coverage tolerance); None where the mask holds none."""
    if not beyond.any():
        return None
    starts, ends = plate_segments(x, n, cfg)
    return share_on_plate(p[beyond][:, [0, 2]], starts[n], ends[n], cfg)


def layer_t_rms_m(sz_m: np.ndarray, plate_t_m: np.ndarray, labels: np.ndarray, n: int) -> float:
    """RMS of the points' plate centres across the plane (`plate_t_m`) about each layer 0..n's own
    plane fitted through them (t linear in s and z: a plate leaning out of its layer by the joints'
    play is still one plane). A layer that holds two links holds a step of a whole pitch where they
    meet, which no plane fits; a layer that holds one plate holds the sensor's noise only."""
    squares, count = 0.0, 0
    for k in range(n + 1):
        mine = labels == k
        if mine.sum() < 4:
            continue
        design = np.column_stack([sz_m[mine], np.ones(int(mine.sum()))])
        coef, *_ = np.linalg.lstsq(design, plate_t_m[mine], rcond=None)
        squares += float(np.sum((plate_t_m[mine] - design @ coef) ** 2))
        count += int(mine.sum())
    return float(np.sqrt(squares / count)) if count else 0.0


def measure_profile(
    obj: ObjectPoints,
    profile: ChainProfile,
    print_scale: float,
    cfg: LayersConfig = LayersConfig(),
    at_count: int | None = None,
) -> LayerMeasurement:
    """`measure_layers` of an observation's points in its profile frame (None-filled where the
    profile found no chain); `at_count` as there."""
    if profile.reason is not None or len(obj.points_m) == 0:
        return LayerMeasurement(None, None, None, ())
    points_m, view_dirs = obj.points_m, obj.view_dirs
    if obj.fine_points_m is not None and len(obj.fine_points_m):
        points_m, view_dirs = obj.fine_points_m, obj.fine_view_dirs
    points = profile.in_profile_frame(points_m)
    view_dirs = None if view_dirs is None else view_dirs @ profile.T_table_profile[:3, :3]
    return measure_layers(points, print_scale, profile.sign_known, cfg, view_dirs, at_count)
