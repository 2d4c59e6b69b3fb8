"""What `spare-twin dataset --analytic-profiles` draws (`AnalyticProfileConfig`) and whether a run may
start (`check_analytic`): light to import (no trimesh, no torch), so the command refuses a bad count,
seed, worker count or folder at once. `nets.profile_analytic` draws the samples (its module doc says how).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

from spare_twin.nets.sample_folders import ANALYTIC_KIND, check_samples_folder
from spare_twin.sim.effects import CaptureEffects
from spare_twin.validate import check_count, check_whole

#: Chain seeds of analytic samples start here: above every bench (< 1e6) and hand-held (1e9..2e9) seed.
ANALYTIC_SEED_BASE = 3_000_000_000
#: Seeds per dataset seed S: S's samples are chain seeds base + S * SEED_STRIDE + i.
SEED_STRIDE = 1_000_000
MAX_SEED = 999
#: Every this many rounds of six samples (one chain of each count), the last is validation.
VAL_EVERY = 10
#: Samples per chunk file: what an interrupted run keeps.
CHUNK = 1000

_EFFECTS = CaptureEffects()


@dataclass(frozen=True)
class AnalyticProfileConfig:
    """What `spare-twin dataset --analytic-profiles` draws (lengths in metres, angles in degrees)."""

    samples: int
    """Samples drawn (sample i has n = i % 6 + 1 moving links)."""
    seed: int = 0
    """Dataset seed: sample i is chain seed ANALYTIC_SEED_BASE + seed * SEED_STRIDE + i."""
    joint_tilt_deg: tuple[float, float] = _EFFECTS.joint_tilt_deg
    """Each link's tilt out of the chain's plane (random sign), as the bench's joint play."""
    joint_shift_mm: float = _EFFECTS.joint_shift_mm
    scale_error: tuple[float, float] = _EFFECTS.scale_error
    level_error_deg: tuple[float, float] = _EFFECTS.level_error_deg
    points_per_m2: tuple[float, float] = (1.5e5, 1.0e6)
    """Points per square metre of a face seen (a sweep's fused points, after thinning)."""
    far_face_share: tuple[float, float] = (0.0, 1.0)
    """Share of the far faces seen, drawn as u**2 over this range (most sweeps stay on one side)."""
    rim_share: tuple[float, float] = (0.05, 0.3)
    hidden_share: float = 0.8
    """Of a plate's points behind a nearer plate, this share is hidden."""
    dark_link_prob: float = 0.25
    dark_return: tuple[float, float] = (0.2, 0.6)
    noise_across_m: tuple[float, float] = (0.2e-3, 1.2e-3)
    noise_in_plane_m: tuple[float, float] = (0.3e-3, 1.5e-3)
    views: tuple[int, int] = (6, 20)
    view_offset_m: tuple[float, float] = (0.2e-3, 2.0e-3)
    view_turn_deg: tuple[float, float] = (0.05, 0.4)
    holes: int = 5
    """Up to this many holes, each 3-12 mm across."""
    stray_share: tuple[float, float] = (0.0, 0.005)
    stray_across_m: float = 0.015
    base_axis_error_m: tuple[float, float] = (1.5e-3, 1.0e-3)
    """(s, t) standard deviations of the base axis as found."""
    plane_error_deg: float = 0.7

    def __post_init__(self):
        check_count("instances", self.samples, SEED_STRIDE, "the seeds of one dataset seed")
        check_count("seed", self.seed, MAX_SEED, "the seeds kept for analytic samples", lower=0)

    def to_json(self) -> dict:
        return asdict(self)


def split_of(index: int) -> str:
    """Sample `index`'s split: "val" in every `VAL_EVERY`-th round of counts, else "train"."""
    return "val" if (index // 6) % VAL_EVERY == VAL_EVERY - 1 else "train"


def check_analytic(out: str | Path, c: AnalyticProfileConfig, workers: int = 1, force: bool = False) -> None:
    """`analytic_profiles(out, c, workers, force=force)` may start: `workers` at least 1, `out` absent,
    empty or a folder of analytic samples (`force` replaces anything else), and one already there has
    `c`'s seed (`force` replaces one of another seed)."""
    check_whole("workers", workers, least=1)
    check_samples_folder(out, ANALYTIC_KIND, c.seed, "analytic profile samples", force)
