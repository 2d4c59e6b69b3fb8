"""Every answer `predict` can give of a recording, each on its own, and their scores: `predict`'s
combined answer, the measurement alone and each network alone (`answers_of`), scored against the
truth (`score_prediction`) and counted (`answer_stats`: wrong answers apart from no answers; a
network that refused the recording is never scored). `compare --batch` and the sim-to-real bench
(`spare_twin.bench`) both report these rows.

A network refuses a recording when it cannot read that kind of recording: a refusal that does not name
the recording (errors about a recording's content name it, as every error names its file), or a
temporal network given fewer frames than it reads. An error about the recording's content (no object
found on its table, say) is no answer, with the error as its reason.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spare_twin.config import LABEL_SLOTS, PartDims
from spare_twin.errors import SpareTwinError
from spare_twin.nets import checkpoint as ckpt
from spare_twin.nets.metrics import length_errors
from spare_twin.predict.images import CaptureRefused
from spare_twin.predict.run import predict_recording

#: The answer kinds before the networks: `predict`'s combined answer and the measurement alone.
COMBINED, MEASUREMENT = "combined", "measurement"


#: Shipped models that read posed views or a sweep's frames (the profile network, the multi-view
#: depth and grey networks); a temporal one reads its trained number of consecutive frames.
_READS_A_SWEEP = ("profile", "mv")


@dataclass(frozen=True)
class Model:
    """A network scored alone: its row name, checkpoint and content hash."""

    name: str
    path: str
    sha256: str


def _file_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def model_of(name: str, path: str | Path) -> Model:
    ckpt.load_model(path)  # a bad checkpoint is refused before any work
    return Model(name, str(path), _file_sha256(path))


def resolve_models(names: Sequence[str] | None, frames_lo: int, models_dir: Path = ckpt.MODELS_DIR) -> list[Model]:
    """The networks to score alone: `names` (shipped names in models/index.json, or checkpoint files),
    or by default every shipped model that can read the captures (those reading posed views or a
    sweep, and temporal ones whose trained frame count the shortest capture has)."""
    index = ckpt.read_index(models_dir)
    shipped = index.get("models", {})
    if names is None:
        chosen = []
        first = index.get("defaults", {}).get("predict")  # predict's own network leads
        for name, entry in sorted(shipped.items(), key=lambda item: (item[0] != first, item[0])):
            path = Path(models_dir) / entry.get("file", f"{name}.pt")
            if entry.get("mode") in _READS_A_SWEEP or ckpt.load_model(path)[1].frames <= frames_lo:
                chosen.append(model_of(name, path))
        return chosen
    out, seen = [], set()
    for name in names:
        if name in shipped:
            path = Path(models_dir) / shipped[name].get("file", f"{name}.pt")
        elif Path(name).is_file():
            path, name = Path(name), Path(name).stem
        else:
            raise SpareTwinError(f"models {name!r}: no shipped model of that name (models/index.json) and no such file")
        if name in seen or name in (COMBINED, MEASUREMENT):
            raise SpareTwinError(f"models {name!r}: named twice, or the name of another row")
        seen.add(name)
        out.append(model_of(name, path))
    return out


def _answer(j: dict, kind: str) -> dict:
    """`predict --json`'s keys (`j`: a combined prediction's JSON) of the answer (`kind` combined) or
    of one estimate alone (measurement, network)."""
    if kind == COMBINED:
        keep = ("n_links", "link_lengths_pu", "joint_angles_rad", "source", "reason", "input")
        return {k: j[k] for k in keep if k in j}
    est = j.get(kind)
    if est is None:  # nothing in view: the estimator had nothing to read
        return _no_answer(j.get("reason"))
    return {**est, "source": None if est.get("n_links") is None else kind}


def _no_answer(reason: str) -> dict:
    return {"n_links": None, "link_lengths_pu": None, "joint_angles_rad": None, "source": None, "reason": reason}


def _refused(reason: str) -> dict:
    return {"n_links": None, "link_lengths_pu": None, "joint_angles_rad": None, "refused": reason}


def _predict(rec: Path, model: str | None, answer: str, parts: PartDims | None = None):
    """`predict_recording`, whether the model refused the kind of capture, and the wall time; (None,
    error, refused, seconds) where it gave no prediction."""
    t0 = time.perf_counter()
    try:
        pred = predict_recording(rec, model, progress=False, answer=answer, parts=parts)
    except SpareTwinError as exc:  # the recording named by its own name: where it lies differs per run
        error = str(exc).replace(str(rec), rec.name)
        return None, error, isinstance(exc, CaptureRefused), time.perf_counter() - t0
    return pred, None, False, time.perf_counter() - t0


def answers_of(
    rec: Path, combined_model: Model, models: list[Model], combined: dict | None = None, parts: PartDims | None = None
) -> tuple[dict, dict]:
    """Every answer on the recording `rec` (combined, measurement, each of `models` alone), and the
    seconds each `predict` took. `combined`: the JSON of `predict`'s combined answer with
    `combined_model` where it was already made (`compare` makes it); the default model's network
    estimate is taken from it: the same estimate `--answer network` gives. `parts`: what the object
    was printed with (`predict --parts`; default the default parts)."""
    answers, times = {}, {}
    error = None
    if combined is None:
        pred, error, _, times[COMBINED] = _predict(rec, combined_model.path, COMBINED, parts)
        combined = None if pred is None else pred.to_json()
    if combined is None:  # predict's own answer: a refusal is no answer
        answers[COMBINED], answers[MEASUREMENT] = _no_answer(f"error: {error}"), _no_answer(f"error: {error}")
    else:
        answers[COMBINED], answers[MEASUREMENT] = _answer(combined, COMBINED), _answer(combined, MEASUREMENT)
    for m in models:
        if m.sha256 == combined_model.sha256 and combined is not None:
            answers[m.name] = _answer(combined, "network")
            continue
        net, error, refused, times[m.name] = _predict(rec, m.path, "network", parts)
        if refused:  # the kind of capture is not what the network reads
            answers[m.name] = _refused(error)
        elif net is None:  # about its content (no overlap, no chain): no answer
            answers[m.name] = _no_answer(f"error: {error}")
        elif net.n_links is None and net.input == "none":  # it read nothing: the recording is not its kind
            answers[m.name] = _refused(net.reason)
        else:
            answers[m.name] = _answer(net.to_json(), "network")
    return answers, times


def score_answers(answers: dict, truth: dict) -> dict:
    """Each answer that was not refused, with its `score` against `truth`."""
    return {k: a if a.get("refused") else {**a, "score": score_prediction(truth, a)} for k, a in answers.items()}


def _wrap_rad(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def _slots(lengths) -> np.ndarray:
    v = np.zeros(LABEL_SLOTS)
    if lengths is not None:
        lengths = np.asarray(lengths, dtype=np.float64)[:LABEL_SLOTS]
        v[: len(lengths)] = lengths
    return v


def score_prediction(truth: dict, pred: dict) -> dict:
    """One answer against the truth; both dicts with `n_links` (None: no answer), `link_lengths_pu`
    (n + 1 paper-unit lengths, base first) and `joint_angles_rad` (n, or None).

    - `count_correct`: the count is the true one; `answered`: a count was given (no answer is not right,
      and not a wrong count either: the table counts the two apart);
    - `E_L`: end to end over the paper's 7 slots (docs/design.md): the truth zero past the true count,
      the prediction zero past the predicted one (no answer: all zero), sum of squared differences;
    - `joint_angle_error_deg`: only when the count is right and both angles are known: mean absolute
      difference (wrapped to +-180 deg) over the joints. A planar chain seen from the other side is its
      own mirror image with every angle negated, so the angles are known up to one global sign: the
      better sign is taken (`joint_angle_sign`)."""
    true_n, pred_n = int(truth["n_links"]), pred.get("n_links")
    err = length_errors(
        _slots(truth["link_lengths_pu"])[None],
        _slots(pred.get("link_lengths_pu") if pred_n else None)[None],
        np.array([true_n]),
        np.array([pred_n or 0]),
    )
    out = {"count_correct": pred_n == true_n, "answered": pred_n is not None, "E_L": float(err[0])}
    out.update(joint_angle_error_deg=None, joint_angle_sign=None)
    angles, true_angles = pred.get("joint_angles_rad"), truth.get("joint_angles_rad")
    if out["count_correct"] and angles is not None and true_angles is not None and len(angles) == true_n:
        a, t = np.asarray(angles, dtype=np.float64), np.asarray(true_angles, dtype=np.float64)
        errors = {sign: float(np.degrees(np.abs(_wrap_rad(t - sign * a))).mean()) for sign in (1, -1)}
        sign = min(errors, key=lambda s: (errors[s], -s))
        out["joint_angle_error_deg"], out["joint_angle_sign"] = errors[sign], sign
    return out


def mean_of(values: list) -> float | None:
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


def answer_stats(answers: list[dict]) -> dict:
    """Figures of one answer kind over `answers` (each with `score`, or `refused`):
    count accuracy, wrong and no answers (counts), E_L and the joint-angle error over the scored ones."""
    scored = [a["score"] for a in answers if not a.get("refused")]
    angles = [s["joint_angle_error_deg"] for s in scored if s["joint_angle_error_deg"] is not None]
    return {
        "objects": len(scored),
        "refused": len(answers) - len(scored),
        "count_accuracy": float(np.mean([s["count_correct"] for s in scored])) if scored else None,
        "wrong": sum(s["answered"] and not s["count_correct"] for s in scored),
        "none": sum(not s["answered"] for s in scored),
        "E_L": mean_of([s["E_L"] for s in scored]),
        "joint_angle_error_deg": mean_of(angles),
        "joint_angle_objects": len(angles),
    }


def rows_table(results: list[dict], rows: list[str], sides: Sequence[str]) -> dict:
    """Per answer kind (`rows`) and side, `answer_stats` over `results` (each `{"sides": {side:
    {"answers": {row: answer}}}}`)."""
    return {
        row: {side: answer_stats([r["sides"][side]["answers"][row] for r in results]) for side in sides} for row in rows
    }


def _f(x, fmt: str) -> str:
    return "-" if x is None else format(x, fmt)


def _figures(s: dict) -> list[str]:
    """Cells of one side: count accuracy (over the answers scored), wrong, none, E_L, angle error."""
    if not s["objects"]:
        return ["refused" if s["refused"] else "-", "-", "-", "-", "-"]
    acc = f"{_f(s['count_accuracy'], '.3f')}"
    if s["refused"]:
        acc += f" ({s['refused']} refused)"
    return [acc, str(s["wrong"]), str(s["none"]), _f(s["E_L"], ".4f"), _f(s["joint_angle_error_deg"], ".2f")]


def rows_markdown(
    stats: list[dict], rows: list[str], side_titles: dict[str, str], first: str, first_values: list[str]
) -> list[str]:
    """Markdown lines: one line per group (`first_values`, e.g. n) and answer kind; per side (columns,
    titled by `side_titles`) count accuracy, wrong, none, E_L and joint-angle error."""
    cols = ["count acc.", "wrong", "none", "E_L", "angle err. (deg)"]
    head = f"| {first} | answer | " + " | ".join(f"{c} {t}" for t in side_titles.values() for c in cols) + " |"
    lines = [head, "|" + "---|" * (2 + len(cols) * len(side_titles))]
    for value, st in zip(first_values, stats):
        for row in rows:
            cells = [cell for side in side_titles for cell in _figures(st[row][side])]
            lines.append(f"| {value} | {row} | " + " | ".join(cells) + " |")
    return lines
