"""The paper's metrics: link-count accuracy, the link-length error E_L, per-n breakdowns, confusion.

Pure numpy (torch tensors are accepted and converted). Conventions (docs/design.md, the object model):

- counts are moving links n in 1..6; the class index is n - 1;
- length vectors are the paper's 7-slot label in paper units (base first, zeros past the last link);
- E_L = sum_i (L_i - L_hat_i)^2 per instance, where the true vector is zero past the true count and
  the predicted vector is zero past the *predicted* count (the end-to-end rule). A wrong count thus
  adds the squared lengths of the links it misses (or invents). "Lengths, n known" is the same
  formula with the predicted count set to the true one.
"""

from __future__ import annotations

import numpy as np

from spare_twin.config import LABEL_SLOTS, MAX_MOVING_LINKS, MIN_MOVING_LINKS

# The PNG writers live in plots.py; train.py still reaches them through this module.
from spare_twin.nets.plots import write_confusion_png, write_learning_curve_png  # noqa: F401

N_CLASSES = MAX_MOVING_LINKS - MIN_MOVING_LINKS + 1


def _np(a) -> np.ndarray:
    if hasattr(a, "detach"):  # torch tensor without importing torch here
        a = a.detach().cpu().numpy()
    return np.asarray(a)


def mask_slots(lengths, n_links) -> np.ndarray:
    """Zero every slot past link n (slots 0..n are kept: the base and n moving links)."""
    lengths = _np(lengths).astype(np.float64)
    n = _np(n_links).astype(np.int64).reshape(-1)
    if lengths.ndim != 2 or lengths.shape[1] != LABEL_SLOTS or lengths.shape[0] != n.shape[0]:
        raise ValueError(f"lengths must be (N, {LABEL_SLOTS}) matching n_links (N,), got {lengths.shape} and {n.shape}")
    keep = np.arange(LABEL_SLOTS)[None, :] <= n[:, None]
    return np.where(keep, lengths, 0.0)


def count_accuracy(true_n, pred_n) -> float:
    """Fraction of instances whose predicted count equals the true one."""
    t, p = _np(true_n).reshape(-1), _np(pred_n).reshape(-1)
    if t.shape != p.shape or t.size == 0:
        raise ValueError(f"need equally long, non-empty count vectors, got {t.shape} and {p.shape}")
    return float(np.mean(t == p))


def length_errors(true_lengths, pred_lengths, true_n, pred_n=None) -> np.ndarray:
    """Per-instance E_L (paper units squared). `pred_n=None` means n known (predicted = true count)."""
    t = mask_slots(true_lengths, true_n)
    p = mask_slots(pred_lengths, true_n if pred_n is None else pred_n)
    return np.sum((t - p) ** 2, axis=1)


def confusion_matrix(true_n, pred_n, n_classes: int = N_CLASSES) -> np.ndarray:
    """(n_classes, n_classes) int64 counts; row = true n, column = predicted n (index n - 1)."""
    t = _np(true_n).astype(np.int64).reshape(-1) - 1
    p = _np(pred_n).astype(np.int64).reshape(-1) - 1
    if ((t < 0) | (t >= n_classes) | (p < 0) | (p >= n_classes)).any():
        raise ValueError(f"counts must lie in 1..{n_classes}")
    cm = np.zeros((n_classes, n_classes), dtype=np.int64)
    np.add.at(cm, (t, p), 1)
    return cm


def per_n_breakdown(true_n, pred_n=None, errors=None) -> dict[str, dict]:
    """Per true count n: instances, count accuracy (if `pred_n`) and mean E_L (if per-instance `errors`).

    Keys are str(n) so the result is JSON-ready; counts absent from the data are left out.
    """
    t = _np(true_n).astype(np.int64).reshape(-1)
    out: dict[str, dict] = {}
    for n in range(1, N_CLASSES + 1):
        sel = t == n
        if not sel.any():
            continue
        row: dict = {"instances": int(sel.sum())}
        if pred_n is not None:
            row["count_accuracy"] = float(np.mean(_np(pred_n).reshape(-1)[sel] == n))
        if errors is not None:
            row["E_L"] = float(np.mean(_np(errors).reshape(-1)[sel]))
        out[str(n)] = row
    return out
