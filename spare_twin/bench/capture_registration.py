"""`bench_registration`: registration accuracy and speed on the APC shelf frames (real RealSense data).

The frames of ``DATA/apc_shelf_realsense`` (7-Scenes layout, with reference poses) are imported,
registered with their reference poses withheld (``use_reference=False``), fused and compared with
the reference: for every pair of frames `gap` positions apart in the sequence, the relative pose
error's rotation (degrees) and translation (mm). The reference poses are themselves good to about
2-5 mm. The repository holds 4 of the sequence's 50 frames (tests/data); the full sequence (files
15, 17, ..., 113, so a gap of 10 positions is 20 in file numbers) is in the tsdf-fusion sample data.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from spare_twin.capture.importers import ImportOptions, import_folder
from spare_twin.capture.pipeline import register_recording
from spare_twin.capture.registration import RegistrationConfig, relative_pose_errors
from spare_twin.errors import SpareTwinError
from spare_twin.validate import check_whole

GOAL_ROTATION_DEG = 2.0
GOAL_TRANSLATION_MM = 20.0


def bench_registration(
    data_dir: str | Path,
    gaps: tuple[int, ...] = (1, 10, 40),
    cfg: RegistrationConfig | None = None,
    max_frames: int | None = None,
    work_dir: str | Path | None = None,
    progress: bool = False,
) -> dict:
    """Import + register + fuse the APC frames in `data_dir`/apc_shelf_realsense; returns errors per gap
    and timings (JSON-ready)."""
    src = Path(data_dir) / "apc_shelf_realsense"
    if not src.is_dir():
        raise SpareTwinError(f"data_dir {data_dir}: no apc_shelf_realsense/ folder in it")
    for g in gaps:
        check_whole("gaps", g)
    cfg = cfg or RegistrationConfig()
    with tempfile.TemporaryDirectory(prefix="spare-twin-bench-", dir=work_dir) as tmp:
        t0 = time.perf_counter()
        rec = import_folder(src, "7scenes", Path(tmp) / "apc", ImportOptions(max_frames=max_frames, progress=progress))
        import_s = time.perf_counter() - t0
        reference = rec.camera_poses("cam0")
        if reference is None:
            raise SpareTwinError(f"{src}: no reference poses (frame-NNNNNN.pose.txt) to compare with")
        t1 = time.perf_counter()
        out = register_recording(rec.root, cfg, use_reference=False, find="skip", progress=progress)
        total_s = time.perf_counter() - t1
    poses = out.poses_camera_to_world
    summary = out.registration.summary
    n = len(poses)
    result = {
        "data": str(src),
        "frames": n,
        "reference_poses": "withheld",
        "config": {
            "voxel_m": cfg.voxel_m,
            "loop_gaps_frames": list(cfg.loop_gaps_frames),
            "global_init": cfg.global_init,
        },
        "errors": {},
        "import_s": round(import_s, 3),
        "import_frames_per_s": round(n / import_s, 2),
        "registration_s": round(sum(summary["seconds"].values()), 3),
        "registration_breakdown_s": summary["seconds"],
        "fusion_s": summary["fusion_s"],
        "fusion_frames_per_s": round(n / max(summary["fusion_s"], 1e-9), 2),
        "register_command_s": round(total_s, 3),
        "edges": summary["edges"],
        "edges_from_ransac": summary["edges_from_ransac"],
    }
    worst_ok = True
    for g in gaps:
        if g >= n:
            continue
        E = relative_pose_errors(poses, reference, g)
        row = {"pairs": int(len(E)), "rotation_deg": _stats(E[:, 0]), "translation_mm": _stats(E[:, 1])}
        row["within_goal"] = bool(E[:, 0].max() <= GOAL_ROTATION_DEG and E[:, 1].max() <= GOAL_TRANSLATION_MM)
        worst_ok &= row["within_goal"]
        result["errors"][str(g)] = row
    result["goal"] = {"rotation_deg": GOAL_ROTATION_DEG, "translation_mm": GOAL_TRANSLATION_MM, "met": worst_ok}
    return result


def _stats(v: np.ndarray) -> dict:
    return {"mean": round(float(v.mean()), 3), "median": round(float(np.median(v)), 3), "max": round(float(v.max()), 3)}
