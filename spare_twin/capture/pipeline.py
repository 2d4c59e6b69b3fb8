"""Register a recording end to end: poses, TSDF fusion, the object; results written atomically.

What `register_recording` writes into the recording folder (one atomic update, see `store`):

- ``cameras/<cam>/T_world_camera.npy``: the registered camera-to-world poses (camera ``poses`` becomes
  ``"per_frame"``); poses that were there before the first registration (an importer's reference
  poses) are kept as ``cameras/<cam>/T_world_camera.reference.npy``;
- ``fused.ply``: the TSDF-fused coloured point cloud (world frame); ``fused_mesh.ply`` with ``mesh``;
- ``object.ply``: the object's points (world frame), when an object was found;
- ``recording.json`` key ``registration``: camera, settings, timings, the files above and ``object``
  (``T_world_object``, table plane, size) or null.

World frame: the reference world when reference poses were used, else the first frame's camera.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np

from spare_twin.errors import SpareTwinError

REFERENCE_POSES = "T_world_camera.reference.npy"


def reference_poses(rec, cam: str) -> np.ndarray | None:
    """Poses the recording came with (kept aside by an earlier registration), or None."""
    p = rec.root / "cameras" / cam / REFERENCE_POSES
    if p.is_file():
        return np.load(p)
    c = rec.camera(cam)
    if "registration" in rec.meta:
        return None
    if c.poses == "per_frame":
        return rec._poses[cam].copy()
    if c.poses == "fixed" and c.T_world_camera is not None:
        return np.repeat(c.T_world_camera[None], rec.n_frames, axis=0)
    return None


def register_recording(
    root: str | Path,
    reg_cfg=None,
    fusion_cfg=None,
    seg_cfg=None,
    camera: str | None = None,
    use_reference: bool = True,
    find: str = "auto",
    mesh: bool = False,
    progress: bool = True,
) -> dict:
    """Register, fuse and segment `root` in place; returns the `capture register --json` object.

    find: "auto" (look for the object; none found is a warning), "require" (none found is an error),
    "skip".
    """
    from spare_twin.capture.frames import load_frames
    from spare_twin.capture.fusion import FusionConfig, fuse_frames, mesh_ply_bytes, ply_bytes
    from spare_twin.capture.registration import RegistrationConfig, register_frames
    from spare_twin.capture.segment import SegmentConfig, find_object
    from spare_twin.capture.store import npy_bytes, update_recording
    from spare_twin.recording import Recording

    reg_cfg = reg_cfg or RegistrationConfig()
    fusion_cfg = fusion_cfg or FusionConfig()
    seg_cfg = seg_cfg or SegmentConfig()
    if find not in ("auto", "require", "skip"):
        raise SpareTwinError(f"--object {find!r}: expected auto, require or skip")
    rec = Recording.open(root)
    rec.validate()
    cam = camera or rec.cameras[0].name
    rec.camera(cam)
    ref = reference_poses(rec, cam)
    frames = load_frames(rec, cam)
    result = register_frames(frames, reg_cfg, ref if (use_reference and ref is not None) else None, progress)
    fused = fuse_frames(frames, result.poses, fusion_cfg, mesh=mesh, progress=progress)
    if len(fused.points) == 0:
        raise SpareTwinError(f"{rec.root}: TSDF fusion produced no surface (depth beyond {fusion_cfg.max_depth_m} m?)")
    obj = None
    if find != "skip":
        try:
            obj = find_object(
                fused.points, fused.colors, result.poses[:, :3, 3], seg_cfg, source=str(rec.root / "fused.ply")
            )
        except SpareTwinError as exc:
            if find == "require":
                raise
            print(f"warning: {exc}", file=sys.stderr)

    files = {
        f"cameras/{cam}/T_world_camera.npy": npy_bytes(result.poses),
        "fused.ply": ply_bytes(fused.points, fused.colors),
    }
    if ref is not None and "registration" not in rec.meta:
        files[f"cameras/{cam}/{REFERENCE_POSES}"] = npy_bytes(ref)
    if fused.mesh is not None:
        files["fused_mesh.ply"] = mesh_ply_bytes(fused.mesh)
    if obj is not None:
        files["object.ply"] = ply_bytes(obj.points, obj.colors)
    meta = dict(rec.meta)
    meta["cameras"] = [
        {**c.to_dict(), "poses": "per_frame", "T_world_camera": None} if c.name == cam else c.to_dict()
        for c in rec.cameras
    ]
    registration = {
        "camera": cam,
        "used_reference": bool(use_reference and ref is not None),
        "world": "reference" if (use_reference and ref is not None) else "first camera",
        "config": {"registration": _cfg_dict(reg_cfg), "fusion": _cfg_dict(fusion_cfg), "segment": _cfg_dict(seg_cfg)},
        "summary": result.summary() | {"fusion_s": round(fused.seconds, 3), "fused_points": int(len(fused.points))},
        "fused": "fused.ply",
        "mesh": "fused_mesh.ply" if fused.mesh is not None else None,
        "object": None if obj is None else {"file": "object.ply", **obj.summary()},
    }
    meta["registration"] = registration
    # a stale object.ply from an earlier run must not outlive this result
    update_recording(rec.root, meta, files, remove=tuple(f for f in ("object.ply", "fused_mesh.ply") if f not in files))
    names = [f"{i:06d}" for i in range(rec.n_frames)]
    out = {
        "frames": names,
        "poses_camera_to_world": [P.tolist() for P in result.poses],
        "camera": cam,
        "recording": str(rec.root),
        **{k: v for k, v in registration.items() if k not in ("config", "camera")},
    }
    src_names = rec.source.get("source_frames")
    if src_names and len(src_names) == rec.n_frames:
        out["source_frames"] = src_names
    return out


def _cfg_dict(cfg) -> dict:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(cfg).items()}


def fuse_recording(rec, object_only: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The boundary for canonical views: (points (N, 3) world, colours (N, 3) in 0..1, T_world_object 4x4).

    Reads what `register_recording` wrote; `object_only=False` returns the whole fused scene.
    Raises a one-line SpareTwinError when the recording is not registered or has no object.
    """
    from spare_twin.capture.fusion import read_ply_points
    from spare_twin.recording import Recording

    rec = rec if isinstance(rec, Recording) else Recording.open(rec)
    reg = rec.meta.get("registration")
    if not reg:
        raise SpareTwinError(f"{rec.root}: not registered yet; run `spare-twin capture register {rec.root}`")
    if not reg.get("object"):
        raise SpareTwinError(f"{rec.root / 'fused.ply'}: no object found when it was registered")
    pts, cols = read_ply_points(rec.root / (reg["object"]["file"] if object_only else reg["fused"]))
    return pts, cols, np.asarray(reg["object"]["T_world_object"], np.float64)
