"""`spare-twin predict`: a network on any recording (sim or real).

The recording's views are brought into the network's input space: 96 x 128, centre-cropped to the
4:3 aspect and resized, with the intrinsics adjusted to match (depth resized with nearest
neighbour, so no depth is invented at edges). A recording from the training rig is used as it is.
Any other recording is brought into the canonical object frame (base at the origin on the table, z up,
chain in x-z; see `spare_twin.observe.canonical`): the geometry-aware voxel networks take its own
posed views moved into that frame, the image networks see it re-rendered into the training rig
(`to_rig_views`). A real recording's object frame is known only up to a yaw hypothesis (a quarter
turn); the network runs on every hypothesis and the most confident output (largest count
probability) wins. Unregistered real recordings are registered in a temporary copy first.
"""

from __future__ import annotations

import numpy as np
import torch

from spare_twin.capture.frames import fit_view
from spare_twin.errors import SpareTwinError
from spare_twin.nets import checkpoint as ckpt
from spare_twin.nets.models import decode, model_inputs
from spare_twin.nets.presets import NetConfig

DEFAULT_PRINT_SCALE = 0.08  # ChainSpec's default, for recordings that do not carry their object


def _view(rec, cam, frame: int, net: NetConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    import cv2

    c = rec.camera(cam)
    if net.input == "depth":
        img, K = fit_view(rec.depth_m(cam, frame), c.K, net.height, net.width, nearest=True)
    else:
        grey = cv2.cvtColor(rec.color(cam, frame), cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
        img, K = fit_view(grey, c.K, net.height, net.width, nearest=False)
    T = rec.T_world_camera(cam, frame)
    return img.astype(np.float32), K, T


def _print_scale(rec, print_scale: float | None) -> float:
    if print_scale is not None:
        return float(print_scale)
    obj = rec.object_config or {}
    return float(obj.get("print_scale", DEFAULT_PRINT_SCALE))


def _batch(views: list, net: NetConfig, print_scale: float) -> dict:
    """A batch of one in the CONTRACTS.md layout from (image, K, T_world_camera) views."""
    x = np.stack([v[0] for v in views])[None]
    Ks = np.stack([v[1] for v in views])[None]
    Ts = np.stack([v[2] if v[2] is not None else np.eye(4) for v in views])[None]
    if net.mode == "tmp":
        Ks, Ts = Ks[:, :1], Ts[:, :1]
    return {
        "x": torch.as_tensor(x, dtype=torch.float32),
        "K": torch.as_tensor(Ks, dtype=torch.float32),
        "T_world_camera": torch.as_tensor(Ts, dtype=torch.float32),
        "print_scale": torch.tensor([print_scale], dtype=torch.float32),
    }


def recording_sample(
    rec, net: NetConfig, frame: int | None = None, camera: str | None = None, print_scale: float | None = None
) -> dict:
    """A batch of one in the CONTRACTS.md layout from a recording's own views (its world as it is)."""
    needs_poses = net.arch == "geo_voxel"
    if net.mode == "mv":
        if len(rec.cameras) != net.frames:
            raise SpareTwinError(
                f"{rec.root}: the network takes {net.frames} views, the recording has {len(rec.cameras)} cameras"
            )
        frame = rec.n_frames // 2 if frame is None else frame
        views = [_view(rec, c.name, frame, net) for c in rec.cameras]
    else:
        cam = camera or rec.cameras[0].name
        picks = np.linspace(0, rec.n_frames - 1, net.frames).round().astype(int)  # resample to T frames
        views = [_view(rec, cam, int(f), net) for f in picks]
        views = [(img, views[0][1], views[0][2]) for img, _, _ in views]
    if needs_poses and any(T is None for _, _, T in views):
        raise SpareTwinError(f"{rec.root}: camera poses unknown; run `spare-twin capture register` first")
    return _batch(views, net, _print_scale(rec, print_scale))


def _sim_world(rec) -> bool:
    """An unregistered simulation recording with posed cameras: its world already is the canonical
    object frame (base at the origin, chain in x-z), so its poses are used as they are."""
    return (
        not rec.meta.get("registration")
        and rec.source.get("kind") == "sim"
        and all(c.poses != "unknown" for c in rec.cameras)
    )


def _posed_views(
    rec,
    net: NetConfig,
    frame: int | None,
    camera: str | None,
    T_canonical_world: np.ndarray,
    camera_poses: dict | None = None,
) -> list:
    """net.frames posed views for the voxel network, poses moved into the canonical frame: the
    recording's cameras at `frame` when it has that many posed ones, else frames of one camera spread
    over the recording (a hand-held sweep round a still object). `camera_poses` ({(camera, frame):
    T_world_camera}) overrides the recording's poses where it has them."""
    posed = [c for c in rec.cameras if c.poses != "unknown"]
    if not posed:
        raise SpareTwinError(f"{rec.root}: camera poses unknown; run `spare-twin capture register` first")
    if len(posed) == net.frames:
        f = rec.n_frames // 2 if frame is None else frame
        picks = [(c.name, f) for c in posed]
    else:
        cam = camera or (rec.meta.get("registration") or {}).get("camera") or posed[0].name
        picks = [(cam, int(f)) for f in np.linspace(0, rec.n_frames - 1, net.frames).round()]
    views = []
    for cam, f in picks:
        img, K, T = _view(rec, cam, f, net)
        T = (camera_poses or {}).get((cam, f), T)
        views.append((img, K, T_canonical_world @ T))
    return views


def recording_batches(
    rec,
    net: NetConfig,
    training_rig: str | None,
    frame: int | None = None,
    camera: str | None = None,
    print_scale: float | None = None,
    workdir=None,
    progress: bool = True,
    yaw_hypotheses: int = 4,
    T_world_base: np.ndarray | None = None,
    camera_poses: dict | None = None,
) -> tuple[list[dict], tuple[float, ...], str]:
    """The network inputs for a recording, one batch per yaw hypothesis, the yaws and the method:

    - "rig": the recording is the training rig (or the model does not name its rig): its own views;
    - "posed": voxel networks take posed views directly, in the canonical object frame (a simulation
      world as it is; a real recording registered, its poses moved by the inverse object pose of each
      yaw hypothesis of `capture.canonical.object_frame`);
    - "fused" / "sim-views": other networks see `capture.canonical.to_rig_views`;
    - "posed-given": `T_world_base` (the object's base pose in the recording's world, e.g. from
      articulated registration) is the canonical frame, for voxel networks on posed recordings;
      `camera_poses` may refine the recording's camera poses (e.g. re-aligned onto the fitted twin).
    """
    import tempfile

    from spare_twin.observe import canonical

    ps = _print_scale(rec, print_scale)
    cfg = canonical.CanonicalConfig(yaw_hypotheses=yaw_hypotheses)
    if training_rig is None or rec.rig == training_rig:
        return [recording_sample(rec, net, frame, camera, print_scale)], (0.0,), "rig"
    if net.arch == "geo_voxel" and net.mode == "mv":
        if T_world_base is not None:
            views = _posed_views(rec, net, frame, camera, np.linalg.inv(T_world_base), camera_poses)
            return [_batch(views, net, ps)], (0.0,), "posed-given"
        if _sim_world(rec):
            if len(rec.cameras) == net.frames:
                return [recording_sample(rec, net, frame, camera, print_scale)], (0.0,), "posed"
            return [_batch(_posed_views(rec, net, frame, camera, np.eye(4)), net, ps)], (0.0,), "posed"
        with tempfile.TemporaryDirectory(dir=workdir) as tmp:
            reg = canonical.registered(rec, tmp, progress)
            obj = canonical.object_frame(reg, cfg)
            batches = [
                _batch(_posed_views(reg, net, frame, camera, np.linalg.inv(obj.T_world_canonical(k))), net, ps)
                for k in range(len(obj.yaws_rad))
            ]
        return batches, obj.yaws_rad, "posed"
    if net.arch == "geo_voxel" and _sim_world(rec) and rec.camera(camera or rec.cameras[0].name).poses == "fixed":
        # a fixed camera in the canonical world: its own frames keep the motion the temporal net reads
        return [recording_sample(rec, net, frame, camera, print_scale)], (0.0,), "posed"
    cv = canonical.to_rig_views(rec, training_rig, frame=frame, cfg=cfg, workdir=workdir, progress=progress)
    return [_canonical_batch(cv, k, net, camera, ps) for k in range(len(cv.yaws_rad))], cv.yaws_rad, cv.method


def _canonical_batch(cv, k: int, net: NetConfig, camera: str | None, print_scale: float) -> dict:
    imgs = cv.depth_m[k] if net.input == "depth" else cv.grey[k]
    V = len(imgs)
    if net.mode == "mv":
        if V != net.frames:
            raise SpareTwinError(f"the network takes {net.frames} views, its training rig has {V} cameras")
        views = [(imgs[i], cv.K[i], cv.T_world_camera[i]) for i in range(V)]
    else:
        # a fused recording is one still object: the temporal network sees one rig camera's view repeated
        i = int(camera[3:]) if camera and camera.startswith("cam") and camera[3:].isdigit() else 0
        if not 0 <= i < V:
            raise SpareTwinError(f"--camera {camera}: the training rig has cameras cam0..cam{V - 1}")
        views = [(imgs[i], cv.K[i], cv.T_world_camera[i])] * net.frames
    return _batch(views, net, print_scale)


def predict_recording(
    rec_dir,
    model_path=None,
    frame: int | None = None,
    camera: str | None = None,
    print_scale: float | None = None,
    n_links: int | None = None,
    device: str = "cpu",
    progress: bool = True,
    yaw_hypotheses: int = 4,
    return_input: bool = False,
    T_world_base: np.ndarray | None = None,
    camera_poses: dict | None = None,
) -> dict:
    """The network's prediction for a recording; `return_input` adds `network_input`, the (V, H, W)
    views it saw for the chosen yaw (numpy, not JSON: for logging). `T_world_base` fixes the object
    frame of a posed recording for voxel networks, `camera_poses` refines its camera poses (see
    `recording_batches`)."""
    from spare_twin.recording import Recording

    model_path = model_path or ckpt.default_model("predict")
    model, net, ck = ckpt.load_model(model_path, device)
    rec = Recording.open(rec_dir)
    if frame is not None and not 0 <= frame < rec.n_frames:
        raise SpareTwinError(f"--frame {frame}: the recording has frames 0..{rec.n_frames - 1}")
    batches, yaws, method = recording_batches(
        rec,
        net,
        ck["meta"].get("rig"),
        frame,
        camera,
        print_scale,
        progress=progress,
        yaw_hypotheses=yaw_hypotheses,
        T_world_base=T_world_base,
        camera_poses=camera_poses,
    )
    batch = {k: torch.cat([b[k] for b in batches]) for k in batches[0]}  # one forward pass for all yaws
    true_n = None
    if net.arch == "conv3d_per_n":
        if n_links is None:
            raise SpareTwinError("--n-links: this model measures lengths for a known link count; give it")
        true_n = torch.full((len(batches),), int(n_links))
    res = decode(model, net, model_inputs(batch, device), true_n=true_n)
    # the most confident yaw hypothesis (count models); length-only models keep the first
    best = int(res["probabilities"].max(1).values.argmax()) if "probabilities" in res else 0
    out: dict = {"n_links": None, "link_lengths_m": None, "probabilities": None}
    if "pred_n" in res:
        n = int(res["pred_n"][best])
        out["n_links"] = n
        out["probabilities"] = [float(p) for p in res["probabilities"][best]]
        if "lengths_e2e" in res:
            out["link_lengths_m"] = [float(v) for v in res["lengths_e2e"][best, : n + 1]]
    elif "lengths_known" in res:
        out["n_links"] = n_links
        out["link_lengths_m"] = [float(v) for v in res["lengths_known"][best, : n_links + 1]]
    if "angles" in res and out["n_links"]:
        out["joint_angles_rad"] = [float(v) for v in res["angles"][best, : out["n_links"]]]
    out["input"] = method
    out["yaw_hypotheses_deg"] = [round(float(np.degrees(y)), 3) for y in yaws]
    out["yaw_deg"] = out["yaw_hypotheses_deg"][best]
    out["model"] = str(model_path)
    out["recording"] = str(rec_dir)
    if return_input:
        out["network_input"] = batch["x"][best].numpy()
    return out
