"""Scene variation for sim-to-real training: rig pose and intrinsics jitter, lighting, link colour
jitter, table colour and clutter. All of it is drawn from one seeded generator per sequence.
`sample_clutter` is also the desk of a hand-held render (`render --clutter N`): boxes and cylinders
clear of the posed object.

With `DomainRandomization()` (all zeros / off, the paper's clean setting) the scene is exactly the
rig's: nominal poses and K, default lighting, named link colours, a plain table, no clutter.
Depth-sensor noise is not here: it is applied when the data is read (`spare_twin.sim.noise`), so one
stored dataset serves both clean and noisy training.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from spare_twin.config import COLORS, ChainSpec
from spare_twin.errors import SpareTwinError
from spare_twin.sim.rig import Rig, jitter_intrinsics, jitter_rig_poses
from spare_twin.sim.twin import DEFAULT_TABLE_RGBA, Lighting, Twin


@dataclass(frozen=True)
class DomainRandomization:
    """How much each sequence's scene departs from the nominal rig (0 / False: not at all)."""

    rig_rot_deg: float = 0.0
    """Std of a random rotation of each camera (an imperfectly built or calibrated rig)."""
    rig_trans_m: float = 0.0
    """Std of each camera's position offset per axis."""
    focal_rel: float = 0.0
    """Std of the relative focal-length error."""
    principal_px: float = 0.0
    """Std of the principal-point error, in network-resolution pixels."""
    lighting: bool = False
    """Random light direction, colour temperature and ambient / diffuse balance."""
    color_jitter: float = 0.0
    """Std of a per-link multiplicative RGB jitter (printed filament is not the nominal colour)."""
    table: bool = False
    """Random table colour."""
    clutter_max: int = 0
    """Up to this many boxes on the table, outside the chain's reach."""

    @property
    def active(self) -> bool:
        return any(bool(v) for v in dataclasses.asdict(self).values())


#: The sim-to-real preset: magnitudes of a hand-built rig calibrated with a checkerboard.
SIM2REAL = DomainRandomization(
    rig_rot_deg=1.0,
    rig_trans_m=0.005,
    focal_rel=0.02,
    principal_px=1.0,
    lighting=True,
    color_jitter=0.12,
    table=True,
    clutter_max=3,
)


@dataclass
class Scene:
    """Everything about one sequence's scene besides the object and its motion."""

    T_world_camera: np.ndarray
    """(V, 4, 4)."""
    K: np.ndarray
    """(V, 3, 3) at the network resolution."""
    lighting: Lighting = field(default_factory=Lighting)
    link_rgb: list | None = None
    """(n + 1) RGB triples overriding the named colours, or None."""
    table_rgba: tuple = DEFAULT_TABLE_RGBA
    clutter: list = field(default_factory=list)
    """Boxes: dicts with half_extents_m, position_m, rgba, yaw_rad."""

    def describe(self) -> dict:
        return {
            "lighting": dataclasses.asdict(self.lighting),
            "link_rgb": self.link_rgb,
            "table_rgba": list(self.table_rgba),
            "clutter": self.clutter,
        }


def sample_scene(rig: Rig, spec: ChainSpec, dr: DomainRandomization, rng: np.random.Generator) -> Scene:
    poses = rig.poses()
    K = np.stack([rig.K()] * rig.n_cameras)
    if not dr.active:
        return Scene(poses, K)
    if dr.rig_rot_deg or dr.rig_trans_m:
        poses = jitter_rig_poses(poses, rng, dr.rig_rot_deg, dr.rig_trans_m)
    if dr.focal_rel or dr.principal_px:
        K = np.stack([jitter_intrinsics(k, rng, dr.focal_rel, dr.principal_px) for k in K])
    lighting = Lighting()
    if dr.lighting:
        az, el = rng.uniform(0, 2 * math.pi), rng.uniform(math.radians(25), math.radians(80))
        warm = rng.uniform(-0.12, 0.12)  # colour temperature: warm (+) to cool (-)
        ambient = rng.uniform(0.25, 0.65)
        lighting = Lighting(
            direction=(math.cos(az) * math.cos(el), math.sin(az) * math.cos(el), math.sin(el)),
            color=(1.0, 1.0 - abs(warm) / 2, 1.0 - warm),
            ambient=ambient,
            diffuse=rng.uniform(0.35, 0.75),
            specular=rng.uniform(0.0, 0.2),
        )
    link_rgb = None
    if dr.color_jitter:
        base = np.array([COLORS[c] for c in spec.colors])
        link_rgb = np.clip(base * (1 + rng.normal(scale=dr.color_jitter, size=base.shape)), 0, 1).round(4).tolist()
    table = DEFAULT_TABLE_RGBA
    if dr.table:
        table = tuple(float(v) for v in rng.uniform(0.15, 0.9, size=3).round(4)) + (1.0,)
    # Outside the chain's reach (<= 0.24 m from the base axis, mostly in the x-z plane) and inside the
    # camera ring (0.42 m), so boxes occlude and clutter but never intersect links.
    n_clutter = int(rng.integers(0, dr.clutter_max + 1)) if dr.clutter_max else 0
    clutter = [_clutter_item(rng, (0.26, 0.34), (0.008, 0.03)) for _ in range(n_clutter)]
    return Scene(poses, K, lighting, link_rgb, table, clutter)


# -- table clutter ----------------------------------------------------------------------------------
CLUTTER_SHAPES = ("box", "cylinder")


@dataclass(frozen=True)
class ClutterConfig:
    """Objects standing on the table round the chain (a hand-held capture's desk), metres."""

    count: int = 0
    r_min_m: float = 0.12
    """Nearest any part of an item comes to the base axis."""
    r_max_m: float = 0.35
    """Farthest any part of an item reaches from the base axis (inside the camera path's 0.37 m)."""
    size_min_m: float = 0.02
    size_max_m: float = 0.12
    """Range of each full extent (box sides, cylinder diameter and height)."""
    margin_m: float = 0.02
    """Least horizontal gap between an item and the chain's footprint or another item."""
    max_tries: int = 500
    """Draws per item before giving up (no room)."""


def _clutter_item(rng: np.random.Generator, r_range_m, half_range_m, shape: str | None = None) -> dict:
    """One item at a random place on a ring round the base axis. The draws (radius, azimuth, half
    extents, colour, yaw) are in the order the dataset's scene randomisation has always used, so its
    scenes stay byte-identical; `shape` None is the dataset's box (no "shape" key)."""
    r, a = rng.uniform(*r_range_m), rng.uniform(0, 2 * math.pi)
    half = rng.uniform(*half_range_m, size=3).round(4)
    if shape == "cylinder":
        half[1] = half[0]  # radius = half_extents[0] = half_extents[1], half height = half_extents[2]
    item = {
        "half_extents_m": half.tolist(),
        "position_m": [round(r * math.cos(a), 4), round(r * math.sin(a), 4), float(half[2])],
        "rgba": rng.uniform(0.1, 0.95, size=3).round(4).tolist() + [1.0],
        "yaw_rad": round(float(rng.uniform(0, math.pi)), 4),
    }
    return item if shape is None else {"shape": shape, **item}


def clutter_radius_m(item: dict) -> float:
    """Radius of the item's horizontal footprint about its centre."""
    hx, hy = item["half_extents_m"][:2]
    return float(hx if item.get("shape") == "cylinder" else math.hypot(hx, hy))


def _point_segment_distance(p: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Distance of the 2-D point `p` to each segment (S, 2, 2)."""
    a, b = segments[:, 0], segments[:, 1]
    ab = b - a
    t = np.clip(((p - a) * ab).sum(1) / np.maximum((ab * ab).sum(1), 1e-12), 0.0, 1.0)
    return np.linalg.norm(a + t[:, None] * ab - p, axis=1)


def sample_clutter(
    cfg: ClutterConfig, rng: np.random.Generator, footprint_xy_m: np.ndarray, footprint_radius_m: float = 0.0
) -> list[dict]:
    """`cfg.count` boxes and cylinders standing on the table, clear of the object and of each other.

    `footprint_xy_m` (S, 2, 2) are the object's footprint segments on the table (e.g. its links'
    centre lines seen from above, over all frames) and `footprint_radius_m` their half width: every
    item keeps `margin_m` from them and from the other items, and lies wholly within r_min..r_max of
    the base axis. Rejection sampling, so a pure function of the generator's state; an error naming
    `clutter` when there is no room."""
    footprint = np.asarray(footprint_xy_m, dtype=np.float64).reshape(-1, 2, 2)
    half_range = (cfg.size_min_m / 2, cfg.size_max_m / 2)
    items: list[dict] = []
    for _ in range(cfg.count):
        for _ in range(cfg.max_tries):
            shape = CLUTTER_SHAPES[int(rng.integers(len(CLUTTER_SHAPES)))]
            item = _clutter_item(rng, (cfg.r_min_m, cfg.r_max_m), half_range, shape)
            c, rad = np.asarray(item["position_m"][:2]), clutter_radius_m(item)
            r = float(np.linalg.norm(c))
            if r - rad < cfg.r_min_m or r + rad > cfg.r_max_m:
                continue
            if len(footprint) and _point_segment_distance(c, footprint).min() < rad + footprint_radius_m + cfg.margin_m:
                continue
            if any(
                np.linalg.norm(c - np.asarray(o["position_m"][:2])) < rad + clutter_radius_m(o) + cfg.margin_m
                for o in items
            ):
                continue
            items.append(item)
            break
        else:
            raise SpareTwinError(
                f"clutter {cfg.count}: no room for item {len(items) + 1} clear of the object on the "
                f"{cfg.r_min_m * 100:.0f}..{cfg.r_max_m * 100:.0f} cm ring"
            )
    return items


def add_clutter(twin: Twin, items: list[dict]) -> None:
    """Put clutter items (from `sample_clutter` or a dataset scene: no "shape" is a box) into the twin."""
    for item in items:
        if item.get("shape", "box") == "box":
            twin.add_box(item["half_extents_m"], item["position_m"], item["rgba"], item["yaw_rad"])
        else:
            half = item["half_extents_m"]
            twin.add_cylinder(half[0], 2 * half[2], item["position_m"], item["rgba"])
