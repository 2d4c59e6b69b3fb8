"""`spare-twin predict`: a network on any recording (sim or real).

The recording's views are brought into the network's input space: 96 x 128, centre-cropped to the
4:3 aspect and resized, with the intrinsics adjusted to match (depth resized with nearest
neighbour, so no depth is invented at edges). A recording from another camera rig than the training
rig goes through `spare_twin.capture.canonical.to_rig_views` (the capture stage), except for the
geometry-aware networks, which fuse views through their poses and take any posed cameras as they are.
"""

from __future__ import annotations

import numpy as np
import torch

from spare_twin import SpareTwinError
from spare_twin.nets import checkpoint as ckpt
from spare_twin.nets.models import decode, model_inputs
from spare_twin.nets.presets import NetConfig

DEFAULT_PRINT_SCALE = 0.08  # ChainSpec's default, for recordings that do not carry their object


def fit_view(img: np.ndarray, K: np.ndarray, height: int, width: int, nearest: bool) -> tuple[np.ndarray, np.ndarray]:
    """Centre-crop to width:height aspect, resize to (height, width); K follows the crop and scale."""
    import cv2

    h, w = img.shape[:2]
    if w * height > h * width:  # too wide: crop columns
        cw, ch = int(round(h * width / height)), h
    else:
        cw, ch = w, int(round(w * height / width))
    x0, y0 = (w - cw) // 2, (h - ch) // 2
    img = img[y0 : y0 + ch, x0 : x0 + cw]
    out = cv2.resize(img, (width, height), interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_AREA)
    sx, sy = width / cw, height / ch
    K2 = np.asarray(K, np.float64).copy()
    # pixel-centre convention: u' + 0.5 = (u - x0 + 0.5) * s
    K2[0, 0] *= sx
    K2[1, 1] *= sy
    K2[0, 2] = (K2[0, 2] - x0 + 0.5) * sx - 0.5
    K2[1, 2] = (K2[1, 2] - y0 + 0.5) * sy - 0.5
    return out, K2


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


def recording_sample(rec, net: NetConfig, frame: int | None = None, camera: str | None = None,
                     print_scale: float | None = None) -> dict:
    """A batch of one in the CONTRACTS.md layout from a recording."""
    needs_poses = net.arch == "geo_voxel"
    if print_scale is None:
        obj = rec.object_config or {}
        print_scale = float(obj.get("print_scale", DEFAULT_PRINT_SCALE))
    if net.mode == "mv":
        if len(rec.cameras) != net.frames:
            raise SpareTwinError(f"{rec.root}: the network takes {net.frames} views, the recording has {len(rec.cameras)} cameras")
        frame = rec.n_frames // 2 if frame is None else frame
        views = [_view(rec, c.name, frame, net) for c in rec.cameras]
    else:
        cam = camera or rec.cameras[0].name
        picks = np.linspace(0, rec.n_frames - 1, net.frames).round().astype(int)  # resample to T frames
        views = [_view(rec, cam, int(f), net) for f in picks]
        views = [(img, views[0][1], views[0][2]) for img, _, _ in views]
    if needs_poses and any(T is None for _, _, T in views):
        raise SpareTwinError(f"{rec.root}: camera poses unknown; run `spare-twin capture register` first")
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


def _to_training_rig(rec, training_rig: str | None, net: NetConfig):
    if training_rig is None or rec.rig == training_rig:
        return rec
    if net.arch == "geo_voxel" and all(c.poses != "unknown" and (c.T_world_camera is not None or c.poses == "per_frame") for c in rec.cameras) and net.mode == "tmp":
        return rec  # one posed camera suffices for the temporal voxel network
    if net.arch == "geo_voxel" and len(rec.cameras) == net.frames and all(c.T_world_camera is not None or c.poses == "per_frame" for c in rec.cameras):
        return rec  # posed views fuse into the world grid whatever the rig
    try:
        from spare_twin.capture.canonical import to_rig_views
    except ImportError:
        raise SpareTwinError(
            f"{rec.root}: recorded with rig {rec.rig!r}, the model was trained on rig {training_rig!r}, and "
            "re-rendering into the training rig (spare_twin.capture.canonical.to_rig_views) is not available"
        ) from None
    return to_rig_views(rec, training_rig)


def predict_recording(rec_dir, model_path=None, frame: int | None = None, camera: str | None = None,
                      print_scale: float | None = None, n_links: int | None = None, device: str = "cpu") -> dict:
    from spare_twin.recording import Recording

    model_path = model_path or ckpt.default_model("predict")
    model, net, ck = ckpt.load_model(model_path, device)
    rec = _to_training_rig(Recording.open(rec_dir), ck["meta"].get("rig"), net)
    if frame is not None and not 0 <= frame < rec.n_frames:
        raise SpareTwinError(f"--frame {frame}: the recording has frames 0..{rec.n_frames - 1}")
    batch = recording_sample(rec, net, frame, camera, print_scale)
    true_n = None
    if net.arch == "conv3d_per_n":
        if n_links is None:
            raise SpareTwinError("--n-links: this model measures lengths for a known link count; give it")
        true_n = torch.tensor([n_links])
    res = decode(model, net, model_inputs(batch, device), true_n=true_n)
    out: dict = {"n_links": None, "link_lengths_m": None, "probabilities": None}
    if "pred_n" in res:
        n = int(res["pred_n"][0])
        out["n_links"] = n
        out["probabilities"] = [float(p) for p in res["probabilities"][0]]
        if "lengths_e2e" in res:
            out["link_lengths_m"] = [float(v) for v in res["lengths_e2e"][0, : n + 1]]
    elif "lengths_known" in res:
        out["n_links"] = n_links
        out["link_lengths_m"] = [float(v) for v in res["lengths_known"][0, : n_links + 1]]
    if "angles" in res and out["n_links"]:
        out["joint_angles_rad"] = [float(v) for v in res["angles"][0, : out["n_links"]]]
    out["model"] = str(model_path)
    out["recording"] = str(rec_dir)
    return out
