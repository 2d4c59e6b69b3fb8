"""`compare`'s printed twin in Rerun through Rerun's own URDF support (`live.rerun_twin.UrdfTwin`, the
logging `live` uses), instead of meshes posed by hand.

Two copies of the object folder's URDF stand on the twin's base frame (the comparison's world):
`twin_sim`, posed frame by frame with the simulated joint angles (the sim recording's ground truth),
and `twin_real`, translucent orange, posed with the joint angles `predict` estimated from the real
recording. Their difference per joint is a time series, `angle_error_deg/joint<k>` (real minus sim,
degrees). Where the real side has no angles for this chain (no answer, another count), only the sim
twin is shown.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spare_twin.live.rerun_twin import UrdfTwin
from spare_twin.recording import Recording

SIM, REAL = "twin_sim", "twin_real"
#: What a 3D view of the comparison's world must include to show the twins (their entities sit beside
#: `world`; their frames hang from its frame).
TWIN_CONTENTS = (f"/{SIM}/**", f"/{REAL}/**")
#: The real twin's tint (RGBA): translucent, so the sim twin shows through it.
REAL_TINT = (1.0, 0.55, 0.15, 0.45)


def _tint(stream, twin: UrdfTwin, rgba) -> None:
    """Override the albedo of every visual mesh of `twin` (the URDF's materials are the print's colours)."""
    import rerun as rr

    links = {twin.tree.root_link().name, *(j.child_link for j in twin.tree.joints())}
    for link in sorted(links):
        for path in twin.tree.get_visual_geometry_paths(link):
            stream.log(path, rr.Asset3D.from_fields(albedo_factor=list(rgba)), static=True)


def log_twins(stream, urdf_path: str | Path, sim_rec: Recording, result: dict, frames: range) -> None:
    """Log both twins and the angle errors at each frame of `frames` (timeline `frame`)."""
    import rerun as rr

    sim_twin = UrdfTwin(stream, urdf_path, SIM)
    truth = sim_rec.ground_truth() or {}
    sim_angles = truth.get("joint_angles_rad")
    real_angles = (result.get("real") or {}).get("joint_angles_rad")
    n = sim_twin.n_joints
    real_twin = None
    if real_angles is not None and len(real_angles) == n:
        real_twin = UrdfTwin(stream, urdf_path, REAL)
        _tint(stream, real_twin, REAL_TINT)
    base = np.eye(4)  # the comparison's world is the twin's base frame
    for f in frames:
        stream.set_time("frame", sequence=f)
        sim_f = None if sim_angles is None else np.asarray(sim_angles)[min(f, len(sim_angles) - 1)]
        sim_twin.pose(base, sim_f if sim_f is not None else np.zeros(n))
        if real_twin is None:
            continue
        real_twin.pose(base, real_angles)
        if sim_f is not None and len(sim_f) == n:
            for k, err in enumerate(np.degrees(np.subtract(real_angles, sim_f)), start=1):
                stream.log(f"angle_error_deg/joint{k}", rr.Scalars(float(err)))
