"""`spare-twin predict`: a network on any recording (sim or real).

`spare_twin.observe` makes the network's input of the recording (one per yaw hypothesis of its
object frame); this module loads the model, runs it on all of them in one pass and keeps the most
confident output (largest count probability).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from spare_twin.config import MAX_MOVING_LINKS, MIN_MOVING_LINKS
from spare_twin.errors import SpareTwinError
from spare_twin.nets import checkpoint as ckpt
from spare_twin.nets.measured import measurement_slots, overrule
from spare_twin.nets.models import decode, model_inputs
from spare_twin.nets.presets import NetConfig
from spare_twin.observe.chain import measured_chain
from spare_twin.observe.network_input import DEFAULT_PRINT_SCALE, InputSpec, NetworkInput, observe_recording
from spare_twin.recording import Recording


@dataclass(frozen=True)
class Prediction:
    """What a network says of a recording (`spare-twin predict --json`)."""

    n_links: int | None
    """Moving links; None when the model gives no count and none was given."""
    link_lengths_pu: tuple[float, ...] | None
    """n + 1 lengths in paper units, base first (JSON `link_lengths_m`)."""
    probabilities: tuple[float, ...] | None
    """One per count class (n = 1..6), in class order; None for a lengths-only model."""
    joint_angles_rad: tuple[float, ...] | None
    """n joint angles of the observed pose, for models that regress them (else absent from the JSON)."""
    input: str
    """How the recording became the network's input (`spare_twin.observe.Observation.method`)."""
    yaw_hypotheses_deg: tuple[float, ...]
    yaw_deg: float
    """The yaw hypothesis whose output was kept."""
    model: str
    recording: str
    network_input: np.ndarray | None = field(default=None, repr=False, compare=False)
    """(V, H, W) views (or the chain's profile) the network saw for the kept yaw (for logging; not JSON)."""
    reason: str | None = None
    """Why there is no answer (no chain in view); then `n_links` is None."""
    timings_s: dict = field(default_factory=dict, compare=False)
    """Seconds spent in "registration", "observation" and "network" (not JSON: it differs per run)."""
    T_world_profile: np.ndarray | None = field(default=None, repr=False, compare=False)
    """The yaw-free network's profile frame (base on the table, x along the chain's plane, z up) in
    the recording's world, for logging."""

    def to_json(self) -> dict:
        out: dict = {
            "n_links": self.n_links,
            "link_lengths_m": None if self.link_lengths_pu is None else list(self.link_lengths_pu),
            "probabilities": None if self.probabilities is None else list(self.probabilities),
        }
        if self.joint_angles_rad is not None:
            out["joint_angles_rad"] = list(self.joint_angles_rad)
        if self.reason is not None:
            out["reason"] = self.reason
        out["input"] = self.input
        out["yaw_hypotheses_deg"] = list(self.yaw_hypotheses_deg)
        out["yaw_deg"] = self.yaw_deg
        out["model"] = self.model
        out["recording"] = self.recording
        return out


def input_spec(net: NetConfig) -> InputSpec:
    """What `net` reads, in observe's terms."""
    return InputSpec(net.input, net.mode, net.frames, net.height, net.width, posed=net.posed)


def to_batch(inputs: Sequence[NetworkInput]) -> dict:
    """A batch in the docs/design.md layout, one row per input."""
    return {
        "x": torch.as_tensor(np.stack([i.x for i in inputs]), dtype=torch.float32),
        "K": torch.as_tensor(np.stack([i.K for i in inputs]), dtype=torch.float32),
        "T_world_camera": torch.as_tensor(np.stack([i.T_world_camera for i in inputs]), dtype=torch.float32),
        "print_scale": torch.tensor([i.print_scale for i in inputs], dtype=torch.float32),
    }


def _floats(values) -> tuple[float, ...]:
    return tuple(float(v) for v in values)


def _is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def check_options(
    frame: int | None = None,
    print_scale: float | None = None,
    n_links: int | None = None,
    yaw_hypotheses: int = 4,
    device: str = "cpu",
) -> None:
    """`predict_recording`'s options are usable; else an error naming the parameter. Checked before the
    model and the recording are read, so a typo costs no registration."""
    if frame is not None and (not _is_int(frame) or frame < 0):
        raise SpareTwinError(f"frame {frame!r}: must be a frame index, 0 or more")
    if print_scale is not None and (
        isinstance(print_scale, bool)
        or not isinstance(print_scale, (int, float))
        or not math.isfinite(print_scale)
        or print_scale <= 0
    ):
        raise SpareTwinError(f"print_scale {print_scale!r}: must be a positive number (physical m per paper m)")
    if n_links is not None and (not _is_int(n_links) or not MIN_MOVING_LINKS <= n_links <= MAX_MOVING_LINKS):
        raise SpareTwinError(f"n_links {n_links!r}: must be {MIN_MOVING_LINKS}..{MAX_MOVING_LINKS} moving links")
    if yaw_hypotheses not in (1, 2, 4) or isinstance(yaw_hypotheses, bool):
        raise SpareTwinError(f"yaw_hypotheses {yaw_hypotheses!r}: must be 1, 2 or 4")
    if device not in ("cpu", "cuda"):
        raise SpareTwinError(f"device {device!r}: must be cpu or cuda")
    if device == "cuda" and not torch.cuda.is_available():
        raise SpareTwinError("device cuda: no CUDA device is available here; use cpu")


def predict_recording(
    rec_dir: str | Path,
    model_path: str | Path | None = None,
    frame: int | None = None,
    camera: str | None = None,
    print_scale: float | None = None,
    n_links: int | None = None,
    device: str = "cpu",
    progress: bool = True,
    yaw_hypotheses: int = 4,
    T_world_base: np.ndarray | None = None,
    camera_poses: dict | None = None,
) -> Prediction:
    """The network's prediction for a recording (see `observe_recording` for `frame`, `camera`,
    `print_scale`, `yaw_hypotheses`, `T_world_base` and `camera_poses`); `n_links` is the known count
    a lengths-only model needs. The prediction carries the views the network saw (`network_input`)."""
    check_options(frame, print_scale, n_links, yaw_hypotheses, device)
    model_path = model_path or ckpt.default_model("predict")
    model, net, ck = ckpt.load_model(model_path, device)
    if net.arch == "profile":
        return _predict_profile(rec_dir, model, net, model_path, frame, camera, print_scale, device, progress)
    seen = observe_recording(
        rec_dir,
        input_spec(net),
        ck["meta"].get("rig"),
        frame,
        camera,
        print_scale,
        progress=progress,
        yaw_hypotheses=yaw_hypotheses,
        T_world_base=T_world_base,
        camera_poses=camera_poses,
    )
    batch = to_batch(seen.inputs)  # one forward pass for all yaws
    true_n = None
    if net.arch == "conv3d_per_n":
        if n_links is None:
            raise SpareTwinError("n_links: this model measures lengths for a known link count; give it")
        true_n = torch.full((len(seen.inputs),), int(n_links))
    res = decode(model, net, model_inputs(batch, device), true_n=true_n)
    # the most confident yaw hypothesis (count models); length-only models keep the first
    best = int(res["probabilities"].max(1).values.argmax()) if "probabilities" in res else 0
    n, lengths, probabilities, angles = None, None, None, None
    if "pred_n" in res:
        n = int(res["pred_n"][best])
        probabilities = _floats(res["probabilities"][best])
        if "lengths_e2e" in res:
            lengths = _floats(res["lengths_e2e"][best, : n + 1])
    elif "lengths_known" in res:
        n = n_links
        lengths = _floats(res["lengths_known"][best, : n_links + 1])
    if "angles" in res and n:
        angles = _floats(res["angles"][best, :n])
    yaws_deg = tuple(round(float(np.degrees(y)), 3) for y in seen.yaws_rad)
    return Prediction(
        n_links=n,
        link_lengths_pu=lengths,
        probabilities=probabilities,
        joint_angles_rad=angles,
        input=seen.method,
        yaw_hypotheses_deg=yaws_deg,
        yaw_deg=yaws_deg[best],
        model=str(model_path),
        recording=str(rec_dir),
        network_input=batch["x"][best].numpy(),
    )


#: Decimals kept in `predict --json` of the yaw-free network: far below any measurement's precision,
#: and what makes the output the same bytes on every machine (float reductions differ in the last bits).
JSON_DECIMALS = 6


def _rounded(values) -> tuple[float, ...]:
    return tuple(round(float(v), JSON_DECIMALS) for v in values)


def _predict_profile(rec_dir, model, net, model_path, frame, camera, print_scale, device, progress) -> Prediction:
    """The yaw-free network on `observe.chain.measured_chain`'s profile of the recording, overruled by
    the chain measured on the points layer by layer (`observe.layers`, `nets.measured`) wherever that
    finds one; no answer (a `reason`) where the layers count a chain whose points lie on none. The
    print scale is the flag's or the default: the recording's own object configuration is never read."""
    rec = Recording.open(rec_dir)
    scale = float(print_scale) if print_scale is not None else DEFAULT_PRINT_SCALE
    seen, measurement = measured_chain(rec, scale, frame, camera, progress=progress)
    common = dict(
        input=f"profile ({seen.source}, {seen.views} views)",
        yaw_hypotheses_deg=(),
        yaw_deg=0.0,
        model=str(model_path),
        recording=str(rec_dir),
        network_input=seen.profile.image,
        T_world_profile=seen.T_world_profile,
    )
    if seen.reason is not None:
        timings = {**seen.timings_s, "network": 0.0}
        return Prediction(
            None, None, None, None, reason=f"no chain in view: {seen.reason}", timings_s=timings, **common
        )
    t0 = time.perf_counter()
    x = torch.from_numpy(seen.profile.image[None]).to(device)
    res = decode(model, net, {"x": x})
    timings = {**seen.timings_s, "network": round(time.perf_counter() - t0, 4)}
    if measurement.reason is not None:  # the network, on the same blurred points, does no better
        return Prediction(
            None, None, None, None, reason=f"no chain measured: {measurement.reason}", timings_s=timings, **common
        )
    slots = measurement_slots(measurement)
    res = overrule(res, {k: torch.as_tensor(v)[None] for k, v in slots.items()})
    n = int(res["pred_n"][0])
    return Prediction(
        n_links=n,
        link_lengths_pu=_rounded(res["lengths_e2e"][0, : n + 1]),
        probabilities=_rounded(res["probabilities"][0]),
        joint_angles_rad=_rounded(res["angles"][0, :n]),
        timings_s=timings,
        **common,
    )
