"""Sim vs real over many printed objects: `compare` on every object/real pair of a folder, and the
sim-to-real benchmark that makes such a folder from unseen objects first.

A finished comparison (same model and settings) is kept in `<pair>/compare.json`, so an interrupted
batch resumes where it stopped. The table folder and the benchmark's folder go through the output rule
(`spare_twin.output`).
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
from spare_twin.nets.checkpoint import default_model, load_model
from spare_twin.object.folder import build_object
from spare_twin.output import check_output, writing

#: What a batch keeps of each comparison in its table.
INSTANCE_KEYS = ("name", "truth", "sim", "real", "real_estimated_frame", "errors")


def pairs_in(root: str | Path) -> list[Path]:
    """The `<name>/` folders of `root` that hold both `object/` and `real/`, sorted by name."""
    root = Path(root)
    if not root.is_dir():
        return []
    return sorted(d for d in root.iterdir() if (d / "object").is_dir() and (d / "real").is_dir())


#: Output kinds (`spare_twin.output`): a batch's table folder, and a whole sim-to-real benchmark.
TABLE = "compare batch"
BENCH = "bench sim2real"
TABLE_FILES = ("json", "md", "png")


def _model(model: str | Path | None) -> str:
    """The checkpoint to use, loaded once so a bad one is refused before any work."""
    model = str(model or default_model("predict"))
    load_model(model)
    return model


def _table_files(out_dir: Path) -> dict[str, str]:
    return {k: str(out_dir / f"sim2real.{k}") for k in TABLE_FILES}


def compare_batch(
    root: str | Path,
    table_dir: str | Path,
    model: str | Path | None = None,
    progress: bool = True,
    force: bool = False,
) -> tuple[dict, dict[str, str]]:
    """Compare every pair under `root`; returns the sim-to-real table and the files written to `table_dir`,
    an output of its own (`spare_twin.output`; `force` replaces a folder that is not an earlier table).
    Each pair's `Comparison.to_json()`, with its `name`, is kept in `<pair>/compare.json`."""
    pairs = pairs_in(root)
    if not pairs:
        raise SpareTwinError(f"batch {root}: no <name>/object and <name>/real folders in it")
    model = _model(model)
    check_output(table_dir, TABLE, (root, model), force)
    table = _compare_pairs(pairs, model, progress, force)
    with writing(table_dir, TABLE, (root, model), force) as tmp:
        write_table(table, tmp)
    return table, _table_files(Path(table_dir))


def _compare_pairs(pairs: list[Path], model: str, progress: bool, force: bool = False) -> dict:
    results = []
    for d in tqdm(pairs, desc="compare", unit="object", file=sys.stderr, disable=not progress):
        done = d / "compare.json"
        if done.is_file() and _reusable(read_json(done), model):
            results.append(read_json(done))
            continue
        r = {**compare(d / "object", d / "real", model=model, sim_dir=d / "sim_twin", force=force).to_json()}
        r["name"] = d.name
        write_json_atomic(done, r)
        results.append(r)
    table = sim2real_table(results)
    table["model"] = model
    table["instances"] = [{k: r.get(k) for k in INSTANCE_KEYS} for r in results]
    return table


def _reusable(previous: dict, model: str) -> bool:
    return previous.get("model") == model and previous.get("settings") == json.loads(
        json.dumps(CompareConfig().settings())
    )


def bench_sim2real(
    out: str | Path,
    objects: int = 12,
    seed: int = 1000,
    model: str | Path | None = None,
    progress: bool = True,
    force: bool = False,
) -> tuple[dict, dict[str, str]]:
    """Capture `objects` unseen chains (seeds seed, seed+1, ...; n cycling 1..6) with the simulated
    hand-held sensor into `out/n<N>_seed<S>/`, then compare them all and write the table into `out`.

    `out` is a resumable output (`spare_twin.output`): an interrupted run leaves its partial folder for
    the next one, which keeps the captures and comparisons it finds; `force` replaces a folder that is
    not an earlier benchmark."""
    if isinstance(objects, bool) or not isinstance(objects, int) or objects < 1:
        raise SpareTwinError(f"objects {objects}: need at least 1")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise SpareTwinError(f"seed {seed}: must be a non-negative integer")
    model = _model(model)
    with writing(out, BENCH, (model,), force, resumable=True) as tmp:
        for i in tqdm(range(objects), desc="captures", unit="object", file=sys.stderr, disable=not progress):
            n_links = i % MAX_MOVING_LINKS + 1
            d = tmp / f"n{n_links}_seed{seed + i}"
            if (d / "real" / "object.ply").is_file():
                continue  # captured and registered by an earlier run
            obj = build_object(sample_chain(n_links=n_links, seed=seed + i), d / "object")
            simulated_capture(obj.root, d, SensorCaptureConfig(seed=seed + i), progress=progress)
        table = _compare_pairs(pairs_in(tmp), model, progress)
        write_table(table, tmp)
    return table, _table_files(Path(out))
