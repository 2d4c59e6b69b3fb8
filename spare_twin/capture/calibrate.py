"""Calibrate a recording's cameras with the ChArUco board (see `board`) and store the poses."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spare_twin.capture.board import BoardSpec, board_pose, detect_board, refine_with_depth
from spare_twin.errors import SpareTwinError
from spare_twin.recording import Recording, update_recording


def calibrate_recording(root: str | Path, spec: BoardSpec, frame: int | None = None, use_depth: bool = True) -> dict:
    """Each camera's fixed pose from the board (world = board on the table, z up), written atomically.

    Cameras with per-frame poses (a moving camera) are left alone. With `frame` None, the frame with
    the most detected corners (of up to 30 spread over the recording) is used.
    """
    rec = Recording.open(root)
    rec.validate()
    if frame is not None and not 0 <= frame < rec.n_frames:
        raise SpareTwinError(f"frame {frame}: out of range 0..{rec.n_frames - 1}")
    results, cams = [], []
    for c in rec.cameras:
        if c.poses == "per_frame":
            cams.append(c.to_dict())
            continue
        candidates = (
            [frame]
            if frame is not None
            else sorted(set(np.linspace(0, rec.n_frames - 1, min(30, rec.n_frames)).astype(int)))
        )
        best = max(candidates, key=lambda f: len(detect_board(rec.color(c.name, f), spec)[1]))
        src = str(rec.path(c.name, "color", best))
        pose = board_pose(rec.color(c.name, best), c.K, spec, source=src)
        if use_depth:
            pose = refine_with_depth(pose, rec.depth_m(c.name, best), c.K, spec)
        T = pose.T_world_camera
        cams.append({**c.to_dict(), "T_world_camera": T.tolist(), "poses": "fixed"})
        results.append(
            {
                "name": c.name,
                "frame": int(best),
                "corners": pose.corners,
                "reprojection_px": round(pose.reprojection_px, 4),
                "depth": pose.depth,
                "T_world_camera": T.tolist(),
            }
        )
    if not results:
        raise SpareTwinError(f"{rec.root}: every camera has per-frame poses; nothing to calibrate")
    meta = dict(rec.meta)
    meta["cameras"] = cams
    meta["calibration"] = {
        "board": {
            "squares_x": spec.squares_x,
            "squares_y": spec.squares_y,
            "square_m": spec.square_m,
            "marker_m": spec.marker_m,
            "dictionary": spec.dictionary,
        },
        "world": "ChArUco board on the table: z up, table z = 0",
        "cameras": results,
    }
    update_recording(rec.root, meta, {})
    return {"recording": str(rec.root), "cameras": results}
