"""PNG figures for training and evaluation, drawn with OpenCV (the project has no matplotlib).

- `write_confusion_png`: the 6x6 count confusion matrix, cells shaded by the row-normalised rate.
- `write_learning_curve_png`: per-epoch curves (losses on the left, validation metrics on the right).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from spare_twin.io import encode_png, write_bytes_atomic

_WHITE = (255, 255, 255)
_BLACK = (0, 0, 0)
_GREY = (200, 200, 200)
# BGR line colours, distinguishable in print.
_PALETTE = [(180, 119, 31), (14, 127, 255), (44, 160, 44), (40, 39, 214), (189, 103, 148), (75, 86, 140)]


def _text(img, s, org, scale=0.45, color=_BLACK, thickness=1, center=False):
    import cv2

    if center:
        (w, h), _ = cv2.getTextSize(s, cv2.FONT_HERSHEY_SIMPLEX, scale, thickness)
        org = (int(org[0] - w / 2), int(org[1] + h / 2))
    cv2.putText(img, s, org, cv2.FONT_HERSHEY_SIMPLEX, scale, color, thickness, cv2.LINE_AA)


def write_confusion_png(cm, path: str | Path, title: str = "link count confusion") -> Path:
    """Rows: true n, columns: predicted n (1..6). Each cell shows the count; shade = fraction of its row."""
    import cv2

    cm = np.asarray(cm, dtype=np.int64)
    k = cm.shape[0]
    cell, left, top = 64, 90, 70
    img = np.full((top + k * cell + 60, left + k * cell + 30, 3), 255, np.uint8)
    rows = cm.sum(axis=1, keepdims=True)
    frac = np.divide(cm, np.maximum(rows, 1), dtype=np.float64)
    for i in range(k):
        for j in range(k):
            x0, y0 = left + j * cell, top + i * cell
            shade = int(255 - 200 * frac[i, j])
            color = (shade, shade, 255) if i != j else (shade, 255 - int(55 * frac[i, j]), shade)
            cv2.rectangle(img, (x0, y0), (x0 + cell, y0 + cell), color, -1)
            cv2.rectangle(img, (x0, y0), (x0 + cell, y0 + cell), _GREY, 1)
            ink = _WHITE if frac[i, j] > 0.6 else _BLACK
            _text(img, str(int(cm[i, j])), (x0 + cell // 2, y0 + cell // 2 - 6), 0.5, ink, 1, center=True)
            if rows[i, 0]:
                _text(img, f"{100 * frac[i, j]:.0f}%", (x0 + cell // 2, y0 + cell // 2 + 14), 0.38, ink, 1, center=True)
        _text(img, str(i + 1), (left - 16, top + i * cell + cell // 2), 0.55, center=True)
        _text(img, str(i + 1), (left + i * cell + cell // 2, top - 14), 0.55, center=True)
    _text(img, "predicted n", (left + k * cell // 2, top - 40), 0.55, center=True)
    _text(img, "true n", (28, top + k * cell // 2), 0.5, center=True)
    total = int(cm.sum())
    acc = float(np.trace(cm)) / total if total else float("nan")
    _text(img, f"{title}: accuracy {acc:.3f} over {total} instances", (10, top + k * cell + 35), 0.5)
    path = Path(path)
    write_bytes_atomic(path, encode_png(img))
    return path


def _panel(img, x0, y0, w, h, series: dict[str, list[float]], title: str, log_y: bool):
    """One line chart with axes, ticks and a legend, drawn into img at (x0, y0, w, h)."""
    import cv2

    cv2.rectangle(img, (x0, y0), (x0 + w, y0 + h), _BLACK, 1)
    _text(img, title, (x0 + w // 2, y0 - 14), 0.5, center=True)
    vals = [v for ys in series.values() for v in ys if v is not None and math.isfinite(v) and (v > 0 or not log_y)]
    if not vals:
        _text(img, "no data", (x0 + w // 2, y0 + h // 2), 0.5, center=True)
        return
    n_ep = max(len(ys) for ys in series.values())
    f = (lambda v: math.log10(v)) if log_y else (lambda v: v)
    lo, hi = f(min(vals)), f(max(vals))
    if hi - lo < 1e-9:
        lo, hi = lo - 0.5, hi + 0.5
    pad = 0.05 * (hi - lo)
    lo, hi = lo - pad, hi + pad

    def xy(i, v):
        x = x0 + (w * (i + 0.5) / n_ep if n_ep > 1 else w / 2)
        return int(round(x)), int(round(y0 + h - (f(v) - lo) / (hi - lo) * h))

    for t in range(5):  # y ticks
        fv = lo + (hi - lo) * t / 4
        yy = int(y0 + h - h * t / 4)
        cv2.line(img, (x0, yy), (x0 + w, yy), (235, 235, 235), 1)
        lab = f"{10**fv:.3g}" if log_y else f"{fv:.3g}"
        _text(img, lab, (x0 - 58, yy + 4), 0.38)
    step = max(1, n_ep // 8)
    for i in range(0, n_ep, step):  # x ticks: epochs, 1-based
        xx, _ = xy(i, vals[0])
        _text(img, str(i + 1), (xx, y0 + h + 14), 0.38, center=True)
    _text(img, "epoch", (x0 + w // 2, y0 + h + 34), 0.45, center=True)
    for k, (name, ys) in enumerate(series.items()):
        color = _PALETTE[k % len(_PALETTE)]
        pts = [xy(i, v) for i, v in enumerate(ys) if v is not None and math.isfinite(v) and (v > 0 or not log_y)]
        for a, b in zip(pts, pts[1:]):
            cv2.line(img, a, b, color, 2, cv2.LINE_AA)
        for p in pts:
            cv2.circle(img, p, 3, color, -1, cv2.LINE_AA)
        ly = y0 + 14 + 18 * k
        cv2.line(img, (x0 + w - 170, ly - 4), (x0 + w - 145, ly - 4), color, 2)
        _text(img, name, (x0 + w - 140, ly), 0.42)


def write_learning_curve_png(history: list[dict], path: str | Path, title: str = "") -> Path:
    """Left: every `*loss*` key per epoch (log scale). Right: validation metrics (accuracy, E_L)."""
    keys = sorted({k for row in history for k in row if k != "epoch" and isinstance(row.get(k), (int, float))})
    losses = {k: [row.get(k) for row in history] for k in keys if "loss" in k}
    metrics = {k: [row.get(k) for row in history] for k in keys if "loss" not in k and k.startswith("val_")}
    w, h, margin = 460, 300, 70
    img = np.full((h + 2 * margin + 10, 2 * (w + margin) + 20, 3), 255, np.uint8)
    _panel(img, margin, margin, w, h, losses, f"{title} losses".strip(), log_y=True)
    _panel(img, 2 * margin + w + 10, margin, w, h, metrics, "validation metrics", log_y=False)
    path = Path(path)
    write_bytes_atomic(path, encode_png(img))
    return path
