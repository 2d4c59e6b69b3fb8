"""Sim vs real over many printed objects: `compare` on every object/real pair of a folder, and the
sim-to-real benchmark that makes such a folder from unseen objects first.

A finished comparison (same model and settings) is kept in `<pair>/compare.json`, so an interrupted
batch resumes where it stopped.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from tqdm import tqdm

from spare_twin.capture.simulated import SensorCaptureConfig, simulated_capture
from spare_twin.compare.sim_vs_real import CompareConfig, compare
from spare_twin.compare.table import sim2real_table, write_table
from spare_twin.config import MAX_MOVING_LINKS, sample_chain
from spare_twin.errors import SpareTwinError
from spare_twin.io import read_json, write_json_atomic
from spare_twin.nets.checkpoint import default_model
from spare_twin.object.folder import build_object

#: What a batch keeps of each comparison in its table.
INSTANCE_KEYS = ("name", "truth", "sim", "real", "real_estimated_frame", "errors")


def pairs_in(root: str | Path) -> list[Path]:
    """The `<name>/` folders of `root` that hold both `object/` and `real/`, sorted by name."""
    root = Path(root)
    if not root.is_dir():
        return []
    return sorted(d for d in root.iterdir() if (d / "object").is_dir() and (d / "real").is_dir())


def compare_batch(
    root: str | Path, table_dir: str | Path, model: str | Path | None = None, progress: bool = True
) -> tuple[dict, dict[str, str]]:
    """Compare every pair under `root`; returns the sim-to-real table and the files written to `table_dir`.
    Each pair's `Comparison.to_json()`, with its `name`, is kept in `<pair>/compare.json`."""
    pairs = pairs_in(root)
    if not pairs:
        raise SpareTwinError(f"batch {root}: no <name>/object and <name>/real folders in it")
    model = str(model or default_model("predict"))
    results = []
    for d in tqdm(pairs, desc="compare", unit="object", file=sys.stderr, disable=not progress):
        done = d / "compare.json"
        if done.is_file() and _reusable(read_json(done), model):
            results.append(read_json(done))
            continue
        r = {**compare(d / "object", d / "real", model=model, sim_dir=d / "sim_twin").to_json(), "name": d.name}
        write_json_atomic(done, r)
        results.append(r)
    table = sim2real_table(results)
    table["model"] = model
    table["instances"] = [{k: r.get(k) for k in INSTANCE_KEYS} for r in results]
    return table, write_table(table, table_dir)


def _reusable(previous: dict, model: str) -> bool:
    return previous.get("model") == model and previous.get("settings") == json.loads(
        json.dumps(CompareConfig().settings())
    )


def bench_sim2real(
    out: str | Path, objects: int = 12, seed: int = 1000, model: str | Path | None = None, progress: bool = True
) -> tuple[dict, dict[str, str]]:
    """Capture `objects` unseen chains (seeds seed, seed+1, ...; n cycling 1..6) with the simulated
    hand-held sensor into `out/n<N>_seed<S>/`, then `compare_batch` over them into `out`."""
    if objects < 1:
        raise SpareTwinError(f"objects {objects}: need at least 1")
    if seed < 0:
        raise SpareTwinError(f"seed {seed}: must be a non-negative integer")
    out = Path(out)
    for i in tqdm(range(objects), desc="captures", unit="object", file=sys.stderr, disable=not progress):
        n_links = i % MAX_MOVING_LINKS + 1
        d = out / f"n{n_links}_seed{seed + i}"
        if (d / "real" / "object.ply").is_file():
            continue  # captured and registered by an earlier run
        obj = build_object(sample_chain(n_links=n_links, seed=seed + i), d / "object")
        simulated_capture(obj.root, d, SensorCaptureConfig(seed=seed + i), progress=progress)
    return compare_batch(out, out, model, progress=progress)
