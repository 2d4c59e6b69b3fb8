"""The sim-to-real table: many `compare` results -> count accuracy and E_L, sim vs real, per n.

Written as JSON (`sim2real.json`), Markdown (`sim2real.md`) and a plot (`sim2real.png`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spare_twin.io import encode_png, write_bytes_atomic, write_json_atomic

#: sim (the twin through the real cameras); real (`predict` on the real recording alone); and the
#: diagnostic that re-aligns the real cameras onto the fitted printed twin (needs the true object).
SIDES = ("sim", "real", "real_twin_aligned")


def _stats(rows: list[dict]) -> dict:
    out = {"instances": len(rows)}
    for side in SIDES:
        errs = [r["errors"][side] for r in rows if side in r["errors"]]
        e_l = [e["E_L"] for e in errs if e["E_L"] is not None]
        out[side] = {
            "count_accuracy": float(np.mean([e["count_correct"] for e in errs])) if errs else None,
            "E_L": float(np.mean(e_l)) if e_l else None,
        }
    out["joint_angle_error_deg"] = _mean_max([a for r in rows for a in (r["errors"].get("joint_angles_deg") or [])])
    out["real_joint_angle_error_deg"] = _mean_max(
        [a for r in rows for a in (r["errors"].get("real_joint_angles_deg") or [])]
    )
    return out


def _mean_max(values: list[float]) -> dict | None:
    return {"mean": float(np.mean(values)), "max": float(np.max(values))} if values else None


def sim2real_table(results: list[dict]) -> dict:
    """Overall and per-n figures from `compare` results (each with `truth`, `sim`, `real`, `errors`;
    `real` is `predict` alone, `real_twin_aligned` the diagnostic where present)."""
    per_n = {}
    for n in sorted({r["truth"]["n_links"] for r in results}):
        per_n[str(n)] = _stats([r for r in results if r["truth"]["n_links"] == n])
    overall = _stats(results)
    gap = None
    if overall["instances"]:
        gap = overall["sim"]["count_accuracy"] - overall["real"]["count_accuracy"]
    return {"overall": overall, "per_n": per_n, "count_accuracy_gap_points": None if gap is None else 100.0 * gap}


def table_markdown(table: dict) -> str:
    def f(x, fmt):
        return "-" if x is None else format(x, fmt)

    def mean_max(d):
        return "-" if d is None else f"{d['mean']:.2f} / {d['max']:.2f}"

    lines = [
        "| n | instances | count acc. sim | count acc. real | E_L sim | E_L real "
        "| joint-angle error real (deg, mean / max) "
        "| diagnostic: count acc. / E_L real, twin-aligned | diagnostic: twin fit's joint-angle error (deg) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    rows = list(table["per_n"].items()) + [("all", table["overall"])]
    for n, s in rows:
        aligned = s["real_twin_aligned"]
        lines.append(
            f"| {n} | {s['instances']} | {f(s['sim']['count_accuracy'], '.3f')} | "
            f"{f(s['real']['count_accuracy'], '.3f')} | "
            f"{f(s['sim']['E_L'], '.4f')} | {f(s['real']['E_L'], '.4f')} | "
            f"{mean_max(s.get('real_joint_angle_error_deg'))} | "
            f"{f(aligned['count_accuracy'], '.3f')} / {f(aligned['E_L'], '.4f')} | "
            f"{mean_max(s['joint_angle_error_deg'])} |"
        )
    return "\n".join(lines) + "\n"


def write_table_png(table: dict, path: str | Path) -> Path:
    """Grouped bars per n: count accuracy (left) and E_L (right), sim in blue, real in orange."""
    import cv2

    width, height = 900, 360
    img = np.full((height, width, 3), 255, np.uint8)
    keys = list(table["per_n"])
    colours = {"sim": (200, 120, 40), "real": (40, 120, 230)}  # BGR
    for panel, (metric, title) in enumerate((("count_accuracy", "count accuracy"), ("E_L", "E_L (paper units^2)"))):
        x0, y0, w, h = 60 + panel * 440, 40, 380, 260
        values = [table["per_n"][k][s][metric] or 0.0 for k in keys for s in ("sim", "real")]
        top = 1.0 if metric == "count_accuracy" else max(max(values, default=0.0) * 1.15, 1e-3)
        cv2.rectangle(img, (x0, y0), (x0 + w, y0 + h), (0, 0, 0), 1)
        cv2.putText(img, title, (x0, y0 - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
        cv2.putText(img, f"{top:.3g}", (x0 - 50, y0 + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
        slot = w / max(len(keys), 1)
        for i, k in enumerate(keys):
            for j, side in enumerate(("sim", "real")):
                v = table["per_n"][k][side][metric] or 0.0
                bx = int(x0 + i * slot + slot * (0.2 + 0.3 * j))
                by = int(y0 + h - h * min(v / top, 1.0))
                cv2.rectangle(img, (bx, by), (bx + int(slot * 0.28), y0 + h), colours[side], -1)
            cv2.putText(
                img,
                f"n={k}",
                (int(x0 + i * slot + slot * 0.25), y0 + h + 18),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.4,
                (0, 0, 0),
                1,
                cv2.LINE_AA,
            )
    for j, side in enumerate(("sim", "real")):
        cv2.rectangle(img, (60 + j * 120, height - 22), (75 + j * 120, height - 10), colours[side], -1)
        cv2.putText(img, side, (80 + j * 120, height - 11), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    path = Path(path)
    write_bytes_atomic(path, encode_png(img))
    return path


def write_table(table: dict, out_dir: str | Path) -> dict:
    out_dir = Path(out_dir)
    write_json_atomic(out_dir / "sim2real.json", table)
    write_bytes_atomic(out_dir / "sim2real.md", table_markdown(table).encode())
    write_table_png(table, out_dir / "sim2real.png")
    return {k: str(out_dir / f"sim2real.{k}") for k in ("json", "md", "png")}
