"""Rerun view of a recording: every camera (pinhole + pose), colour, depth and the fused cloud.

Entity layout::

    world                               view coordinates (z up when an object frame is known)
    world/fused                         fused cloud (static), when the recording is registered
    world/object                        the object's points (static), when one was found
    world/cameras/<cam>                 Transform3D camera-to-world (per frame, or static when fixed)
    world/cameras/<cam>/image           Pinhole (static)
    world/cameras/<cam>/image/color     EncodedImage (the PNG as stored)
    world/cameras/<cam>/image/depth     DepthImage (raw uint16, meter = 1 / depth_scale)

Timeline ``frame`` (sequence) and ``time`` (seconds). Blueprint: the 3D scene on the left; colour and
depth of each camera on the right (tabs when there are more than two cameras).
When the recording has an object frame, everything is shown in it (z up, table z = 0).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spare_twin.capture.checks import whole
from spare_twin.capture.fusion import read_ply_points
from spare_twin.output import RRD, check_output, writing
from spare_twin.recording import Recording


@dataclass(frozen=True)
class ViewConfig:
    """What to log."""

    every: int = 1
    """log every n-th frame."""
    max_points: int = 300_000
    """subsample the fused cloud to at most this many points (the viewer stays responsive)."""
    seed: int = 0

    def __post_init__(self):
        whole("every", self.every, 1)
        whole("max_points", self.max_points, 1)
        whole("seed", self.seed, 0)


def _blueprint(cams: list[str]):
    import rerun.blueprint as rrb

    per_cam = [
        rrb.Vertical(
            rrb.Spatial2DView(origin=f"world/cameras/{c}/image", contents="$origin/color", name=f"{c} colour"),
            rrb.Spatial2DView(origin=f"world/cameras/{c}/image", contents="$origin/depth", name=f"{c} depth"),
            name=c,
        )
        for c in cams
    ]
    right = per_cam[0] if len(per_cam) == 1 else (rrb.Horizontal(*per_cam) if len(per_cam) == 2 else rrb.Tabs(*per_cam))
    return rrb.Blueprint(
        rrb.Horizontal(rrb.Spatial3DView(origin="world", name="scene"), right, column_shares=[3, 2]),
        collapse_panels=True,
    )


def log_recording(
    root: str | Path, rrd: str | Path, cfg: ViewConfig = ViewConfig(), progress: bool = True, force: bool = False
) -> dict:
    """Write `rrd` for the recording at `root`; returns what was logged.

    `rrd` follows the output rule (`spare_twin.output`): absent, empty or an earlier .rrd, unless
    `force`; never inside the recording. Every picture to log is decoded first, so a damaged one is
    an error before anything is written.
    """
    import rerun as rr
    from tqdm import tqdm

    rec = Recording.open(root)
    rec.validate()
    reg = rec.registration
    has_object = reg is not None and reg.object is not None
    T_obj_world = np.linalg.inv(reg.T_world_object) if has_object else np.eye(4)
    cams = [c.name for c in rec.cameras]
    frames = range(0, rec.n_frames, cfg.every)
    check_output(rrd, RRD, inputs=[rec.root], force=force)
    for f in frames:  # the colour is logged as stored, undecoded: decode it here to know it is sound
        for c in rec.cameras:
            rec.color(c.name, f)
            rec.depth_raw(c.name, f)
    logged = {"rrd": str(rrd), "cameras": cams, "frames": 0, "fused_points": 0, "object_points": 0}
    with writing(rrd, RRD, inputs=[rec.root], force=force) as tmp:
        stream = rr.RecordingStream("spare-twin-capture", recording_id=str(rec.root.resolve()))
        stream.save(tmp, default_blueprint=_blueprint(cams))
        try:
            _log_scene(stream, rec, T_obj_world, has_object, cfg, logged)
            ts = rec.timestamps_s
            for f in tqdm(frames, desc="view", unit="frame", file=sys.stderr, disable=not progress):
                stream.set_time("frame", sequence=f)
                stream.set_time("time", duration=float(ts[f]))
                for c in rec.cameras:
                    if c.poses == "per_frame":
                        _log_pose(stream, c.name, T_obj_world @ rec.T_world_camera(c.name, f))
                    base = f"world/cameras/{c.name}/image"
                    stream.log(
                        f"{base}/color",
                        rr.EncodedImage(contents=rec.path(c.name, "color", f).read_bytes(), media_type="image/png"),
                    )
                    stream.log(f"{base}/depth", rr.DepthImage(rec.depth_raw(c.name, f), meter=1.0 / rec.depth_scale))
                logged["frames"] += 1
            stream.flush()
        finally:  # the file is complete and closed before it is swapped in (or removed)
            stream.disconnect()
    return logged


def _log_scene(stream, rec: Recording, T_obj_world: np.ndarray, has_object: bool, cfg: ViewConfig, logged: dict):
    """What does not change from frame to frame: view axes, fused and object clouds, the cameras."""
    import rerun as rr

    up = rr.ViewCoordinates.RIGHT_HAND_Z_UP if has_object else rr.ViewCoordinates.RIGHT_HAND_Y_DOWN
    stream.log("world", up, static=True)
    rng = np.random.default_rng(cfg.seed)
    reg = rec.registration
    clouds = {} if reg is None else {"fused": reg.fused, "object": reg.object_file}
    for name, rel in clouds.items():
        if rel and (rec.root / rel).is_file():
            pts, cols = read_ply_points(rec.root / rel)
            if len(pts) > cfg.max_points:
                pick = rng.choice(len(pts), cfg.max_points, replace=False)
                pts, cols = pts[pick], cols[pick]
            pts = pts @ T_obj_world[:3, :3].T + T_obj_world[:3, 3]
            stream.log(
                f"world/{name}",
                rr.Points3D(pts, colors=(cols * 255).astype(np.uint8), radii=0.0015 if name == "fused" else 0.002),
                static=True,
            )
            logged[f"{name}_points"] = int(len(pts))
    for c in rec.cameras:
        stream.log(
            f"world/cameras/{c.name}/image",
            rr.Pinhole(
                image_from_camera=c.K,
                resolution=[c.width, c.height],
                camera_xyz=rr.ViewCoordinates.RDF,
                image_plane_distance=0.05,
            ),
            static=True,
        )
        if c.poses == "fixed" and c.T_world_camera is not None:
            _log_pose(stream, c.name, T_obj_world @ c.T_world_camera, static=True)


def _log_pose(stream, cam: str, T: np.ndarray, static: bool = False) -> None:
    import rerun as rr

    stream.log(f"world/cameras/{cam}", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=static)
