"""The object's points as the chain's profile: the image the yaw-free network reads.

A SPARE chain moves in one vertical plane through its base (its joint axes are parallel and
horizontal), so its shape is the side view of that plane. `chain_profile` finds the plane from the
points alone and draws them in it:

1. the base axis: the foot's socket boss (5..17 mm above the table; links never come that low) and the
   bottom of the base link; the median of their horizontal positions;
2. the plane: at right angles to the links' faces, whose normals (each read in its own depth image)
   pile up along the joint axes (`_plane_direction`);
3. its sign: a chain's links are stacked in layers, each a layer pitch (6.4 mm with the default
   parts) further along the joint axes (+y of the object) than its parent, so the links sit at
   larger t than the base link, never smaller.
   s is turned so that they do; then s is the object's x, t its y, and joint angles have the
   object's own sign. Where the points do not tell (as many a layer ahead as behind) s stays as
   found;
4. the image: H x W cells over z in [0, 3.2] and s in [-1.9, 1.9] paper units (points divided by
   the print scale), channels: occupancy, mean t and t extent of the points in a cell, t in layers
   (the links' pitch: link k sits at about k).

The geometry is the printed parts' (`ProfileConfig.for_parts`: layer pitch, plates, socket); the
defaults are the default parts', on which every network was trained.

It also says when the points are not a chain at all (`reason`): too low or too tall, no base column,
reaching farther than a chain can, or too thick across its plane.

No yaw is assumed anywhere: the plane is found, so the network sees every object the same way
whatever its yaw, and training draws yaw from the whole circle to prove it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spare_twin.config import PartDims
from spare_twin.observe.points import ObjectPoints

#: The chain's geometry in paper units (docs/design.md): base >= 1.3 * 3/8 after rescaling, whole
#: chain <= 3, reach from the base axis <= 1.7 plus the links' width.
Z_RANGE_PU = (0.0, 3.2)
S_RANGE_PU = (-1.9, 1.9)
CHANNELS = ("occupancy", "mean_t", "t_extent")
#: How far past a plate's faces the base column's points may lie across the plane (noise, registration blur).
COLUMN_BLUR_M = 0.005


def parts_geometry_m(parts: PartDims) -> dict[str, float]:
    """The profile's settings that the printed parts set (metres): the one place they are derived."""
    return {
        "layer_pitch_m": parts.layer_pitch_mm / 1000.0,
        "keepout_m": (parts.foot_thickness_mm + parts.socket_height_mm) / 1000.0,
        "link_width_m": parts.link_width_mm / 1000.0,
        "link_thickness_m": parts.link_thickness_mm / 1000.0,
        "column_half_depth_m": parts.link_thickness_mm / 2000.0 + COLUMN_BLUR_M,
    }


_DEFAULT_PARTS = parts_geometry_m(PartDims())


@dataclass(frozen=True)
class ProfileConfig:
    """Profile geometry (metres unless `_pu`) and the chain checks. The defaults are the default
    parts' (`config.PartDims`); `for_parts` gives another print's."""

    height: int = 64
    width: int = 80
    boss_band_m: tuple[float, float] = (0.008, 0.02)
    """Heights of the socket boss and the base link's foot: their points locate the base axis."""
    keepout_m: float = _DEFAULT_PARTS["keepout_m"]
    """Moving links never come below the socket's top (`object.kinematics.keepout_height_m`): up to
    here only the base stands."""
    plane_min_height_m: float = 0.025
    """Without normals, points above this (clear of the socket) find the plane by their layer phase.
    With normals, every point's counts: the socket's boss is squared to the base link."""
    coarse_step_deg: float = 1.0
    fine_step_deg: float = 0.1
    max_normal_tilt: float = 0.35
    """|n_z| of a face normal (the links' faces are vertical)."""
    min_normal_agreement: float = 0.5
    """A voxel's mean normal this long: its readings agree on a surface."""
    normal_window_deg: float = 4.0
    layer_pitch_m: float = _DEFAULT_PARTS["layer_pitch_m"]
    """Links' layer spacing along the joint axes (link thickness + gap)."""
    link_width_m: float = _DEFAULT_PARTS["link_width_m"]
    link_thickness_m: float = _DEFAULT_PARTS["link_thickness_m"]
    min_height_pu: float = 0.35
    """Shorter objects are not a chain (the shortest base is 1.3 * 3/8 paper units tall... minus noise)."""
    max_height_pu: float = 3.6
    max_reach_pu: float = 2.3
    """No point of a chain is farther from its base axis (1.7 of moving links, plus margin)."""
    max_thickness_m: float = 0.08
    """The 95th percentile of |t|: 7 layers of 6.4 mm, pin heads, noise, registration blur (6 cm
    rejected three real chains in the benchmark)."""
    column_band_m: tuple[float, float] = (0.02, 0.04)
    """Heights where the base link alone stands on the base axis (above the socket)."""
    column_half_width_m: float = 0.015
    column_half_depth_m: float = _DEFAULT_PARTS["column_half_depth_m"]
    wall_reach_m: float = 0.045
    max_wall_ratio: float = 1.0
    """Points in the column's layer beside it (out to `wall_reach_m`) may be at most this many times
    the column's own: more is a wall, not a 12 mm link."""
    min_column_share: float = 0.5
    """At least this share of the points on the base axis just above the socket lie within
    `column_half_depth_m` of it across the plane (half a plate plus noise and registration blur)."""
    max_base_width_m: float = 0.16
    """Below `keepout_m` only the foot stands: its 10 cm plate (noise and registration blur lift it
    above the table cut) and the socket boss."""

    @classmethod
    def for_parts(cls, parts: PartDims, **settings) -> ProfileConfig:
        """The profile of a chain printed with `parts` (its layer pitch, plates and socket); `settings`
        override the rest."""
        return cls(**{**parts_geometry_m(parts), **settings})


@dataclass(frozen=True)
class ChainProfile:
    """What the yaw-free network reads, and the frame it was drawn in."""

    image: np.ndarray
    """float32 (3, H, W): `CHANNELS`; row 0 is the top (largest z)."""
    T_table_profile: np.ndarray
    """4x4 profile frame (origin on the table at the base axis, x = s, y = t, z up) in the table frame."""
    sign_known: bool
    """Whether the layer order fixed s's sign (else joint angles are known up to one global sign)."""
    reason: str | None = None
    """Why these points are not a chain (then `image` is zero)."""

    def in_profile_frame(self, points_table_m: np.ndarray) -> np.ndarray:
        """(N, 3) table-frame points in the profile frame (s, t, z)."""
        T_profile_table = np.linalg.inv(self.T_table_profile)
        return points_table_m @ T_profile_table[:3, :3].T + T_profile_table[:3, 3]


def _layer_concentration(d: np.ndarray, angles_rad: np.ndarray, pitch_m: float) -> np.ndarray:
    """Per direction angle: how well the points' offsets across it (t) fall on one phase of the layer
    pitch (mean resultant length of exp(2 pi i t / pitch), 0..1). Links are slabs 6 mm thick stacked
    6.4 mm apart, so their visible faces (at t = k * pitch +- 3 mm) all share one phase at the plane's
    true direction and none at any other. Smooth in the angle: no histogram, no voxel-grid aliasing."""
    normals = np.stack([-np.sin(angles_rad), np.cos(angles_rad)], 1)
    phase = (2 * np.pi / pitch_m) * (d @ normals.T)  # (N, A)
    return np.hypot(np.cos(phase).mean(0), np.sin(phase).mean(0))


def _face_normal_azimuth(normals: np.ndarray, cfg: ProfileConfig) -> float | None:
    """Azimuth (radians, mod pi) of the chain plane's normal: where the horizontal surface normals
    pile up (the links' broad faces all face along the joint axes; their narrow rims, at right
    angles, are half as wide; the socket's boss is squared to the base link the same way), refined by
    the mean of the normals within `normal_window_deg` of the peak. None with fewer than 20 usable
    normals. With the links' normals alone (the boss left out, release 0.4.1 and before), a 1-link
    chain seen by a Kinect v1 kept 45 usable normals and its plane came out 15 deg off (seed 17000);
    with the boss, 1.7 deg, and over 59 posed development captures the mean error fell from 1.3 to 0.8
    deg, none worse."""
    length = np.linalg.norm(normals, axis=1)
    unit = normals / np.maximum(length, 1e-12)[:, None]
    unit = unit[(length > cfg.min_normal_agreement) & (np.abs(unit[:, 2]) < cfg.max_normal_tilt)]
    if len(unit) < 20:
        return None
    azimuth = np.arctan2(unit[:, 1], unit[:, 0]) % np.pi
    hist = np.bincount(np.floor(np.degrees(azimuth)).astype(np.int64) % 180, minlength=180).astype(np.float64)
    peak = np.radians(int(sum(np.roll(hist, k) for k in range(-3, 4)).argmax()) + 0.5)
    for _ in range(3):
        offset = (azimuth - peak + np.pi / 2) % np.pi - np.pi / 2
        peak += float(np.mean(offset[np.abs(offset) < np.radians(cfg.normal_window_deg)]))
    return peak


def _plane_direction(d: np.ndarray, normals: np.ndarray | None, cfg: ProfileConfig) -> np.ndarray:
    """The chain plane's horizontal direction from the offsets `d` (N, 2) of the points above the
    socket from the base axis and all the object's normals (M, 3): at right angles to the faces'
    normals (`_face_normal_azimuth`). Measured against the truth on 160 hand-held-like views of rig
    renders (noise, per-view registration error): median 0.13 deg, none over 5 deg (links alone).
    Without normals, the direction whose layer phase is most concentrated (`_layer_concentration`):
    as precise on clean views (0.1 deg), but 13 of those 160 were 5..70 deg off, where registration
    blur flattens its peak below a false one."""
    if len(d) < 20:
        return np.array([1.0, 0.0])
    azimuth = None if normals is None else _face_normal_azimuth(normals, cfg)
    if azimuth is not None:
        best = azimuth + np.pi / 2
    else:
        coarse = np.radians(np.arange(0.0, 180.0, cfg.coarse_step_deg))
        best = coarse[int(_layer_concentration(d, coarse, cfg.layer_pitch_m).argmax())]
        fine = best + np.radians(np.arange(-cfg.coarse_step_deg, cfg.coarse_step_deg + 1e-9, cfg.fine_step_deg))
        best = fine[int(_layer_concentration(d, fine, cfg.layer_pitch_m).argmax())]
    return np.array([np.cos(best), np.sin(best)])


def _layer_sign(s: np.ndarray, t: np.ndarray, z: np.ndarray, cfg: ProfileConfig) -> float | None:
    """+1 if the links sit at larger t than the base link, -1 if smaller, None when it cannot be told.
    Every moving link is one or more layers past the base (none is ever behind it), so of the points
    off the base's column, those a layer or more to one side tell the side; the column is read just
    above the socket, below any link's reach (the shortest base link, 3.9 cm at the default scale)."""
    column = (np.abs(s) < 0.012) & (z > cfg.keepout_m + 0.003) & (z < 0.032)
    rest = (z > 0.045) | (np.abs(s) > 0.02)
    if column.sum() < 10 or rest.sum() < 10:
        return None
    offset = t[rest] - np.median(t[column])
    ahead = float(np.mean(offset > 0.5 * cfg.layer_pitch_m))
    behind = float(np.mean(offset < -0.5 * cfg.layer_pitch_m))
    if abs(ahead - behind) < 0.1:
        return None
    return 1.0 if ahead > behind else -1.0


def _not_a_chain(z_pu, r_pu, t_m, base_width_m, cfg: ProfileConfig) -> str | None:
    top = float(np.percentile(z_pu, 99))
    if top < cfg.min_height_pu:
        return f"the tallest thing on the table is {top:.2f} paper units high, too low for a chain's base"
    if top > cfg.max_height_pu:
        return f"the object is {top:.2f} paper units tall, taller than any chain (3)"
    reach = float(np.percentile(r_pu, 99))
    if reach > cfg.max_reach_pu:
        return f"the object reaches {reach:.2f} paper units from its base, farther than a chain can"
    thick = float(np.percentile(np.abs(t_m), 95))
    if thick > cfg.max_thickness_m:
        return f"the object is {100 * thick:.1f} cm thick across its plane; a chain is flat"
    if base_width_m > cfg.max_base_width_m:
        return f"no chain's foot: the object is {100 * base_width_m:.1f} cm wide just above the table"
    return None


def _no_base_link(z: np.ndarray, s: np.ndarray, t: np.ndarray, cfg: ProfileConfig) -> str | None:
    """A chain's base link rises from its socket as one 12 x 6 mm column: just above the socket, most
    points on the base axis lie within one layer of it across the plane (a link folded down beside it
    adds points a few layers off, fewer than the column's own), and in its layer nothing stands
    beside it. A box or a cylinder standing on the table shows only its walls: centimetres off its
    own axis, or, where a partial sweep put the axis on a wall, a plate running on past the column."""
    lo, hi = cfg.column_band_m
    column = (z > lo) & (z < hi) & (np.abs(s) < cfg.column_half_width_m)
    if column.sum() < 10:
        return "no base link rising from a foot"
    on_axis = float(np.mean(np.abs(t[column]) <= cfg.column_half_depth_m))
    depth = float(np.percentile(t[column], 90) - np.percentile(t[column], 10))
    band = (z > lo) & (z < hi) & (np.abs(t) <= cfg.column_half_depth_m)
    beside = band & (np.abs(s) >= cfg.column_half_width_m) & (np.abs(s) < cfg.wall_reach_m)
    if beside.sum() > cfg.max_wall_ratio * (band & column).sum():
        width = float(np.percentile(s[band], 95) - np.percentile(s[band], 5))
        link = f"a chain's base link is {1000 * cfg.link_width_m:g} mm wide"
        return f"what stands there is a wall {100 * width:.1f} cm wide at its foot; {link}"
    if on_axis < cfg.min_column_share:
        link = f"a chain's base link is {1000 * cfg.link_thickness_m:g} mm thick"
        return f"what stands there is {100 * depth:.1f} cm deep at its foot; {link}"
    return None


def chain_profile(obj: ObjectPoints, print_scale: float, cfg: ProfileConfig = ProfileConfig()) -> ChainProfile:
    """The chain's profile image from the observation (see the module doc)."""
    empty = np.zeros((len(CHANNELS), cfg.height, cfg.width), np.float32)
    if obj.reason is not None:
        return ChainProfile(empty, np.eye(4), False, obj.reason)
    p = obj.points_m
    lo, hi = cfg.boss_band_m
    boss = p[(p[:, 2] >= lo) & (p[:, 2] <= hi)]
    if len(boss) < 10:
        boss = p[p[:, 2] <= np.percentile(p[:, 2], 10)]
    base_xy = np.median(boss[:, :2], axis=0)
    d = p[:, :2] - base_xy
    upper = p[:, 2] > cfg.plane_min_height_m
    e = _plane_direction(d[upper], None if obj.normals is None else obj.normals, cfg)
    s, t = d @ e, d @ np.array([-e[1], e[0]])
    sign = _layer_sign(s, t, p[:, 2], cfg)
    if sign is not None and sign < 0:
        e, s, t = -e, -s, -t
    T = np.eye(4)
    T[:2, 0], T[:2, 1], T[:2, 3] = e, [-e[1], e[0]], base_xy
    foot = (p[:, 2] >= lo) & (p[:, 2] <= cfg.keepout_m)
    base_width = float(np.percentile(np.linalg.norm(d[foot], axis=1), 90) * 2) if foot.sum() >= 10 else 0.0
    z_pu, s_pu = p[:, 2] / print_scale, s / print_scale
    reason = _not_a_chain(z_pu, np.abs(s_pu), t, base_width, cfg) or _no_base_link(p[:, 2], s, t, cfg)
    if reason is not None:
        return ChainProfile(empty, T, sign is not None, reason)
    return ChainProfile(draw_profile(s_pu, z_pu, t / cfg.layer_pitch_m, cfg), T, sign is not None)


def draw_profile(s_pu: np.ndarray, z_pu: np.ndarray, t_layers: np.ndarray, cfg: ProfileConfig) -> np.ndarray:
    """float32 (3, H, W) occupancy, mean t and t extent per cell, t in layers (`layer_pitch_m`): link k sits at
    about k, so the image says which link a cell belongs to as plainly as where it is."""
    H, W = cfg.height, cfg.width
    row = np.floor((Z_RANGE_PU[1] - z_pu) / (Z_RANGE_PU[1] - Z_RANGE_PU[0]) * H).astype(np.int64)
    col = np.floor((s_pu - S_RANGE_PU[0]) / (S_RANGE_PU[1] - S_RANGE_PU[0]) * W).astype(np.int64)
    ok = (row >= 0) & (row < H) & (col >= 0) & (col < W)
    cell = row[ok] * W + col[ok]
    t = t_layers[ok]
    count = np.bincount(cell, minlength=H * W).astype(np.float64)
    mean_t = np.bincount(cell, t, minlength=H * W) / np.maximum(count, 1)
    t_max = np.full(H * W, -np.inf)
    t_min = np.full(H * W, np.inf)
    np.maximum.at(t_max, cell, t)
    np.minimum.at(t_min, cell, t)
    occupied = count > 0
    extent = np.where(occupied, t_max - t_min, 0.0)
    img = np.stack([occupied.astype(np.float64), np.where(occupied, mean_t, 0.0), extent])
    return img.reshape(3, H, W).astype(np.float32)
