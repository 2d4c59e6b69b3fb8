"""Training samples for the profile network from hand-held captures drawn the bench's way
(`spare-twin dataset --handheld`, docs/nets.md).

The rig's views made to look hand-held (`nets.profile_samples.CaptureAugment`) are not what a real
sweep gives `predict`: a sweep of 15-60 frames at 640 x 480 or 848 x 480, registered (or tracked)
and brought into register on the object, every effect of a print and an active sensor in it. On the
bench's development captures the network trained on those alone counted 0.77 right (240 captures,
seeds 20000-20023 and 30006-30221), the measurement 0.96. Here each sample is such a capture: drawn exactly as the
bench draws its `real` side (`bench.capture.draw_real`, every effect on), observed as `predict`
observes it (`observe.views.recording_views`, `measure.chain.measure_views`), and kept as the profile
image the network reads with the truth as its labels. The capture itself is deleted once observed
(about 8 MB each); a capture on whose points `predict` finds no chain gives no sample (counted as
rejected).

Seeds (`bench.handheld_config`, which holds the configuration and its checks, light to import): object
i of `--seed S` is chain seed `HANDHELD_SEED_BASE + S * SEED_STRIDE + i`, never one of the
bench's ranges (all below 1,000,000), so no held-out capture is ever trained on. Its capture settings
are row i of the bench's settings table (`bench.settings.capture_settings`) drawn for blocks of
`SETTINGS_BLOCK` objects, so they do not depend on how many objects are asked for. Every
`VAL_EVERY`-th round of counts (six objects, one of each count) is validation.

Labels: the count, the 7-slot nominal lengths (paper units: the print's scale error is not in them, as
`predict` is scored on nominal lengths) and the held pose's joint angles in the profile frame's sign:
the profile turns its frame so that a chain's links sit at larger layers than the base, which is the
object's own sign (`observe.profile`); where the measured angles tell the opposite sign, theirs is taken.

The folder is resumable and extendable: one sample file per object (`objects/<name>.npz`, written
whole), so an interrupted run goes on where it stopped and a larger `--instances` draws only the new
objects; `samples.npz` and `manifest.json` are written last. The same seed gives the same bytes.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from spare_twin.bench import capture
from spare_twin.bench.handheld_config import (
    SETTINGS_BLOCK,
    HandheldConfig,
    check_handheld,
)
from spare_twin.bench.settings import BenchConfig, CaptureSettings
from spare_twin.config import MAX_MOVING_LINKS, ChainSpec
from spare_twin.dataset.backends import start_pool
from spare_twin.errors import SpareTwinError
from spare_twin.io import write_bytes_atomic, write_json_atomic
from spare_twin.measure.chain import measure_views
from spare_twin.measure.level import levelled_image
from spare_twin.nets.sample_folders import HANDHELD_FORMAT, HANDHELD_KIND, SPLIT_CODES
from spare_twin.observe.network_input import DEFAULT_PRINT_SCALE
from spare_twin.observe.profile import ProfileConfig
from spare_twin.observe.views import recording_views
from spare_twin.output import writing
from spare_twin.predict.abstain import MIN_ARC_DEG
from spare_twin.recording import Recording, npz_bytes

#: Object i is a validation sample where its round of counts (i // MAX_MOVING_LINKS: one chain of each
#: count) is the last of every VAL_EVERY rounds: validation holds every count alike (release 0.6.14's
#: every tenth object held only 2-, 4- and 6-link chains, since an object's count follows its index).
VAL_EVERY = 10


def split_of(index: int) -> str:
    """Object `index`'s split: "val" in every `VAL_EVERY`-th round of counts, else "train"."""
    return "val" if (index // MAX_MOVING_LINKS) % VAL_EVERY == VAL_EVERY - 1 else "train"


def _labels(d: Path, measured_angles) -> dict[str, np.ndarray]:
    spec = ChainSpec.from_json_file(d / "object" / "object.json")
    held = np.asarray(Recording.open(d / "sensor").ground_truth()["joint_angles_rad"], np.float64)[0]
    sign = 1.0
    if measured_angles is not None and len(measured_angles) == spec.n_links:
        sign = -1.0 if float(np.dot(measured_angles, held)) < 0 else 1.0
    angles = np.zeros(MAX_MOVING_LINKS, np.float32)
    angles[: spec.n_links] = sign * held
    return {
        "n": np.array(spec.n_links, np.int64),
        "lengths": spec.label_lengths().astype(np.float32),
        "angles": angles,
    }


def draw_sample(d: Path, c: CaptureSettings, cfg: BenchConfig) -> dict[str, np.ndarray]:
    """One object's capture drawn into `d`, observed as `predict` observes it, and deleted: its sample
    (`x` the profile image levelled by its layers' comb as `predict` levels it, float16; labels), or
    only `rejected` where no chain was found."""
    obj = capture.build(d, c)
    capture.draw_real(obj, d, c, cfg.effects)
    obs, m = measure_views(recording_views(Recording.open(d / "real")), DEFAULT_PRINT_SCALE, min_arc_deg=MIN_ARC_DEG)
    if obs.reason is not None:
        return {"rejected": np.array(True)}
    image = levelled_image(obs.object, obs.profile, m.comb_zero, DEFAULT_PRINT_SCALE, ProfileConfig())
    sample = {"x": image.astype(np.float16), "rejected": np.array(False)}
    sample.update(_labels(d, None if m.angles_rad is None else np.asarray(m.angles_rad)))
    return sample


def _object_job(args: tuple) -> str:
    root, c, cfg = args
    out = root / "objects" / f"{c.name}.npz"
    scratch = root / "scratch" / c.name
    try:
        sample = draw_sample(scratch, c, cfg)
        sample["settings"] = np.frombuffer(repr(c.to_json()).encode(), np.uint8)
        write_bytes_atomic(out, npz_bytes(sample))
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return c.name


def _done(path: Path, c: CaptureSettings) -> bool:
    """Whether `path` holds this object's sample (an earlier run's, with the same settings)."""
    if not path.is_file():
        return False
    try:
        with np.load(path) as z:
            return bytes(z["settings"]) == repr(c.to_json()).encode()
    except (OSError, ValueError, KeyError):
        return False


def _assemble(root: Path, rows: list[CaptureSettings]) -> dict:
    arrays: dict[str, list] = {"x": [], "n": [], "lengths": [], "angles": [], "split": []}
    rejected = {"train": 0, "val": 0}
    for i, c in enumerate(rows):
        with np.load(root / "objects" / f"{c.name}.npz") as z:
            if bool(z["rejected"]):
                rejected[split_of(i)] += 1
                continue
            for k in ("x", "n", "lengths", "angles"):
                arrays[k].append(z[k])
        arrays["split"].append(SPLIT_CODES[split_of(i)])
    if not arrays["n"]:
        raise SpareTwinError("--handheld: predict found no chain in any capture drawn")
    stacked = {k: np.stack(v) if k != "split" else np.array(v, np.uint8) for k, v in arrays.items()}
    write_bytes_atomic(root / "samples.npz", npz_bytes(stacked))
    counts = {s: int((stacked["split"] == code).sum()) for s, code in SPLIT_CODES.items()}
    return {"samples": counts, "rejected": rejected}


def handheld_dataset(out: str | Path, hc: HandheldConfig, workers: int = 1, progress: bool = True, force: bool = False):
    """Draw (or resume, or extend) the hand-held sample folder `out` (module doc); returns its manifest."""
    check_handheld(out, hc, workers, force)
    cfg = hc.bench_config()
    rows = hc.settings()
    with writing(out, HANDHELD_KIND, (), force, resumable=True) as tmp:
        (tmp / "objects").mkdir(exist_ok=True)
        todo = [(tmp, c, cfg) for c in rows if not _done(tmp / "objects" / f"{c.name}.npz", c)]
        bar = dict(total=len(rows), initial=len(rows) - len(todo), desc="hand-held", unit="capture", file=sys.stderr)
        with tqdm(disable=not progress, **bar) as pbar:
            if workers > 1 and len(todo) > 1:
                with start_pool(min(workers, len(todo))) as pool:
                    for _ in pool.imap_unordered(_object_job, todo):
                        pbar.update()
            else:
                for job in todo:
                    _object_job(job)
                    pbar.update()
        shutil.rmtree(tmp / "scratch", ignore_errors=True)
        manifest = {
            "format": HANDHELD_FORMAT,
            "kind": HANDHELD_KIND,
            "seed": hc.seed,
            "objects": hc.objects,
            "first_chain_seed": cfg.seed,
            "renderers": list(hc.renderers),
            "settings_block": SETTINGS_BLOCK,
            "bench": cfg.to_json(),
            **_assemble(tmp, rows),
            "file": "samples.npz",
        }
        write_json_atomic(tmp / "manifest.json", manifest)
    return manifest
