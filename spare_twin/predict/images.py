"""Image networks (multi-view and temporal, trained on the rig's depth or grey images) on a recording.

`spare_twin.observe.network_input.observe_recording` makes the network's input of the recording (one
per yaw hypothesis of its object frame); this module runs the network on all of them in one pass and
keeps the most confident output (largest count probability). Outside the training rig the chain is
also observed and measured on the recording's posed views (`--answer combined`): where the
measurement finds no chain there (nothing on the table is one, or its points lie on none) the answer
is no answer and the network is not asked; elsewhere the answer is the network's estimate, with the
measurement's beside it. A temporal network reads its trained number of consecutive frames; a shorter recording
gets no answer from it.

An image network trained on a rig reads fixed cameras only (`capture_refusal`): on hand-held sweeps
the shipped ones counted 3 and 4 of 12 objects even on the clean twin (bench sim2real, seeds
30006-30017), where in the rig they count every one, and nothing in their output told the two apart. So
they refuse a moving camera with one line naming the kind of capture they need; `outside_rig`
(`predict --outside-rig`) runs them anyway as a diagnostic, labelled so in the network's evidence.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from spare_twin.config import PartDims
from spare_twin.errors import SpareTwinError
from spare_twin.measure.chain import measure_views
from spare_twin.nets.models import model_inputs
from spare_twin.nets.presets import NetConfig
from spare_twin.nets.registry import decode
from spare_twin.observe.network_input import InputSpec, NetworkInput, observe_recording
from spare_twin.observe.views import recording_views
from spare_twin.predict.abstain import MIN_ARC_DEG, measurement_estimate, network_estimate, note_parts
from spare_twin.predict.estimate import FIELDS, Estimate, Prediction
from spare_twin.recording import Recording


def input_spec(net: NetConfig) -> InputSpec:
    """What `net` reads, in observe's terms."""
    return InputSpec(net.input, net.mode, net.frames, net.height, net.width, posed=net.posed)


def to_batch(inputs: Sequence[NetworkInput]) -> dict:
    """A batch in the docs/design.md layout, one row per input."""
    import torch

    return {
        "x": torch.as_tensor(np.stack([i.x for i in inputs]), dtype=torch.float32),
        "K": torch.as_tensor(np.stack([i.K for i in inputs]), dtype=torch.float32),
        "T_world_camera": torch.as_tensor(np.stack([i.T_world_camera for i in inputs]), dtype=torch.float32),
        "print_scale": torch.tensor([i.print_scale for i in inputs], dtype=torch.float32),
    }


class CaptureRefused(SpareTwinError):
    """A network refuses a kind of capture it was not trained to read (`capture_refusal`); callers that
    score many networks count it as refused, apart from an answer or no answer."""


def capture_kind(rec: Recording) -> str:
    """The kind of capture `rec` is, in words: a rig's fixed cameras, or a moving camera."""
    if rec.rig is not None:
        return f"a recording of the rig '{rec.rig}'"
    moving = [c.name for c in rec.cameras if c.poses != "fixed"]
    if len(rec.cameras) == 1:
        return "a hand-held capture (one moving camera)" if moving else "one fixed camera"
    fixed = len(rec.cameras) - len(moving)
    return f"{len(rec.cameras)} cameras ({fixed} fixed, {len(moving)} moving), not a training rig"


def capture_refusal(rec: Recording, rig: str | None, model_name: str, mode: str = "mv") -> str | None:
    """Why an image network trained on the rig `rig` (None: on any cameras) in `mode` ("mv" or
    "tmp") does not read `rec`, or None where it does: it reads its own rig, and other fixed cameras
    re-rendered into it (several for a multi-view network, one for a temporal one), never a moving
    camera."""
    fixed = all(c.poses == "fixed" for c in rec.cameras)
    if rig is None or rec.rig == rig or (fixed and len(rec.cameras) >= (2 if mode == "mv" else 1)):
        return None
    needs = "several fixed cameras" if mode == "mv" else "a fixed camera"
    return (
        f"{Path(model_name).name} reads {needs} only, as in its training rig '{rig}' (on hand-held captures it "
        f"miscounts without knowing it), and this is {capture_kind(rec)}: use the default profile model"
    )


def predict_images(
    rec_dir: str | Path,
    model,
    net: NetConfig,
    ck: dict,
    model_name: str,
    answer: str,
    frame: int | None,
    camera: str | None,
    print_scale: float,
    n_links: int | None,
    device: str,
    progress: bool,
    yaw_hypotheses: int,
    T_world_base: np.ndarray | None,
    camera_poses: dict | None,
    outside_rig: bool = False,
    parts: PartDims = PartDims(),
) -> Prediction:
    """An image network's prediction for a recording (see the module doc; `observe_recording` for
    `frame`, `camera`, `yaw_hypotheses`, `T_world_base` and `camera_poses`); `n_links` is the known
    count a lengths-only model needs. `answer`: "combined" (the network's estimate, no answer where
    the measurement sees no chain) or "network" (the network's estimate alone). A capture outside the
    network's training rig is refused (`capture_refusal`) unless `outside_rig`."""
    import torch

    rec = Recording.open(rec_dir)
    if net.arch == "conv3d_per_n" and n_links is None:
        raise SpareTwinError("n_links: this model measures lengths for a known link count; give it")
    rig = ck["meta"].get("rig")
    in_rig = rig is None or rec.rig == rig
    refusal = capture_refusal(rec, rig, model_name, net.mode)
    if refusal is not None and not outside_rig:
        raise CaptureRefused(refusal + ", or --outside-rig to run it anyway as a diagnostic")
    outside = None if refusal is None else f"{capture_kind(rec)}; trained on the rig '{rig}'"
    measurement, obs, timings = None, None, {}
    if answer == "combined" and not in_rig:
        views = recording_views(rec, frame, camera, progress=progress)
        obs, m = measure_views(views, print_scale, progress, min_arc_deg=MIN_ARC_DEG, parts=parts)
        measurement, timings = measurement_estimate(obs, m), dict(obs.timings_s)
    common = dict(answer_kind=answer, model=model_name, recording=str(rec_dir), print_scale=print_scale, parts=parts)
    if measurement is not None and measurement.n_links is None:  # no chain on the table: no network is asked
        return Prediction(Estimate.none(measurement.reason), None, None, measurement, input="none", **common)
    if net.mode == "tmp" and rec.n_frames < net.frames:
        why = (
            f"the temporal model reads {net.frames} consecutive frames of one camera (its trained length); "
            f"the recording has {rec.n_frames}"
        )
        network = Estimate.none(why)
        return Prediction(network, None, network, measurement, input="none", timings_s=timings, **common)
    t0 = time.perf_counter()
    seen = observe_recording(
        rec,
        input_spec(net),
        rig,
        frame,
        camera,
        print_scale,
        progress=progress,
        yaw_hypotheses=yaw_hypotheses,
        T_world_base=T_world_base,
        camera_poses=camera_poses,
    )
    t1 = time.perf_counter()
    batch = to_batch(seen.inputs)  # one forward pass for all yaws
    true_n = None if net.arch != "conv3d_per_n" else torch.full((len(seen.inputs),), int(n_links))
    with torch.no_grad():
        res = decode(model, net, model_inputs(batch, device), true_n=true_n)
    timings = {**timings, "network input": round(t1 - t0, 3), "network": round(time.perf_counter() - t1, 4)}
    # the most confident yaw hypothesis (count models); length-only models keep the first
    best = int(res["probabilities"].max(1).values.argmax()) if "probabilities" in res else 0
    yaws_deg = tuple(round(float(np.degrees(y)), 3) for y in seen.yaws_rad)
    several = len(yaws_deg) > 1  # a yaw was guessed
    network = network_estimate(res, best, net, n_links, *((yaws_deg, yaws_deg[best]) if several else (None, None)))
    network = note_parts(network, parts)  # the measurement above reads the given parts; the network never saw them
    if outside is not None and network.evidence is not None:
        network = dataclasses.replace(network, evidence=dataclasses.replace(network.evidence, outside_training=outside))
    common.update(input=seen.method, network_input=batch["x"][best].numpy(), timings_s=timings)
    source = None if network.n_links is None else {f: "network" for f in FIELDS}
    return Prediction(network, source, network, measurement, **common)
