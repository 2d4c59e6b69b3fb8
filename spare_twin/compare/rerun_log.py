"""Rerun logging of a sim-vs-real comparison (`spare-twin compare --rrd`).

Entity layout::

    world/real_cloud                    the fused real object cloud, in the twin's base frame
    twin_sim/<robot>, twin_real/<robot>  the printed twin's URDF through Rerun's URDF support, posed per frame
                                        by the simulated and by predict's joint angles (`compare.rerun_urdf`);
                                        angle_error_deg/joint<k> their difference (without a URDF: the posed
                                        meshes at world/twin/link<k>)
    real/frame/color, real/frame/depth  the real recording, frame by frame (timeline `frame`)
    sim/frame/color, sim/frame/depth    the twin rendered through the same cameras
    real/network_input, sim/network_input   the depth views each network saw, tiled (metres); real is
                                        `predict` on the real recording alone
    real_twin_aligned/network_input     diagnostic: the real views with the cameras aligned on the
                                        fitted printed twin
    lengths/truth, lengths/sim, lengths/real, lengths/real_twin_aligned
                                        link lengths (paper units), base first
    summary                             markdown table: truth vs sim vs real, then the diagnostic

Blueprint: real (left) and sim (right) frames beside the 3D scene; below, the networks' inputs (the
diagnostic's in a tab behind real's), the length bar charts and the summary.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spare_twin.compare.rerun_urdf import TWIN_CONTENTS, log_twins
from spare_twin.output import RRD, writing
from spare_twin.recording import Recording


@dataclass(frozen=True)
class ComparisonLog:
    """Everything `log_comparison` writes; arrays in the twin's base frame (metres)."""

    result: dict
    """The `compare --json` object (`Comparison.to_json()`)."""
    real_cloud: np.ndarray
    real_cloud_rgb: np.ndarray
    twin_meshes: list[tuple[np.ndarray, np.ndarray, tuple[float, float, float]]]
    """Posed (vertices, triangles, rgb) per link."""
    real_input: np.ndarray
    """(V, H, W) depth the network saw for the real recording."""
    sim_input: np.ndarray
    real_rec: Recording
    sim_rec: Recording
    real_twin_aligned_input: np.ndarray | None = None
    """(V, H, W) depth the network saw for the diagnostic (real cameras aligned on the fitted twin)."""
    urdf_path: Path | None = None
    """The printed object's URDF: the twins are logged through Rerun's URDF support (`compare.rerun_urdf`)
    and `twin_meshes` is not used."""


def tile(views: np.ndarray, columns: int = 4) -> np.ndarray:
    """(V, H, W) -> one (rows * H, columns * W) mosaic, empty tiles zero (no reading)."""
    v, h, w = views.shape
    rows = -(-v // columns)
    out = np.zeros((rows * h, columns * w), dtype=views.dtype)
    for i in range(v):
        r, c = divmod(i, columns)
        out[r * h : (r + 1) * h, c * w : (c + 1) * w] = views[i]
    return out


#: Summary rows: side -> label (`real` is `predict` alone; the last a diagnostic that needs the twin).
SUMMARY_LABELS = {
    "truth": "truth",
    "sim": "sim",
    "real": "real (predict alone)",
    "real_twin_aligned": "diagnostic: real, twin-aligned",
}


#: Length bars per side, grouped around each link's slot.
BAR_COLOURS = {
    "truth": [120, 120, 120],
    "sim": [60, 130, 230],
    "real": [230, 120, 40],
    "real_twin_aligned": [150, 150, 60],
}


def summary_markdown(result: dict) -> str:
    errs = result["errors"]

    def lengths(d):
        return ", ".join(f"{x:.3f}" for x in (d.get("link_lengths_pu") or [])) or "-"

    def scored(side):
        e = errs.get(side)
        if e is None:
            return " | "
        e_l = "-" if e["E_L"] is None else f"{e['E_L']:.4f}"
        return f"{'right' if e['count_correct'] else 'wrong'} | {e_l}"

    lines = ["| | links | lengths (paper units, base first) | count | E_L |", "|---|---|---|---|---|"]
    for side, label in SUMMARY_LABELS.items():
        d = result.get(side)
        if d is None:
            continue
        tail = " | " if side == "truth" else scored(side)
        lines.append(f"| {label} | {d['n_links']} | {lengths(d)} | {tail} |")
        for estimator in ("network", "measurement"):  # each estimate beside the answer, as predict gives them
            e = d.get(estimator)
            if e is not None:
                count = e["n_links"] if e["n_links"] is not None else f"none ({e.get('reason')})"
                lines.append(f"| {label}: {estimator} alone | {count} | {lengths(e)} | | |")
    if (result.get("real") or {}).get("reason"):
        lines += ["", f"real: no count ({result['real']['reason']})"]
    fit = result.get("registration") or {}
    if fit.get("joint_angles_rad") is not None:
        lines += [
            "",
            "Joint angles from articulated registration (deg): "
            + ", ".join(f"{np.degrees(a):.1f}" for a in fit["joint_angles_rad"]),
        ]
    if errs.get("joint_angles_deg") is not None:
        lines += [
            "",
            "Their error against the recording's ground truth (deg): "
            + ", ".join(f"{a:.2f}" for a in errs["joint_angles_deg"]),
        ]
    return "\n".join(lines) + "\n"


def _blueprint():
    import rerun.blueprint as rrb

    def frames(side: str):
        return rrb.Vertical(
            rrb.Spatial2DView(origin=f"{side}/frame", contents="$origin/color", name=f"{side}: colour"),
            rrb.Spatial2DView(origin=f"{side}/frame", contents="$origin/depth", name=f"{side}: depth"),
            name=side,
        )

    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                frames("real"),
                rrb.Spatial3DView(
                    origin="world", contents=["$origin/**", *TWIN_CONTENTS], name="real cloud + posed twin"
                ),
                frames("sim"),
                column_shares=[1, 2, 1],
            ),
            rrb.Horizontal(
                rrb.Tabs(
                    rrb.Spatial2DView(origin="real/network_input", name="real: network input (depth)"),
                    rrb.Spatial2DView(
                        origin="real_twin_aligned/network_input", name="diagnostic, twin-aligned: network input"
                    ),
                ),
                rrb.Spatial2DView(origin="sim/network_input", name="sim: network input (depth)"),
                rrb.Tabs(
                    rrb.BarChartView(origin="lengths", name="link lengths: truth, sim, real, diagnostic"),
                    rrb.TimeSeriesView(origin="angle_error_deg", name="joint angles: real - sim (deg)"),
                ),
                rrb.TextDocumentView(origin="summary", name="truth vs sim vs real (predict alone)"),
            ),
            row_shares=[3, 2],
        ),
        collapse_panels=True,
    )


def log_comparison(
    rrd: str | Path, log: ComparisonLog, every: int = 1, inputs: Iterable = (), force: bool = False
) -> None:
    """Write the comparison to `rrd`, an output made from `inputs` (`spare_twin.output`: under a
    temporary name, in place when complete; `force` replaces a file that is not an earlier .rrd)."""
    with writing(rrd, RRD, inputs, force) as tmp:
        _log(tmp, log, every)


def _log(tmp: Path, log: ComparisonLog, every: int) -> None:
    import rerun as rr

    stream = rr.RecordingStream("spare-twin-compare")
    stream.save(tmp, default_blueprint=_blueprint())
    stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    stream.log(
        "world/real_cloud",
        rr.Points3D(log.real_cloud, colors=(np.clip(log.real_cloud_rgb, 0, 1) * 255).astype(np.uint8), radii=0.0012),
        static=True,
    )
    for k, (vertices, triangles, rgb) in enumerate(log.twin_meshes if log.urdf_path is None else ()):
        stream.log(
            f"world/twin/link{k}",
            rr.Mesh3D(vertex_positions=vertices, triangle_indices=triangles, albedo_factor=[*rgb, 0.55]),
            static=True,
        )
    inputs = (("real", log.real_input), ("sim", log.sim_input), ("real_twin_aligned", log.real_twin_aligned_input))
    for side, views in inputs:
        if views is not None:
            stream.log(
                f"{side}/network_input", rr.DepthImage(tile(np.asarray(views, np.float32)), meter=1.0), static=True
            )
    for offset, (side, colour) in zip((-0.3, -0.1, 0.1, 0.3), BAR_COLOURS.items()):
        if side not in log.result:
            continue
        values = log.result[side].get("link_lengths_pu") or []
        padded = np.zeros(7, np.float32)
        padded[: len(values)] = values
        # Grouped bars: link i's truth, sim and real side by side around x = i.
        stream.log(
            f"lengths/{side}",
            rr.BarChart(padded, color=colour, abscissa=np.arange(7) + offset, widths=np.full(7, 0.18, np.float32)),
            static=True,
        )
    stream.log("summary", rr.TextDocument(summary_markdown(log.result), media_type=rr.MediaType.MARKDOWN), static=True)

    n = min(log.real_rec.n_frames, log.sim_rec.n_frames)
    real_cam, sim_cam = log.real_rec.cameras[0].name, log.sim_rec.cameras[0].name
    for f in range(0, n, every):
        stream.set_time("frame", sequence=f)
        for side, rec, cam in (("real", log.real_rec, real_cam), ("sim", log.sim_rec, sim_cam)):
            stream.log(f"{side}/frame/color", rr.Image(rec.color(cam, f)))
            stream.log(f"{side}/frame/depth", rr.DepthImage(rec.depth_m(cam, f), meter=1.0))
    if log.urdf_path is not None:
        log_twins(stream, log.urdf_path, log.sim_rec, log.result, range(0, n, every))
    stream.flush()
    stream.disconnect()
