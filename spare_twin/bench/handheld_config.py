"""What `spare-twin dataset --handheld` draws (`HandheldConfig`) and whether a run may start
(`check_handheld`): light to import, so the command refuses a bad count, seed, worker count or folder
before it loads the measurement and torch (5 s of a new process). `bench.handheld_samples` draws the
samples (its module doc says how)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from spare_twin.bench.settings import BenchConfig, CaptureSettings, capture_settings
from spare_twin.nets.sample_folders import HANDHELD_KIND, check_samples_folder
from spare_twin.validate import check_count, check_whole

#: Chain seeds of the training captures start here, far above every bench range (< 1,000,000).
HANDHELD_SEED_BASE = 1_000_000_000
#: Seeds per `--seed`: dataset S draws its objects from base + S * SEED_STRIDE on.
SEED_STRIDE = 1_000_000
#: Objects are drawn in blocks of this many, each with the bench's settings table for a block of this
#: size (`capture_settings` spreads each setting over the objects it is asked for): an object's capture
#: does not depend on `--instances`, so a larger count extends the folder and a smaller one is a prefix.
SETTINGS_BLOCK = 600
#: The largest dataset seed (its objects' chain seeds stay below 2,000,000,000).
MAX_SEED = 999


@dataclass(frozen=True)
class HandheldConfig:
    """What `spare-twin dataset --handheld` draws; a count or seed out of range is refused when it is made."""

    objects: int
    """Captures drawn (object i has n = i % 6 + 1 moving links)."""
    seed: int = 0
    """Dataset seed: object i is chain seed HANDHELD_SEED_BASE + seed * SEED_STRIDE + i."""
    renderers: tuple[str, ...] = ("pybullet", "raycast")
    """Renderers of the captures, as the bench alternates them."""

    def __post_init__(self):
        check_count("instances", self.objects, SEED_STRIDE, "the seeds of one dataset seed")
        check_count("seed", self.seed, MAX_SEED, "the seeds kept for training captures", lower=0)

    def bench_config(self, block: int = 0) -> BenchConfig:
        """The bench configuration of settings block `block` (objects block * SETTINGS_BLOCK on)."""
        first = HANDHELD_SEED_BASE + self.seed * SEED_STRIDE + block * SETTINGS_BLOCK
        return BenchConfig(objects=SETTINGS_BLOCK, seed=first, renderers=self.renderers)

    def settings(self) -> list[CaptureSettings]:
        """Object i's capture settings for i < `objects`: row i % SETTINGS_BLOCK of block i // SETTINGS_BLOCK."""
        blocks = -(-self.objects // SETTINGS_BLOCK)
        rows = [c for b in range(blocks) for c in capture_settings(self.bench_config(b))]
        return rows[: self.objects]


def check_handheld(out: str | Path, hc: HandheldConfig, workers: int, force: bool = False) -> None:
    """`handheld_dataset(out, hc, workers, force=force)` may start: `workers` at least 1, `out` absent,
    empty or a folder of hand-held samples (`force` replaces anything else), and one already there has
    `hc`'s seed (`force` replaces one of another seed)."""
    check_whole("workers", workers, least=1)
    check_samples_folder(out, HANDHELD_KIND, hc.seed, "hand-held samples", force)
