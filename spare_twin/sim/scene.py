"""Scene variation for sim-to-real training: rig pose and intrinsics jitter, lighting, link colour
jitter, table colour and clutter. All of it is drawn from one seeded generator per sequence.

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
from spare_twin.sim.rig import Rig, jitter_intrinsics, jitter_rig_poses
from spare_twin.sim.twin import DEFAULT_TABLE_RGBA, Lighting


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
    clutter = []
    for _ in range(int(rng.integers(0, dr.clutter_max + 1)) if dr.clutter_max else 0):
        # Outside the chain's reach (<= 0.24 m from the base axis, mostly in the x-z plane) and
        # inside the camera ring (0.42 m), so boxes occlude and clutter but never intersect links.
        r, a = rng.uniform(0.26, 0.34), rng.uniform(0, 2 * math.pi)
        half = rng.uniform(0.008, 0.03, size=3).round(4)
        clutter.append(
            {
                "half_extents_m": half.tolist(),
                "position_m": [round(r * math.cos(a), 4), round(r * math.sin(a), 4), float(half[2])],
                "rgba": rng.uniform(0.1, 0.95, size=3).round(4).tolist() + [1.0],
                "yaw_rad": round(float(rng.uniform(0, math.pi)), 4),
            }
        )
    return Scene(poses, K, lighting, link_rgb, table, clutter)
