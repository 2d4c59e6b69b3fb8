"""Register a recording end to end: poses, TSDF fusion, the object; results written atomically.

What `register_recording` writes into the recording folder (one atomic `update_recording`, which keeps
everything else in the folder as it was):

- ``cameras/<cam>/T_world_camera.npy``: the registered camera-to-world poses (camera ``poses`` becomes
  ``"per_frame"``); poses that were there before the first registration (an importer's reference
  poses) are kept as ``cameras/<cam>/T_world_camera.reference.npy``;
- ``fused.ply``: the TSDF-fused coloured point cloud (world frame); ``fused_mesh.ply`` with ``mesh``;
- ``object.ply``: the object's points (world frame), when an object was found;
- ``recording.json`` key ``registration`` (`spare_twin.recording.Registration`): camera, settings,
  timings, the files above and ``object`` (``T_world_object``, table plane, size) or null.

World frame: the reference world when reference poses were used, else the first frame's camera.
"""

from __future__ import annotations

import dataclasses
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spare_twin.capture.frames import load_frames
from spare_twin.capture.fusion import FusionConfig, fuse_frames, mesh_ply_bytes, ply_bytes, read_ply_points
from spare_twin.capture.registration import RegistrationConfig, register_frames
from spare_twin.capture.segment import SegmentConfig, find_object
from spare_twin.errors import SpareTwinError
from spare_twin.output import own_files
from spare_twin.recording import REFERENCE_POSES, Recording, Registration, npy_bytes, update_recording
from spare_twin.recording.writer import check_updatable

FIND = ("auto", "require", "skip")
#: The files a registration writes, or removes where this one has none (a stale object must not outlive it).
RESULT_FILES = ("fused.ply", "fused_mesh.ply", "object.ply")


@dataclass(frozen=True)
class RegisterResult:
    """What `register_recording` did: the poses it found and the registration it stored."""

    recording: Path
    frames: tuple[str, ...]
    """Frame names, in order ("000000", ...)."""
    poses_camera_to_world: np.ndarray
    """(frames, 4, 4) registered poses of `registration.camera`."""
    registration: Registration
    source_frames: tuple[str, ...] | None = None
    """The importer's names of the frames (e.g. "frame-000015"), when it kept them."""

    def to_json(self) -> dict:
        """The `capture register --json` object."""
        reg = self.registration.to_dict()
        out = {
            "frames": list(self.frames),
            "poses_camera_to_world": [P.tolist() for P in self.poses_camera_to_world],
            "camera": reg["camera"],
            "recording": str(self.recording),
            **{k: v for k, v in reg.items() if k not in ("config", "camera")},
        }
        if self.source_frames is not None:
            out["source_frames"] = list(self.source_frames)
        return out


def register_recording(
    root: str | Path,
    reg_cfg: RegistrationConfig | None = None,
    fusion_cfg: FusionConfig | None = None,
    seg_cfg: SegmentConfig | None = None,
    camera: str | None = None,
    use_reference: bool = True,
    find: str = "auto",
    mesh: bool = False,
    progress: bool = True,
) -> RegisterResult:
    """Register, fuse and segment `root` in place.

    find: "auto" (look for the object; none found is a warning), "require" (none found is an error),
    "skip". `use_reference`: start from the poses the recording came with, when it has them.
    """
    reg_cfg = reg_cfg or RegistrationConfig()
    fusion_cfg = fusion_cfg or FusionConfig()
    seg_cfg = seg_cfg or SegmentConfig()
    if find not in FIND:
        raise SpareTwinError(f"find {find!r}: expected auto, require or skip")
    rec = Recording.open(root)
    rec.validate()
    if rec.n_frames < 2:  # one view has nothing to register against, and fuses into no closed surface
        raise SpareTwinError(f"{rec.root}: has 1 frame; registration needs at least 2 frames of the scene")
    cam = camera or rec.cameras[0].name
    rec.camera(cam)
    # refused now, not after the registration: the results go into the folder
    check_updatable(rec.root, writes=[f"cameras/{cam}/T_world_camera.npy"])
    _refuse_users_files(rec, RESULT_FILES)
    # the poses it came with, not those of an earlier registration: registering again gives the same result
    ref = rec.reference_poses(cam)
    use_ref = bool(use_reference and ref is not None)
    frames = load_frames(rec, cam)
    # both steps are byte-reproducible (registration.py, fusion.py): a rerun writes identical files
    result = register_frames(frames, reg_cfg, ref if use_ref else None, progress)
    poses = result.poses
    fused = fuse_frames(frames, poses, fusion_cfg, mesh=mesh, progress=progress)
    if len(fused.points) == 0:
        raise SpareTwinError(f"{rec.root}: TSDF fusion produced no surface (depth beyond {fusion_cfg.max_depth_m} m?)")
    obj = None
    if find != "skip":
        try:
            obj = find_object(fused.points, fused.colors, poses[:, :3, 3], seg_cfg, source=str(rec.root / "fused.ply"))
        except SpareTwinError as exc:
            if find == "require":
                raise
            print(f"warning: {exc}", file=sys.stderr)

    files = {
        f"cameras/{cam}/T_world_camera.npy": npy_bytes(poses),
        "fused.ply": ply_bytes(fused.points, fused.colors),
    }
    if ref is not None and rec.registration is None:
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
    registration = Registration(
        camera=cam,
        used_reference=use_ref,
        world="reference" if use_ref else "first camera",
        config={"registration": _cfg_dict(reg_cfg), "fusion": _cfg_dict(fusion_cfg), "segment": _cfg_dict(seg_cfg)},
        summary=result.summary() | {"fusion_s": round(fused.seconds, 3), "fused_points": int(len(fused.points))},
        fused="fused.ply",
        mesh="fused_mesh.ply" if fused.mesh is not None else None,
        object=None if obj is None else {"file": "object.ply", **obj.summary()},
    )
    meta["registration"] = registration.to_dict()
    # a stale object.ply from an earlier run must not outlive this result
    update_recording(rec.root, meta, files, remove=tuple(f for f in RESULT_FILES if f not in files))
    src_names = rec.source.get("source_frames")
    return RegisterResult(
        recording=rec.root,
        frames=tuple(f"{i:06d}" for i in range(rec.n_frames)),
        poses_camera_to_world=poses,
        registration=registration,
        source_frames=tuple(src_names) if src_names and len(src_names) == rec.n_frames else None,
    )


def _refuse_users_files(rec: Recording, names: tuple[str, ...]) -> None:
    """The results replace or remove these files: refused where one is the user's (neither listed as
    spare-twin's by the folder's marker nor named by its registration). An older marker lists nothing:
    then they count as spare-twin's, as before."""
    own = own_files(rec.root)
    if own is None:
        return
    reg = rec.registration
    named = {reg.fused, reg.mesh, reg.object_file} if reg else set()
    for name in names:
        if os.path.lexists(rec.root / name) and name not in own and name not in named:
            raise SpareTwinError(
                f"{rec.root / name}: not written by spare-twin, and registering writes its results there; "
                "move it out of the recording"
            )


def _cfg_dict(cfg) -> dict:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(cfg).items()}


def fuse_recording(rec: Recording | str | Path, object_only: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The boundary for canonical views: (points (N, 3) world, colours (N, 3) in 0..1, T_world_object 4x4).

    Reads what `register_recording` wrote; `object_only=False` returns the whole fused scene.
    Raises a one-line SpareTwinError when the recording is not registered or has no object.
    """
    rec = rec if isinstance(rec, Recording) else Recording.open(rec)
    reg = rec.registration
    if reg is None:
        raise SpareTwinError(f"{rec.root}: not registered yet; run `spare-twin capture register {rec.root}`")
    if reg.object is None:
        raise SpareTwinError(f"{rec.root / 'fused.ply'}: no object found when it was registered")
    pts, cols = read_ply_points(rec.root / (reg.object_file if object_only else reg.fused))
    return pts, cols, reg.T_world_object
