"""Sim vs real over many printed objects: `compare` on every object/real pair of a folder, and the
predict-only sim-to-real benchmark (`bench sim2real`) on simulated hand-held captures of unseen objects.

A finished comparison (same model and settings) is kept in `<pair>/compare.json`, a finished benchmark
object in `<object>/result.json`, so an interrupted batch or benchmark resumes where it stopped. The
table folder and the benchmark's folder go through the output rule (`spare_twin.output`).

The benchmark (`bench_sim2real`)
--------------------------------
Object i of `objects` is `sample_chain(n = i % 6 + 1, seed = seed + i)`: with the default 24, four
per link count. Its seeds start at 7000 (`BENCH_SEED`), a range no dataset (their chains take 63-bit
seeds from `SeedSequence`), test or demo draws from, so no shipped model saw these objects.

Each object is captured by the simulated hand-held sensor (`render_recording` on a hand-held path)
with settings from a seeded table (`capture_settings`): the arc (120..360 deg), the frame count
(15..60), the resolution (320x240, 640x480, 848x480), the fitted noise model (realsense_sr300,
kinect_v1; the Kinect is held beyond its 1 m minimum range), 0..4 clutter items, each spread evenly
over the objects and shuffled; half of the objects of every n have their poses hidden. The others
keep them, in a table frame (z up, table z = 0) where the object stands at a seeded place (+-5 cm)
and yaw, as a capture calibrated on a board gives. The capture is written out as a 7-Scenes folder
(colour, millimetre depth, intrinsics, poses when kept) and imported like any real one, so the
recording `predict` reads has no segmentation, no object configuration, no ground truth and no sign
that it was simulated.

Per object:
- `sim`: the object rendered by the twin in the training rig (`render_recording` with the default
  rig, `sim_frames` frames), then `predict_recording`;
- `real`: `predict_recording(capture)` and nothing else: no object folder, print scale or poses
  beyond what the recording holds; its wall time, and the stage times `predict` reports
  (`Prediction.timings_s`, where the model gives them);
- `real_twin_aligned` (only with `twin_aligned`: slow): `compare`'s result with the real cameras
  re-aligned onto the fitted printed twin, a diagnostic, never "real".
The truth (count, lengths in paper units, the held joint angles) comes from the object folder and
the simulation's ground truth and is used for scoring only (`score_prediction`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import re
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from spare_twin import __version__
from spare_twin.capture.export import export_7scenes
from spare_twin.capture.importers import ImportOptions, import_folder
from spare_twin.compare.sim_vs_real import CompareConfig, compare
from spare_twin.compare.table import sim2real_table, write_table, write_table_png
from spare_twin.config import LABEL_SLOTS, MAX_MOVING_LINKS, sample_chain
from spare_twin.errors import SpareTwinError
from spare_twin.io import read_json, write_bytes_atomic, write_json_atomic
from spare_twin.nets.checkpoint import default_model, load_model
from spare_twin.nets.metrics import length_errors
from spare_twin.object.folder import build_object
from spare_twin.object.kinematics import base_pose
from spare_twin.output import check_output, writing
from spare_twin.predict.run import predict_recording
from spare_twin.recording import Recording
from spare_twin.sim.noise import load_noise
from spare_twin.sim.render import RenderConfig, render_recording
from spare_twin.sim.scene import MAX_CLUTTER

#: What a batch keeps of each comparison in its table.
INSTANCE_KEYS = ("name", "truth", "sim", "real", "real_twin_aligned", "errors")


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


# -- the predict-only sim-to-real benchmark -----------------------------------------------------------------

#: First object seed of the benchmark: no dataset, test or demo draws its chains from 7000 up.
BENCH_SEED = 7000
#: What a per-object result means; a result of another format is recomputed.
BENCH_FORMAT = 1
_RESOLUTION = re.compile(r"^(\d+)x(\d+)$")


def _whole(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


@dataclass(frozen=True)
class BenchConfig:
    """What `bench_sim2real` captures and how (see the module doc)."""

    objects: int = 24
    """Objects; object i has n = i % 6 + 1 moving links (24: four per n)."""
    seed: int = BENCH_SEED
    """Seed of object 0 (object i: seed + i); also seeds the table of capture settings."""
    frames: tuple[int, int] = (15, 60)
    """Frame counts of the captures, spread evenly over this range."""
    sweep_deg: tuple[float, float] = (120.0, 360.0)
    """Arcs of the hand-held paths."""
    resolutions: tuple[str, ...] = ("320x240", "640x480", "848x480")
    noises: tuple[str, ...] = ("realsense_sr300", "kinect_v1")
    """Fitted noise models (capture/rigs/noise_NAME.json)."""
    clutter_max: int = 4
    """Clutter items on the table: 0..clutter_max, spread evenly."""
    sim_frames: int = 10
    """Frames of the twin's recording in the training rig (the sim side)."""
    sim_resolution: str = "record"
    twin_aligned: bool = False
    """Also run `compare` (articulated fit, cameras re-aligned onto the fitted twin): slow, a diagnostic."""

    def validate(self) -> None:
        """Errors name the parameter (the command says its flag)."""
        if not _whole(self.objects) or self.objects < 1:
            raise SpareTwinError(f"objects {self.objects!r}: need at least 1")
        if not _whole(self.seed) or self.seed < 0:
            raise SpareTwinError(f"seed {self.seed!r}: must be a non-negative integer")
        lo, hi = self.frames
        if not (_whole(lo) and _whole(hi) and 1 <= lo <= hi):
            raise SpareTwinError(f"frames {lo}-{hi}: need whole numbers 1 <= LO <= HI")
        lo, hi = self.sweep_deg
        if not (_number(lo) and _number(hi) and 30 <= lo <= hi <= 360):
            raise SpareTwinError(f"sweep_deg {lo:g}-{hi:g}: need 30 <= LO <= HI <= 360 degrees")
        if not self.resolutions:
            raise SpareTwinError("resolutions: give at least one WxH")
        for r in self.resolutions:
            m = _RESOLUTION.match(r)
            if not m or not all(16 <= int(v) <= 4096 for v in m.groups()):
                raise SpareTwinError(f"resolutions {r!r}: expected WxH, each within 16..4096 (e.g. 640x480)")
        if not self.noises:
            raise SpareTwinError("noises: give at least one noise model")
        for name in self.noises:
            if name == "none":
                raise SpareTwinError("noises 'none': a simulated sensor capture needs a fitted noise model")
            load_noise(name, param="noises")
        if not _whole(self.clutter_max) or not 0 <= self.clutter_max <= MAX_CLUTTER:
            raise SpareTwinError(f"clutter_max {self.clutter_max!r}: must be a whole number, 0..{MAX_CLUTTER}")
        if not _whole(self.sim_frames) or self.sim_frames < 1:
            raise SpareTwinError(f"sim_frames {self.sim_frames!r}: must be a whole number, at least 1")


@dataclass(frozen=True)
class CaptureSettings:
    """How one object is captured by the simulated hand-held sensor."""

    name: str
    """The object's folder in the benchmark, `seed<S>`."""
    n_links: int
    seed: int
    """Seed of the chain and of its capture (path, held pose, noise, clutter)."""
    sweep_deg: float
    frames: int
    resolution: str
    noise: str
    clutter: int
    hide_poses: bool
    world_x_m: float
    world_y_m: float
    world_yaw_deg: float
    """Where the object stands in the table frame of a capture that keeps its poses."""

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


def _spread(rng: np.random.Generator, values: list) -> list:
    """`values` in a random order: every value is used as often as the list says."""
    return [values[i] for i in rng.permutation(len(values))]


def capture_settings(cfg: BenchConfig) -> list[CaptureSettings]:
    """The seeded table of capture settings, one row per object: every varied setting spread evenly
    over its range and shuffled on its own, so no two settings go together by construction; poses
    hidden for half of each n (alternating along its objects). A pure function of `cfg`."""
    cfg.validate()
    n_obj = cfg.objects
    rng = np.random.default_rng([cfg.seed, 0xBE7C])
    sweeps = _spread(rng, [round(float(v), 1) for v in np.linspace(*cfg.sweep_deg, n_obj)])
    frames = _spread(rng, [int(v) for v in np.linspace(*cfg.frames, n_obj).round()])
    resolutions = _spread(rng, [cfg.resolutions[i % len(cfg.resolutions)] for i in range(n_obj)])
    noises = _spread(rng, [cfg.noises[i % len(cfg.noises)] for i in range(n_obj)])
    clutter = _spread(rng, [i % (cfg.clutter_max + 1) for i in range(n_obj)])
    rows = []
    for i in range(n_obj):
        n, k = i % MAX_MOVING_LINKS + 1, i // MAX_MOVING_LINKS
        x, y = (float(v) for v in rng.uniform(-0.05, 0.05, 2).round(4))
        yaw = round(float(rng.uniform(0.0, 360.0)), 2)
        rows.append(
            CaptureSettings(
                name=f"seed{cfg.seed + i}",  # no count in the name: the capture's path tells predict nothing
                n_links=n,
                seed=cfg.seed + i,
                sweep_deg=sweeps[i],
                frames=frames[i],
                resolution=resolutions[i],
                noise=noises[i],
                clutter=clutter[i],
                hide_poses=(k + n - 1) % 2 == 1,
                world_x_m=x,
                world_y_m=y,
                world_yaw_deg=yaw,
            )
        )
    return rows


def _wrap_rad(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def _slots(lengths) -> np.ndarray:
    v = np.zeros(LABEL_SLOTS)
    if lengths is not None:
        lengths = np.asarray(lengths, dtype=np.float64)[:LABEL_SLOTS]
        v[: len(lengths)] = lengths
    return v


def score_prediction(truth: dict, pred: dict) -> dict:
    """One prediction against the truth; both dicts with `n_links` (None: no answer),
    `link_lengths_pu` (n + 1 paper-unit lengths, base first) and `joint_angles_rad` (n, or None).

    - `count_correct`: the count is the true one (no answer is wrong);
    - `E_L`: end to end over the paper's 7 slots (docs/design.md): the truth zero past the true count,
      the prediction zero past the predicted one (no answer: all zero), sum of squared differences;
    - `joint_angle_error_deg`: only when the count is right and angles are given: mean absolute
      difference (wrapped to +-180 deg) over the joints. A planar chain seen from the other side is its
      own mirror image with every angle negated, so the angles are known up to one global sign: the
      smaller of the two errors is scored and `joint_angle_sign` says which sign won.
    """
    true_n, pred_n = int(truth["n_links"]), pred.get("n_links")
    err = length_errors(
        _slots(truth["link_lengths_pu"])[None],
        _slots(pred.get("link_lengths_pu") if pred_n else None)[None],
        np.array([true_n]),
        np.array([pred_n or 0]),
    )
    out = {"count_correct": pred_n == true_n, "E_L": float(err[0]), "joint_angle_error_deg": None}
    out["joint_angle_sign"] = None
    angles, true_angles = pred.get("joint_angles_rad"), truth.get("joint_angles_rad")
    if out["count_correct"] and angles is not None and true_angles is not None and len(angles) == true_n:
        a, t = np.asarray(angles, dtype=np.float64), np.asarray(true_angles, dtype=np.float64)
        errors = {sign: float(np.degrees(np.abs(_wrap_rad(t - sign * a))).mean()) for sign in (1, -1)}
        sign = min(errors, key=lambda s: (errors[s], -s))
        out["joint_angle_error_deg"], out["joint_angle_sign"] = errors[sign], sign
    return out


def _mean(values: list) -> float | None:
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


def _bench_stats(rows: list[dict]) -> dict:
    """Count accuracy and E_L per side, the real joint-angle error and predict's times over `rows`."""
    out: dict = {"objects": len(rows)}
    for side in ("sim", "real", "real_twin_aligned"):
        scored = [r[side]["score"] for r in rows if r.get(side)]
        if not scored:
            continue
        out[side] = {
            "count_accuracy": float(np.mean([s["count_correct"] for s in scored])),
            "E_L": _mean([s["E_L"] for s in scored]),
        }
    real = [r["real"] for r in rows]
    angles = [r["score"]["joint_angle_error_deg"] for r in real if r["score"]["joint_angle_error_deg"] is not None]
    out["real"]["no_answer"] = sum(r["n_links"] is None for r in real)
    out["real"]["joint_angle_error_deg"] = _mean(angles)
    out["real"]["joint_angle_error_max_deg"] = float(max(angles)) if angles else None
    out["real"]["joint_angle_objects"] = len(angles)
    wall = [r["predict_s"] for r in real]
    out["real"]["predict_s"] = {"mean": _mean(wall), "max": float(max(wall)) if wall else None}
    stages = sorted({k for r in real for k in (r.get("timings_s") or {})})
    out["real"]["timings_s"] = {k: _mean([(r.get("timings_s") or {}).get(k) for r in real]) for k in stages} or None
    return out


def bench_table(results: list[dict]) -> dict:
    """Per n and overall figures of per-object benchmark results, and the issue's "done when" checks."""
    per_n = {}
    for n in sorted({r["truth"]["n_links"] for r in results}):
        per_n[str(n)] = _bench_stats([r for r in results if r["truth"]["n_links"] == n])
    overall = _bench_stats(results)
    sim, real = overall["sim"], overall["real"]
    gap = 100.0 * (sim["count_accuracy"] - real["count_accuracy"])
    ratio = None if not sim["E_L"] else real["E_L"] / sim["E_L"]
    angle = real["joint_angle_error_deg"]
    checks = {
        "real_count_accuracy_at_least_0.95": real["count_accuracy"] >= 0.95,
        "real_within_3_points_of_sim": gap <= 3.0,
        "real_E_L_at_most_1.5x_sim": ratio is not None and ratio <= 1.5,
        "joint_angle_error_at_most_5_deg": angle is not None and angle <= 5.0,
    }
    return {
        "overall": overall,
        "per_n": per_n,
        "count_accuracy_gap_points": gap,
        "E_L_ratio_real_to_sim": ratio,
        "checks": checks,
        "notes": {
            "real": "predict_recording on the imported capture alone (no object folder, print scale or poses "
            "beyond the recording's)",
            "sim": "the twin in the training rig, predict_recording",
            "E_L": "end to end, 7 slots, paper units squared; no answer counts as all-zero lengths",
            "joint_angle_error_deg": "real, over objects whose count is right; mean absolute error over the "
            "joints, the better of the two global signs (a planar chain is known up to a mirror)",
        },
    }


def _f(x, fmt: str) -> str:
    return "-" if x is None else format(x, fmt)


def bench_markdown(table: dict) -> str:
    """The per-n table, the checks and the per-object table, as Markdown."""
    twin = "real_twin_aligned" in table["overall"]
    head = "| n | objects | count acc. sim | count acc. real | E_L sim | E_L real | joint-angle error real (deg) "
    head += "| predict s (mean / max) |" + (" count acc. / E_L real twin-aligned |" if twin else "")
    lines = [head, "|" + "---|" * (9 if twin else 8)]
    for n, s in [*table["per_n"].items(), ("all", table["overall"])]:
        real, wall = s["real"], s["real"]["predict_s"]
        row = (
            f"| {n} | {s['objects']} | {_f(s['sim']['count_accuracy'], '.3f')} | {_f(real['count_accuracy'], '.3f')} "
            f"| {_f(s['sim']['E_L'], '.4f')} | {_f(real['E_L'], '.4f')} | {_f(real['joint_angle_error_deg'], '.2f')} "
            f"| {_f(wall['mean'], '.1f')} / {_f(wall['max'], '.1f')} |"
        )
        if twin:
            ta = s.get("real_twin_aligned") or {}
            row += f" {_f(ta.get('count_accuracy'), '.3f')} / {_f(ta.get('E_L'), '.4f')} |"
        lines.append(row)
    lines.append("")
    lines.append(
        f"Gap sim - real: {table['count_accuracy_gap_points']:.1f} points of count accuracy; "
        f"E_L real / sim: {_f(table['E_L_ratio_real_to_sim'], '.2f')}. "
        "Joint angles scored up to one global sign (a planar chain's mirror image)."
    )
    lines.append("")
    lines.append("| check | passed |")
    lines.append("|---|---|")
    lines += [f"| {k} | {'yes' if v else 'NO'} |" for k, v in table["checks"].items()]
    lines.append("")
    lines.append(
        "| object | n | arc (deg) | frames | resolution | noise | clutter | poses | real n | sim n | E_L real "
        "| angle error (deg) | predict s | reason |"
    )
    lines.append("|" + "---|" * 14)
    for r in table["objects"]:
        c, real = r["settings"], r["real"]
        poses = "hidden" if c["hide_poses"] else "known"
        lines.append(
            f"| {c['name']} | {c['n_links']} | {c['sweep_deg']:g} | {c['frames']} | {c['resolution']} "
            f"| {c['noise']} | {c['clutter']} "
            f"| {poses} | {_f(real['n_links'], 'd')} | {_f(r['sim']['n_links'], 'd')} "
            f"| {real['score']['E_L']:.4f} | {_f(real['score']['joint_angle_error_deg'], '.2f')} "
            f"| {real['predict_s']:.1f} | {real.get('reason') or ''} |"
        )
    return "\n".join(lines) + "\n"


def _prediction_json(pred) -> dict:
    """What the benchmark keeps of a `Prediction`: `predict --json`'s answer, source and both
    estimates (the same keys), and the seconds per step."""
    out = pred.to_json()
    keep = ("n_links", "link_lengths_pu", "joint_angles_rad", "source", "reason", "network", "measurement", "input")
    return {
        **{k: out.get(k) for k in keep},
        "timings_s": {str(k): float(v) for k, v in dict(pred.timings_s).items()},
    }


def _predict(rec_dir: Path, model: str) -> tuple[dict, float]:
    """`predict_recording(rec_dir, model)` and its wall time; a refusal (SpareTwinError) is no answer."""
    t0 = time.perf_counter()
    try:
        out = _prediction_json(predict_recording(rec_dir, model, progress=False))
    except SpareTwinError as exc:
        out = {"n_links": None, "link_lengths_pu": None, "joint_angles_rad": None, "reason": f"error: {exc}"}
    return out, time.perf_counter() - t0


def _capture(obj_dir: Path, d: Path, c: CaptureSettings) -> Path:
    """The simulated hand-held capture of the object, brought in as a real one; returns `d/real`.

    `d/sensor` is the raw simulation (segmentation, true poses and joint angles in its ground truth);
    `d/real` is its 7-Scenes export imported back: colour, millimetre depth, intrinsics, and the poses
    only when the capture keeps them, moved into the table frame where the object stands at
    (world_x_m, world_y_m, world_yaw_deg)."""
    sensor = d / "sensor"
    render_recording(
        obj_dir,
        sensor,
        RenderConfig(
            path="handheld",
            frames=c.frames,
            seed=c.seed,
            resolution=c.resolution,
            noise=c.noise,
            hide_poses=c.hide_poses,
            sweep_deg=c.sweep_deg,
            clutter=c.clutter,
        ),
        progress=False,
        force=True,
    )
    scenes = d / "capture_7scenes"
    export_7scenes(sensor, scenes, poses=False, force=True)
    if not c.hide_poses:
        T_table_sim = base_pose(c.world_x_m, c.world_y_m, math.radians(c.world_yaw_deg))
        for t, T in enumerate(Recording.open(sensor).ground_truth()["T_world_camera"]):
            np.savetxt(scenes / f"frame-{t:06d}.pose.txt", T_table_sim @ T, fmt="%.9f")
    real = d / "real"
    import_folder(scenes, "7scenes", real, ImportOptions(fps=10.0, progress=False), force=True)
    shutil.rmtree(scenes)  # an intermediate: `real` holds the same frames
    return real


def _truth(obj_dir: Path, sensor: Path) -> dict:
    gt = Recording.open(sensor).ground_truth()
    spec = read_json(obj_dir / "object.json")
    return {
        "n_links": int(gt["n_links"]),
        "link_lengths_pu": [float(v) for v in spec["link_lengths_m"]],
        "joint_angles_rad": [float(v) for v in np.asarray(gt["joint_angles_rad"])[0]],
    }


def _file_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _bench_key(c: CaptureSettings, cfg: BenchConfig, model: str, model_sha: str) -> dict:
    """Everything a per-object result depends on: a stored result is reused only when this matches;
    its captures alone, when "capture" does (a new model or release predicts on them again)."""
    return json.loads(
        json.dumps(
            {
                "capture": {
                    "format": BENCH_FORMAT,
                    "settings": c.to_json(),
                    "sim_frames": cfg.sim_frames,
                    "sim_resolution": cfg.sim_resolution,
                },
                "predict": {"version": __version__, "model": model, "model_sha256": model_sha},
            }
        )
    )


def _bench_object(d: Path, c: CaptureSettings, cfg: BenchConfig, model: str, key: dict) -> dict:
    """Capture, predict and score one object; the result is also written to `d/result.json`."""
    done = d / "result.json"
    previous = read_json(done) if done.is_file() else None
    if previous is not None and previous.get("key") == key:
        if not cfg.twin_aligned or previous.get("real_twin_aligned"):
            return previous
        result = previous  # only the diagnostic is missing
    else:
        captured = previous is not None and (previous.get("key") or {}).get("capture") == key["capture"]
        real_dir = d / "real"
        if captured and real_dir.is_dir() and (d / "sim").is_dir():
            truth, capture_s, sim_render_s = previous["truth"], previous["capture_s"], previous["sim_render_s"]
        else:
            obj = build_object(sample_chain(n_links=c.n_links, seed=c.seed), d / "object", preview=False, force=True)
            t0 = time.perf_counter()
            real_dir = _capture(obj.root, d, c)
            capture_s = time.perf_counter() - t0
            truth = _truth(obj.root, d / "sensor")
            t0 = time.perf_counter()
            render_recording(
                obj.root,
                d / "sim",
                RenderConfig(frames=cfg.sim_frames, seed=c.seed, resolution=cfg.sim_resolution),
                progress=False,
                force=True,
            )
            sim_render_s = time.perf_counter() - t0
        real, real_s = _predict(real_dir, model)
        sim, sim_s = _predict(d / "sim", model)
        result = {
            "key": key,
            "name": c.name,
            "settings": c.to_json(),
            "truth": truth,
            # the twin in the rig moves on a motion of its own: its angles are not the capture's
            "sim": {**sim, "predict_s": sim_s, "score": score_prediction({**truth, "joint_angles_rad": None}, sim)},
            "real": {**real, "predict_s": real_s, "score": score_prediction(truth, real)},
            "capture_s": capture_s,
            "sim_render_s": sim_render_s,
        }
    if cfg.twin_aligned:
        result = {**result, "real_twin_aligned": _twin_aligned(d, model, result["truth"])}
    write_json_atomic(done, result)
    return result


def _twin_aligned(d: Path, model: str, truth: dict) -> dict:
    """`compare`'s twin-informed real result, on a copy of the capture (compare registers it in place,
    and the capture `predict` reads stays as it was imported)."""
    copy = d / "twin_aligned_real"
    if copy.exists():
        shutil.rmtree(copy)
    shutil.copytree(d / "real", copy)
    cmp = compare(d / "object", copy, model=model, sim_dir=d / "twin_aligned_sim", force=True).to_json()
    side = cmp.get("real_twin_aligned") or cmp["real"]
    pred = {
        "n_links": side.get("n_links"),
        "link_lengths_pu": side.get("link_lengths_pu"),
        "joint_angles_rad": side.get("joint_angles_rad"),
    }
    return {**pred, "score": score_prediction(truth, pred)}


def bench_sim2real(
    out: str | Path,
    cfg: BenchConfig = BenchConfig(),
    model: str | Path | None = None,
    progress: bool = True,
    force: bool = False,
) -> tuple[dict, dict[str, str]]:
    """The predict-only sim-to-real benchmark (see the module doc) into `out`: per object
    `seed<S>/{object,sensor,real,sim,result.json}`, and `sim2real.{json,md,png}`. Returns the table
    (per n, overall, checks, per object) and the files written.

    `out` is a resumable output (`spare_twin.output`): an interrupted run leaves its partial folder for
    the next one, which keeps every finished object whose settings and model (by content) are the
    same; `force` replaces a folder that is not an earlier benchmark."""
    settings = capture_settings(cfg)  # validates cfg before anything is loaded or written
    model = _model(model)
    key_sha = _file_sha256(model)
    results = []
    with writing(out, BENCH, (model,), force, resumable=True) as tmp:
        for c in tqdm(settings, desc="sim2real", unit="object", file=sys.stderr, disable=not progress):
            results.append(_bench_object(tmp / c.name, c, cfg, model, _bench_key(c, cfg, model, key_sha)))
        table = bench_table(results)
        table["model"] = model
        table["config"] = json.loads(json.dumps(dataclasses.asdict(cfg)))
        table["objects"] = [{k: v for k, v in r.items() if k != "key"} for r in results]
        write_json_atomic(tmp / "sim2real.json", table)
        write_bytes_atomic(tmp / "sim2real.md", bench_markdown(table).encode())
        write_table_png(table, tmp / "sim2real.png")
    return table, _table_files(Path(out))
