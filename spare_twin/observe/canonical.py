"""Canonical views: any recording re-rendered into the training rig, in the canonical object frame.

Networks trained in simulation see 8 fixed rig cameras around a chain whose base stands at the world
origin on the table (z up), the chain moving in the x-z plane. A real (or hand-held simulated)
recording has other cameras and an arbitrary world frame. `to_rig_views` brings it into the rig's input
space:

1. the object: `fuse_recording` (registration + TSDF fusion + table plane + clustering) gives the
   object's points and its frame (z up, origin on the table). That origin is the footprint centre, which
   a leaning chain drags away from the base, so `object_frame` moves it to the centre of the foot's
   socket boss (the object points 6..16 mm above the table: links never come that low, see
   `kinematics.keepout_height_m`). The foot plate itself (5 mm) is below the segmenter's 8 mm cut, so
   its points are taken back from the fused scene (2.5..8 mm above the table, within 6 cm of the base).
2. yaw: the frame's x axis (the footprint's principal axis) is only known up to a quarter turn (square
   foot, layers along y as wide as the links) and its sign, so `object_frame` returns yaw hypotheses
   (default the 4 rotations by 90 deg about z); predict runs the network on each and keeps the most
   confident output (largest count probability).
3. rendering (`spare_twin.observe.splat`): the points are splatted into each rig camera at the network
   resolution with a z-buffer (disc radius from the cloud's point spacing, one pass of small-hole
   filling), over an analytic table
   (the plane z = 0, the twin's 1 m square top, its grey under the twin's default light) so the views
   look like the training images, which contain the table. Grey comes from the fused colours.

Recordings from the training rig itself take the no-op path (their own views, resized). Simulation
recordings from other rigs whose cameras are posed need no registration: their world is already the
canonical frame, so the object is back-projected from that frame's views (segmentation > 0) and
rendered the same way.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spare_twin.capture.frames import fit_view
from spare_twin.capture.pipeline import fuse_recording, register_recording
from spare_twin.dataset.synthetic import RIG_NAME, synthetic_rig
from spare_twin.errors import SpareTwinError
from spare_twin.observe.splat import BACKGROUND_GREY, TABLE_GREY, point_spacing_m, splat, table_view
from spare_twin.recording import Recording
from spare_twin.sim.rig import Rig, load_rig


@dataclass(frozen=True)
class CanonicalConfig:
    """How the fused object is turned into rig views (metres, pixels)."""

    yaw_hypotheses: int = 4
    """Rotations about z tried: 4 = every 90 deg (footprint axis unknown), 2 = x and -x, 1 = as found."""
    splat_radius_rel: float = 0.8
    """Splat disc radius as a fraction of the cloud's point spacing (>= 0.5 closes a surface)."""
    max_splat_px: int = 3
    fill_min_neighbours: int = 5
    """A pixel with no reading is filled (mean of its neighbours) when at least this many of its 8 have one."""
    boss_band_m: tuple[float, float] = (0.006, 0.016)
    """Heights of the foot's socket boss: object points there locate the base."""
    foot_band_m: tuple[float, float] = (0.0025, 0.008)
    """Heights of the foot plate's top (5 mm) in the fused scene, above table noise and below the
    segmenter's cut."""
    foot_radius_m: float = 0.06
    """Half-size of the square around the base where foot-plate points are taken (the foot is 100 mm)."""
    sim_min_height_m: float = 0.003
    """Simulation recordings without segmentation: points above this are the object."""
    refine_yaw: bool = True
    """Turn x from the footprint's principal axis to the links' layer direction (see `layer_yaw_rad`)."""
    layer_bin_m: float = 0.001


@dataclass(frozen=True)
class ObjectFrame:
    """The object cloud in its canonical frame and the yaw hypotheses to try."""

    points: np.ndarray
    """(N, 3) metres, canonical frame (yaw hypothesis 0)."""
    colors: np.ndarray
    """(N, 3) RGB in [0, 1]."""
    T_world_object: np.ndarray
    """4x4: canonical frame (hypothesis 0) to the recording's world."""
    yaws_rad: tuple[float, ...]
    """Hypothesis k puts a point p of the frame at Rz(yaws_rad[k]) p."""
    method: str
    """"fused" (registered recording) or "sim-views" (posed simulation views, world = canonical)."""

    def T_world_canonical(self, k: int) -> np.ndarray:
        """4x4 canonical frame of hypothesis k to the recording's world."""
        return self.T_world_object @ rot_z(-self.yaws_rad[k])


@dataclass(frozen=True)
class CanonicalViews:
    """The training rig's views of a recording, per yaw hypothesis (Y), V cameras, H x W pixels."""

    depth_m: np.ndarray
    """float32 (Y, V, H, W) z-depth in metres, 0 = no reading."""
    grey: np.ndarray
    """float32 (Y, V, H, W) in [0, 1]."""
    object_mask: np.ndarray
    """bool (Y, V, H, W): pixels where the object (not the table) is seen."""
    K: np.ndarray
    """(V, 3, 3) intrinsics at H x W."""
    T_world_camera: np.ndarray
    """(V, 4, 4) camera-to-world in the canonical object frame."""
    yaws_rad: tuple[float, ...]
    method: str
    """"rig" (the recording is the training rig: its own views), "fused" or "sim-views"."""
    T_world_object: np.ndarray = field(default_factory=lambda: np.eye(4))
    """Canonical frame (hypothesis 0) to the recording's world."""


def rot_z(angle_rad: float) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    return T


def resolve_rig(rig: Rig | dict | str) -> Rig:
    """A Rig from a Rig, a rig dict, a name in capture/rigs/ or the synthetic ring's name
    (`spare_twin.dataset.synthetic.RIG_NAME`)."""
    if isinstance(rig, Rig):
        return rig
    if isinstance(rig, dict):
        return Rig.from_dict(rig, source="rig")
    if rig == RIG_NAME:
        return synthetic_rig()
    return load_rig(rig)


# -- the object ------------------------------------------------------------------------------
def registered(rec: Recording, workdir: str | Path, progress: bool = True) -> Recording:
    """`rec` if it is registered, else a registered copy in `workdir` (images hard-linked): predict
    never writes into the user's recording. Raises a one-line error when no object is found."""
    reg = rec.registration
    if reg is not None:
        if not reg.object:
            raise SpareTwinError(f"{rec.root / 'fused.ply'}: no object found when it was registered")
        return rec
    copy = Path(workdir) / "registered"

    def link(src, dst):
        try:
            os.link(src, dst)
        except OSError:
            shutil.copy2(src, dst)

    shutil.copytree(rec.root, copy, copy_function=link)
    try:
        register_recording(copy, find="require", progress=progress)
    except SpareTwinError as exc:
        msg = str(exc).replace(str(copy / "fused.ply"), str(rec.root)).replace(str(copy), str(rec.root))
        raise SpareTwinError(
            f"{msg} (registered in a temporary copy; `spare-twin capture register` shows more)"
        ) from None
    return Recording.open(copy)


def _yaws(n: int) -> tuple[float, ...]:
    if n not in (1, 2, 4):
        raise SpareTwinError(f"yaw_hypotheses {n}: must be 1, 2 or 4")
    return tuple(2 * math.pi * k / n for k in range(n))


def object_frame(rec: Recording, cfg: CanonicalConfig = CanonicalConfig(), frame: int | None = None) -> ObjectFrame:
    """The object's points in the canonical frame, from a registered recording (see the module doc) or,
    for an unregistered simulation recording with posed cameras, from that frame's views."""
    if rec.in_sim_world:
        return _sim_object(rec, cfg, rec.n_frames // 2 if frame is None else frame)
    pts_w, cols, T_wo = fuse_recording(rec, object_only=True)
    T_ow = np.linalg.inv(T_wo)
    pts = pts_w @ T_ow[:3, :3].T + T_ow[:3, 3]
    # the base: centre of the socket boss (links stay above it), else keep the footprint centre
    lo, hi = cfg.boss_band_m
    boss = pts[(pts[:, 2] > lo) & (pts[:, 2] < hi)]
    if len(boss) >= 10:
        c = (np.percentile(boss[:, :2], 2, axis=0) + np.percentile(boss[:, :2], 98, axis=0)) / 2
        shift = np.eye(4)
        shift[:2, 3] = c
        T_wo = T_wo @ shift
        pts[:, :2] -= c
    if cfg.refine_yaw:
        yaw = layer_yaw_rad(pts, cfg)
        T_wo = T_wo @ rot_z(yaw)
        pts = pts @ rot_z(-yaw)[:3, :3].T
    # the foot plate, from the whole fused scene
    scene_w, scene_c, _ = fuse_recording(rec, object_only=False)
    T_ow = np.linalg.inv(T_wo)
    scene = scene_w @ T_ow[:3, :3].T + T_ow[:3, 3]
    lo, hi = cfg.foot_band_m
    foot = (scene[:, 2] > lo) & (scene[:, 2] < hi) & (np.abs(scene[:, :2]) < cfg.foot_radius_m).all(axis=1)
    return ObjectFrame(
        np.concatenate([pts, scene[foot]]),
        np.concatenate([cols, scene_c[foot]]),
        T_wo,
        _yaws(cfg.yaw_hypotheses),
        "fused",
    )


def layer_yaw_rad(points: np.ndarray, cfg: CanonicalConfig = CanonicalConfig(), above_m: float = 0.02) -> float:
    """Rotation about z that best aligns x with the chain's plane, within +-90 deg.

    The footprint's principal axis is tilted by the links' layers (each link sits 6.4 mm further along
    y: a 13 cm reach over two layers tilts it by about 6 deg). Every link is a plate of constant y, so
    the right yaw makes the points' y coordinates most concentrated: maximise sum(h^2) of their
    histogram (1 mm bins), coarse 1 deg then 0.1 deg steps, over the points above the foot's boss.
    """
    p = points[points[:, 2] > above_m, :2]
    if len(p) < 30:
        return 0.0

    def score(a: float) -> float:
        y = -math.sin(a) * p[:, 0] + math.cos(a) * p[:, 1]
        h = np.bincount(np.floor((y - y.min()) / cfg.layer_bin_m).astype(np.int64))
        return float((h.astype(np.float64) ** 2).sum())

    coarse = np.radians(np.arange(-90.0, 90.0, 1.0))
    best = coarse[int(np.argmax([score(a) for a in coarse]))]
    fine = best + np.radians(np.arange(-1.0, 1.0001, 0.1))
    return float(fine[int(np.argmax([score(a) for a in fine]))])


def _sim_object(rec: Recording, cfg: CanonicalConfig, frame: int) -> ObjectFrame:
    """Back-project every camera's depth at `frame` (simulation: the world is the canonical frame)."""
    pts, cols = [], []
    for cam in rec.cameras:
        d = rec.depth_m(cam.name, frame)
        T = rec.T_world_camera(cam.name, frame)
        seg = rec.segmentation(cam.name, frame)
        v, u = np.nonzero(d > 0)
        z = d[v, u].astype(np.float64)
        K = cam.K
        pc = np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], 1)
        pw = pc @ T[:3, :3].T + T[:3, 3]
        keep = (
            seg[v, u] > 0
            if seg is not None
            else (pw[:, 2] > cfg.sim_min_height_m) & (np.linalg.norm(pw[:, :2], axis=1) < 0.3)
        )
        pts.append(pw[keep])
        cols.append(rec.color(cam.name, frame)[v[keep], u[keep]] / 255.0)
    pts, cols = np.concatenate(pts), np.concatenate(cols)
    if len(pts) < 20:
        raise SpareTwinError(f"{rec.root}: no object found in frame {frame} of the simulation views")
    return ObjectFrame(pts, cols, np.eye(4), (0.0,), "sim-views")


def render_views(
    obj: ObjectFrame,
    K: np.ndarray,
    T_world_camera: np.ndarray,
    height: int,
    width: int,
    cfg: CanonicalConfig = CanonicalConfig(),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(depth, grey, object_mask), each (Y, V, H, W): the object over the table per yaw hypothesis."""
    Y, V = len(obj.yaws_rad), len(T_world_camera)
    grey_pts = obj.colors @ np.array([0.299, 0.587, 0.114])
    spacing = point_spacing_m(obj.points)
    depth = np.zeros((Y, V, height, width), np.float32)
    grey = np.zeros_like(depth)
    mask = np.zeros(depth.shape, bool)
    tables = [table_view(K[i], T_world_camera[i], height, width) for i in range(V)]
    for k, yaw in enumerate(obj.yaws_rad):
        pts = obj.points @ rot_z(yaw)[:3, :3].T
        for i in range(V):
            d, g = splat(
                pts,
                grey_pts,
                K[i],
                T_world_camera[i],
                height,
                width,
                spacing,
                radius_rel=cfg.splat_radius_rel,
                max_px=cfg.max_splat_px,
                fill_min_neighbours=cfg.fill_min_neighbours,
            )
            table = tables[i]
            m = (d > 0) & ((table == 0) | (d < table + 0.002))  # the object stands on the table
            mask[k, i] = m
            depth[k, i] = np.where(m, d, table)
            grey[k, i] = np.where(m, g, np.where(table > 0, TABLE_GREY, BACKGROUND_GREY))
    return depth, grey, mask


# -- the entry point -------------------------------------------------------------------------
def to_rig_views(
    rec: Recording | str | Path,
    rig: Rig | dict | str,
    frame: int | None = None,
    cfg: CanonicalConfig = CanonicalConfig(),
    workdir: str | Path | None = None,
    progress: bool = True,
) -> CanonicalViews:
    """The training rig's views of `rec` at the rig's network resolution (see the module doc).

    rig: a Rig, rig dict, rig name or the synthetic ring's name. frame: the time step for the no-op and
    simulation paths (default the middle one); a fused recording is one static object. workdir: where
    an unregistered real recording is registered (a temporary folder when None).
    """
    rec = rec if isinstance(rec, Recording) else Recording.open(rec)
    rig = resolve_rig(rig)
    H, W = rig.height, rig.width
    K = np.repeat(rig.K(W, H)[None], rig.n_cameras, axis=0)
    poses = rig.poses()
    frame = rec.n_frames // 2 if frame is None else frame
    if not 0 <= frame < rec.n_frames:
        raise SpareTwinError(f"frame {frame}: the recording has frames 0..{rec.n_frames - 1}")
    if rec.rig == rig.name and len(rec.cameras) == rig.n_cameras:
        return _own_views(rec, rig, frame)
    if rec.registration is not None or rec.in_sim_world:
        obj = object_frame(rec, cfg, frame)
    else:
        with tempfile.TemporaryDirectory(dir=workdir) as tmp:
            obj = object_frame(registered(rec, tmp, progress), cfg, frame)
    depth, grey, mask = render_views(obj, K, poses, H, W, cfg)
    return CanonicalViews(depth, grey, mask, K, poses, obj.yaws_rad, obj.method, obj.T_world_object)


def _own_views(rec: Recording, rig: Rig, frame: int) -> CanonicalViews:
    """No-op path: the training rig's own cameras, resized to the network resolution."""
    import cv2

    H, W = rig.height, rig.width
    depth, grey, mask, Ks, Ts = [], [], [], [], []
    for cam in rec.cameras:
        d, K = fit_view(rec.depth_m(cam.name, frame), cam.K, H, W, nearest=True)
        g, _ = fit_view(
            cv2.cvtColor(rec.color(cam.name, frame), cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0,
            cam.K,
            H,
            W,
            nearest=False,
        )
        seg = rec.segmentation(cam.name, frame)
        m = fit_view(seg, cam.K, H, W, nearest=True)[0] > 0 if seg is not None else np.zeros((H, W), bool)
        depth.append(d)
        grey.append(g)
        mask.append(m)
        Ks.append(K)
        Ts.append(rec.T_world_camera(cam.name, frame))
    return CanonicalViews(
        np.stack(depth)[None].astype(np.float32),
        np.stack(grey)[None].astype(np.float32),
        np.stack(mask)[None],
        np.stack(Ks),
        np.stack(Ts),
        (0.0,),
        "rig",
    )
