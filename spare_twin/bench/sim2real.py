"""The sim-to-real bench (`spare-twin bench sim2real`, docs/sim2real.md): unseen printed objects,
captured with every effect of a real print and sensor by two renderers, and every answer `predict`
can give scored on its own, in sim and in real.

Per object (settings: `spare_twin.bench.settings`; recordings: `spare_twin.bench.capture`):
- three recordings: `sim_rig` (the twin in the training rig), `sim_cameras` (the nominal twin along the
  capture's own camera path, no effect) and `real` (the capture with effects, imported as a real one);
- on each, `predict` with the default model (`combined`: its answer; `measurement`: the measurement's
  own estimate from the same run, what `--answer measurement` gives) and `predict --answer network`
  with each model asked for (the default model's network estimate is taken from its combined run: the
  same estimate). A model that cannot read a kind of recording (a refusal that does not name the
  recording, as errors about a recording's content do; or a temporal network given fewer frames than
  it reads) is recorded as `refused: <reason>`, never scored; an error about the recording's content
  (no object found on its table, say) is no answer, with the error as its reason;
- each answer kept with `predict --json`'s keys (`n_links`, `link_lengths_pu`, `joint_angles_rad`,
  `source`, `reason`, ...) and its score (`spare_twin.bench.scoring`).

A finished object is kept in `<object>/result.json`, keyed by its settings, the effects and every
model's content, so an interrupted bench resumes where it stopped (its captures are kept when only the
models changed). Objects run in `workers` processes; the results do not depend on how many.
"""

from __future__ import annotations

import contextlib
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from tqdm import tqdm

from spare_twin import __version__
from spare_twin.bench import capture
from spare_twin.bench.capture import SIDES
from spare_twin.bench.scoring import COMBINED, bench_markdown, bench_table, write_png
from spare_twin.bench.settings import BENCH, BenchConfig, CaptureSettings, check_bench
from spare_twin.compare.answers import Model, answers_of, model_of, resolve_models, score_answers
from spare_twin.dataset.backends import start_pool
from spare_twin.io import read_json, write_bytes_atomic, write_json_atomic
from spare_twin.nets import checkpoint as ckpt
from spare_twin.output import writing

#: What a per-object result means; a result of another format is recomputed.
BENCH_FORMAT = 2
TABLE_FILES = ("json", "md", "png")


def _key(c: CaptureSettings, cfg: BenchConfig, combined_model: Model, models: list[Model]) -> dict:
    """Everything a per-object result depends on: a stored result is reused only when this matches;
    its recordings alone, when "capture" does (new models or a new release predict on them again)."""
    return json.loads(
        json.dumps(
            {
                "capture": {
                    "format": BENCH_FORMAT,
                    "settings": c.to_json(),
                    "effects": cfg.effects.to_dict(),
                    "sim_frames": cfg.sim_frames,
                    "sim_resolution": cfg.sim_resolution,
                },
                "predict": {
                    "version": __version__,
                    "combined": combined_model.sha256,
                    "models": {m.name: m.sha256 for m in models},
                },
            }
        )
    )


def _draw(d: Path, c: CaptureSettings, cfg: BenchConfig) -> tuple[dict, dict]:
    """The object and its three recordings; returns the truth and the seconds each took."""
    times = {}
    t0 = time.perf_counter()
    obj = capture.build(d, c)
    capture.draw_real(obj, d, c, cfg.effects)
    times["real"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    capture.draw_sim_cameras(obj, d, c, cfg.effects)
    times["sim_cameras"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    capture.draw_sim_rig(obj, d, c, cfg)
    times["sim_rig"] = time.perf_counter() - t0
    return capture.truth(obj, d / "sensor"), times


def run_object(d: Path, c: CaptureSettings, cfg: BenchConfig, combined_model: Model, models: list[Model]) -> dict:
    """Draw, predict and score one object; the result is also written to `d/result.json`."""
    key = _key(c, cfg, combined_model, models)
    done = d / "result.json"
    previous = read_json(done) if done.is_file() else None
    if previous is not None and previous.get("key") == key:
        return previous
    captured = previous is not None and (previous.get("key") or {}).get("capture") == key["capture"]
    if captured and all((d / side).is_dir() for side in SIDES):
        truth, draw_s = previous["truth"], previous["times_s"]["draw"]
    else:
        truth, draw_s = _draw(d, c, cfg)
    sides, predict_s = {}, {}
    for side in SIDES:
        answers, predict_s[side] = answers_of(d / side, combined_model, models)
        # the rig's joints move (no one held pose to score); both hand-held paths see the held pose
        t = {**truth, "joint_angles_rad": None} if side == "sim_rig" else truth
        sides[side] = {"answers": score_answers(answers, t)}
    result = {
        "key": key,
        "name": c.name,
        "settings": c.to_json(),
        "effects_drawn": capture.effects_drawn(d / "sensor"),
        "truth": truth,
        "sides": sides,
        "times_s": {"draw": draw_s, "predict": predict_s},
    }
    write_json_atomic(done, result)
    return result


def _job(args: tuple) -> dict:
    return run_object(*args)


@contextlib.contextmanager
def _one_torch_thread():
    """Every object's networks run on one thread, in this process and in the workers alike, so the
    figures are the same bytes whatever `workers` is (and W workers use W cores)."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def _init_worker() -> None:
    import torch

    torch.set_num_threads(1)


def _run_all(jobs: list[tuple], workers: int, progress: bool) -> list[dict]:
    bar = dict(total=len(jobs), desc="sim2real", unit="object", file=sys.stderr, disable=not progress)
    if workers == 1 or len(jobs) <= 1:
        with _one_torch_thread():
            return [run_object(*j) for j in tqdm(jobs, **bar)]
    with start_pool(min(workers, len(jobs)), _init_worker) as pool:  # quiet on Ctrl-C: the driver answers it
        return list(tqdm(pool.imap(_job, jobs), **bar))


def table_files(out_dir: Path) -> dict[str, str]:
    return {k: str(out_dir / f"sim2real.{k}") for k in TABLE_FILES}


def bench_sim2real(
    out: str | Path,
    cfg: BenchConfig = BenchConfig(),
    models: Sequence[str] | None = None,
    workers: int = 1,
    progress: bool = True,
    force: bool = False,
) -> tuple[dict, dict[str, str]]:
    """The sim-to-real bench (see the module doc) into `out`: per object
    `seed<S>/{object,sensor,real,sim_cameras,sim_rig,result.json}`, and `sim2real.{json,md,png}`.
    Returns the table (`scoring.bench_table` with the config, the models and every object) and the
    files written.

    `out` is a resumable output (`spare_twin.output`): an interrupted run leaves its partial folder for
    the next one, which keeps every finished object whose settings and models (by content) are the
    same; `force` replaces a folder that is not an earlier bench."""
    settings = check_bench(out, cfg, workers, force)  # before any model is loaded or anything written
    combined_model = model_of(COMBINED, ckpt.default_model("predict"))
    nets = resolve_models(models, cfg.frames[0])
    with writing(out, BENCH, (combined_model.path, *(m.path for m in nets)), force, resumable=True) as tmp:
        jobs = [(tmp / c.name, c, cfg, combined_model, nets) for c in settings]
        results = _run_all(jobs, workers, progress)
        table = bench_table(results, [m.name for m in nets])
        table["models"] = {m.name: {"path": m.path, "sha256": m.sha256} for m in [combined_model, *nets]}
        table["config"] = cfg.to_json()
        table["objects"] = [{k: v for k, v in r.items() if k != "key"} for r in results]
        write_json_atomic(tmp / "sim2real.json", table)
        write_bytes_atomic(tmp / "sim2real.md", bench_markdown(table).encode())
        write_png(table, tmp / "sim2real.png")
    return table, table_files(Path(out))
