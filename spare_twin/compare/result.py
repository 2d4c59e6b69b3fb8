"""What `compare` finds for one printed object, as types: the printed truth, each prediction's score
against it (`score`) and the whole comparison (`Comparison`, the `compare --json` object), with the
summary lines the commands and the demo print."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spare_twin.compare.articulated import ArticulatedFit
from spare_twin.config import LABEL_SLOTS
from spare_twin.nets.metrics import length_errors
from spare_twin.predict.estimate import Prediction

#: What each side of a comparison keeps of its prediction (JSON keys, null where the model says nothing)...
SIDE_KEYS = ("n_links", "link_lengths_pu", "link_lengths_mm", "joint_angles_rad", "source", "network", "measurement")
#: ... and what it passes through only where the prediction has it (`reason`: why there is no count;
#: `input`: how `predict` made the estimators' input of the recording).
OPTIONAL_KEYS = ("reason", "input")
#: The sides of a comparison besides the truth: the twin in the same cameras, `predict` on the real
#: recording alone, and the diagnostic that places the real cameras on the fitted printed twin.
SIDES = ("sim", "real", "real_twin_aligned")
#: The summary's rows: side -> label.
SUMMARY_SIDES = {
    "truth": "truth",
    "sim": "sim",
    "real": "real (predict alone)",
    "real_twin_aligned": "diagnostic: real, twin-aligned",
}


@dataclass(frozen=True)
class Score:
    """One prediction against the truth (paper units)."""

    count_correct: bool
    E_L: float | None
    """The paper's end-to-end E_L (7 slots, zeros past each count); None without predicted lengths."""
    per_link_pu: tuple[float, ...] | None
    """Predicted minus true length per slot, up to the longer chain (JSON `per_link_pu`)."""

    def to_json(self) -> dict:
        return {
            "count_correct": self.count_correct,
            "E_L": self.E_L,
            "per_link_pu": None if self.per_link_pu is None else list(self.per_link_pu),
        }


def padded(lengths_pu) -> np.ndarray:
    """Lengths in the label's LABEL_SLOTS slots, zeros past the last link."""
    out = np.zeros(LABEL_SLOTS)
    if lengths_pu:
        out[: len(lengths_pu)] = lengths_pu
    return out


def score(n_true: int, lengths_true_pu, n_pred: int | None, lengths_pred_pu) -> Score:
    """Count right or wrong, E_L with the paper's end-to-end rule, and per-link errors (paper units)."""
    if lengths_pred_pu is None or n_pred is None:
        return Score(n_pred == n_true, None, None)
    t, p = padded(lengths_true_pu), padded(lengths_pred_pu)
    e_l = float(length_errors(t[None], p[None], [n_true], [n_pred])[0])
    return Score(bool(n_pred == n_true), e_l, tuple(float(x) for x in (p - t)[: max(n_true, n_pred) + 1]))


@dataclass(frozen=True)
class Truth:
    """The configuration that was printed, and the pose it was recorded in where known."""

    n_links: int
    link_lengths_pu: tuple[float, ...]
    joint_angles_rad: tuple[float, ...] | None = None

    def score(self, prediction: Prediction) -> Score:
        return score(self.n_links, self.link_lengths_pu, prediction.n_links, prediction.link_lengths_pu)

    def to_json(self) -> dict:
        return {
            "n_links": self.n_links,
            "link_lengths_pu": list(self.link_lengths_pu),
            "joint_angles_rad": None if self.joint_angles_rad is None else list(self.joint_angles_rad),
        }


def summary_row(name: str, n_links: int | None, lengths_pu, scored: Score | None = None) -> str:
    """One line of a sim-vs-real summary: count, lengths (paper units) and, when scored, right/WRONG and E_L."""
    lengths = ", ".join(f"{x:.3f}" for x in (lengths_pu or []))
    tail = ""
    if scored is not None and scored.E_L is not None:
        tail = f"  count {'right' if scored.count_correct else 'WRONG'}, E_L {scored.E_L:.4f}"
    return f"  {name:<32s} n = {n_links}  lengths [{lengths}]{tail}"


def side_json(prediction: Prediction) -> dict:
    """What a comparison keeps of one prediction: SIDE_KEYS always, OPTIONAL_KEYS where present."""
    out = prediction.to_json()
    return {**{k: out.get(k) for k in SIDE_KEYS}, **{k: out[k] for k in OPTIONAL_KEYS if k in out}}


@dataclass(frozen=True)
class Comparison:
    """Sim vs real for one printed object (`compare`).

    `real` is what `predict` says of the real recording alone: no object folder, no print scale, no
    camera poses from the twin; it is the figure that measures the network's transfer to real data.
    `real_twin_aligned` is a diagnostic: the same network with the real cameras re-aligned onto the
    printed twin fitted to the real cloud, and its base frame taken from that fit (the frame the sim
    twin stands in); it needs the true object, so it says how far the rest of the path (not the
    network) costs, never how `predict` does.
    """

    truth: Truth
    sim: Prediction
    real: Prediction
    real_twin_aligned: Prediction
    fit: ArticulatedFit
    """The URDF twin fitted to the real cloud, in the real recording's object frame."""
    T_world_object: np.ndarray
    """4x4 object frame (z up, table z = 0) in the real recording's world."""
    sim_recording: Path
    settings: dict
    """`CompareConfig.settings()`: what a batch checks before reusing the comparison."""
    rrd: str | None = None
    timings_s: dict[str, float] | None = None
    """Seconds per stage (registration, fusion, articulated fit, sim twin, predictions, rrd), for the
    human summary; not in `to_json()`, which is the same bytes on every run."""

    @property
    def T_world_base(self) -> np.ndarray:
        """4x4 pose of the fitted twin's base in the real recording's world."""
        return self.T_world_object @ self.fit.T_object_base

    @property
    def model(self) -> str:
        return self.real.model

    def errors(self, side: str) -> Score:
        """The score of side "sim", "real" or "real_twin_aligned" against the truth."""
        return self.truth.score(getattr(self, side))

    @property
    def joint_angle_errors_deg(self) -> tuple[float, ...] | None:
        """|fitted - recorded| joint angles (wrapped), None when the recording has no ground truth."""
        if self.truth.joint_angles_rad is None:
            return None
        return angle_errors_deg(self.fit.joint_angles_rad, self.truth.joint_angles_rad)

    def predicted_angle_errors_deg(self, side: str = "real") -> tuple[float, ...] | None:
        """|predicted - recorded| joint angles of a side (wrapped); None without both or with another count."""
        predicted = getattr(self, side).joint_angles_rad
        if self.truth.joint_angles_rad is None or predicted is None:
            return None
        if len(predicted) != len(self.truth.joint_angles_rad):
            return None
        return angle_errors_deg(predicted, self.truth.joint_angles_rad)

    def summary_rows(self, names: dict[str, str] = SUMMARY_SIDES) -> list[str]:
        """One `summary_row` per side named in `names` (side -> label), scored against the truth."""
        rows = []
        for side, name in names.items():
            if side == "truth":
                rows.append(summary_row(name, self.truth.n_links, self.truth.link_lengths_pu))
            else:
                p = getattr(self, side)
                rows.append(summary_row(name, p.n_links, p.link_lengths_pu, self.errors(side)))
        return rows

    def summary(self) -> str:
        """The `compare` report: truth and every side, then the fitted joint angles' errors."""
        lines = self.summary_rows()
        reason = self.real.to_json().get("reason")
        if reason:
            lines.append(f"  real: no count ({reason})")
        alone = [(name, e) for name, e in (("network", self.real.network), ("measurement", self.real.measurement)) if e]
        if alone:
            lines.append("  real, each estimate alone: " + "; ".join(f"{k} n = {e.n_links}" for k, e in alone))
        angles = self.joint_angle_errors_deg
        if angles is not None:
            lines.append("  joint angles from registration: error " + ", ".join(f"{a:.1f}" for a in angles) + " deg")
        if self.timings_s:
            lines.append("  seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in self.timings_s.items()))
        return "\n".join(lines)

    def to_json(self) -> dict:
        fit = self.fit
        angles = self.joint_angle_errors_deg
        out = {
            "truth": self.truth.to_json(),
            "sim": side_json(self.sim),
            "real": side_json(self.real),
            "real_twin_aligned": side_json(self.real_twin_aligned),
            "registration": {
                "joint_angles_rad": [float(a) for a in fit.joint_angles_rad],
                "T_world_base": self.T_world_base.tolist(),
                "rmse_m": fit.rmse_m,
                "inlier_fraction": fit.inlier_fraction,
                "depth_error_m": fit.depth_error_m,
                "camera_corrections_mm_deg": [list(c) for c in fit.view_corrections],
            },
            "errors": {
                **{side: self.errors(side).to_json() for side in SIDES},
                "joint_angles_deg": None if angles is None else list(angles),
                "real_joint_angles_deg": _list(self.predicted_angle_errors_deg("real")),
            },
            "sim_recording": str(self.sim_recording),
            "model": self.model,
            "settings": self.settings,
        }
        if self.rrd is not None:
            out["rrd"] = self.rrd
        return out


def angle_errors_deg(angles_rad, truth_rad) -> tuple[float, ...]:
    """|a - b| per joint, wrapped to [0, 180] degrees."""
    diff = np.asarray(angles_rad, np.float64) - np.asarray(truth_rad, np.float64)
    return tuple(float(np.degrees(abs((d + np.pi) % (2 * np.pi) - np.pi))) for d in diff)


def _list(values) -> list | None:
    return None if values is None else list(values)
