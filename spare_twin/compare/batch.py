"""Sim vs real over many printed objects: `compare --batch`, `compare` on every object/real pair of a
folder, and every answer on its own (`spare_twin.compare.answers`: predict's combined answer, the
measurement alone and each network alone) on both sides of each pair, scored per n.

A finished comparison (same model and settings) is kept in `<pair>/compare.json`, with the answers of
the networks scored alone (`answers`, kept while the networks are the same by content), so an
interrupted batch resumes where it stopped. The table folder goes through the output rule
(`spare_twin.output`). The sim-to-real bench on simulated captures is `spare_twin.bench`.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path

from tqdm import tqdm

from spare_twin.compare.answers import (
    COMBINED,
    MEASUREMENT,
    Model,
    answers_of,
    model_of,
    resolve_models,
    rows_markdown,
    rows_table,
    score_answers,
)
from spare_twin.compare.inputs import TABLE, check_batch
from spare_twin.compare.sim_vs_real import CompareConfig, compare
from spare_twin.compare.table import sim2real_table, table_markdown, write_table
from spare_twin.config import ChainSpec
from spare_twin.io import read_json, write_bytes_atomic, write_json_atomic
from spare_twin.nets.checkpoint import default_model, load_model
from spare_twin.output import writing
from spare_twin.recording import Recording

#: What a batch keeps of each comparison in its table.
INSTANCE_KEYS = ("name", "truth", "sim", "real", "real_twin_aligned", "errors", "answers")
#: The sides every answer is scored on: the twin through the real cameras, and the real recording.
ANSWER_SIDES = {"sim": "sim, real cameras", "real": "real"}


TABLE_FILES = ("json", "md", "png")


def _table_files(out_dir: Path) -> dict[str, str]:
    return {k: str(out_dir / f"sim2real.{k}") for k in TABLE_FILES}


def compare_batch(
    root: str | Path,
    table_dir: str | Path,
    model: str | Path | None = None,
    progress: bool = True,
    force: bool = False,
    models: Sequence[str] | None = None,
) -> tuple[dict, dict[str, str]]:
    """Compare every pair under `root`; returns the sim-to-real table and the files written to `table_dir`,
    an output of its own (`spare_twin.output`; `force` replaces a folder that is not an earlier table).
    Each pair's `Comparison.to_json()`, with its `name` and its `answers` (each network of `models`
    alone: shipped names or checkpoints; default every shipped model that can read the pairs' real
    recordings), is kept in `<pair>/compare.json`; the table's `answers` holds their rows."""
    model = str(model or default_model("predict"))
    pairs = check_batch(root, table_dir, model, force)
    load_model(model)  # a bad checkpoint is refused before any work
    frames = min(Recording.open(d / "real").n_frames for d in pairs) if models is None else 0
    nets = resolve_models(models, frames)  # the default: the networks that can read every real recording
    table = _compare_pairs(pairs, model, nets, progress, force)
    with writing(table_dir, TABLE, (root, model), force) as tmp:
        write_table(table, tmp)
        write_bytes_atomic(tmp / "sim2real.md", batch_markdown(table).encode())
    return table, _table_files(Path(table_dir))


def _answers_key(combined: Model, nets: list[Model]) -> dict:
    return {"combined": combined.sha256, "models": {m.name: m.sha256 for m in nets}}


def _pair_answers(d: Path, r: dict, combined: Model, nets: list[Model]) -> dict:
    """Every answer alone on both sides of a comparison `r`, scored: the combined answer and its
    estimates from `compare`'s own predictions, the other networks predicted here."""
    sides = {}
    config = d / "object" / "object.json"  # what was printed, as `compare` read it (it refuses a pair without)
    parts = ChainSpec.from_json_file(config).parts if config.is_file() else None
    for side, rec in (("sim", Path(r.get("sim_recording") or d / "sim_twin")), ("real", d / "real")):
        answers, _ = answers_of(rec, combined, nets, combined=r[side], parts=parts)
        # the twin through the real cameras stands at the fitted angles, not the recorded ones
        truth = {**r["truth"], "joint_angles_rad": None} if side == "sim" else r["truth"]
        sides[side] = {"answers": score_answers(answers, truth)}
    return {"key": _answers_key(combined, nets), "sides": sides}


def _compare_pairs(pairs: list[Path], model: str, nets: list[Model], progress: bool, force: bool = False) -> dict:
    combined = model_of(COMBINED, model)
    results = []
    for d in tqdm(pairs, desc="compare", unit="object", file=sys.stderr, disable=not progress):
        done = d / "compare.json"
        previous = read_json(done) if done.is_file() else None
        if previous is not None and _reusable(previous, model):
            r = previous
        else:
            r = {**compare(d / "object", d / "real", model=model, sim_dir=d / "sim_twin", force=force).to_json()}
            r["name"] = d.name
        if (r.get("answers") or {}).get("key") != _answers_key(combined, nets):
            r["answers"] = _pair_answers(d, r, combined, nets)
            write_json_atomic(done, r)
        results.append(r)
    table = sim2real_table(results)
    table["model"] = model
    rows = [COMBINED, MEASUREMENT, *(m.name for m in nets)]
    per_n = {}
    for n in sorted({r["truth"]["n_links"] for r in results}):
        per_n[str(n)] = rows_table([r["answers"] for r in results if r["truth"]["n_links"] == n], rows, ANSWER_SIDES)
    table["answers"] = {
        "rows": rows,
        "sides": list(ANSWER_SIDES),
        "overall": rows_table([r["answers"] for r in results], rows, ANSWER_SIDES),
        "per_n": per_n,
        "models": {m.name: {"path": m.path, "sha256": m.sha256} for m in nets},
    }
    table["instances"] = [{k: r.get(k) for k in INSTANCE_KEYS} for r in results]
    return table


def batch_markdown(table: dict) -> str:
    """The sim-to-real table (`compare.table`), then every answer alone: overall and per n."""
    a = table["answers"]
    lines = [table_markdown(table).rstrip("\n"), "", "Each answer alone (wrong: a wrong count; none: no answer):", ""]
    lines += rows_markdown([a["overall"]], a["rows"], ANSWER_SIDES, "objects", [str(len(table["instances"]))])
    lines += ["", "Per n:", ""]
    lines += rows_markdown(list(a["per_n"].values()), a["rows"], ANSWER_SIDES, "n", list(a["per_n"]))
    return "\n".join(lines) + "\n"


def _reusable(previous: dict, model: str) -> bool:
    return previous.get("model") == model and previous.get("settings") == json.loads(
        json.dumps(CompareConfig().settings())
    )
