"""`spare-twin predict`: the measurement and a network on any recording (sim or real), one answer
that says its sources.

`predict_views` is the core: posed views in memory (a recording folder's, a live stream's, a
dataset's) -> the chain's observation (`observe.chain`) -> the layer measurement (`measure`) and the
yaw-free profile network -> the answer (`predict.combine`), each estimate held to what it can answer
(`predict.abstain`). `predict_recording` reads a folder into views and calls it; the image networks
(multi-view and temporal, trained on the rig's images) read the recording itself (`predict.images`).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from spare_twin.config import DEFAULT_PRINT_SCALE, PartDims
from spare_twin.errors import SpareTwinError
from spare_twin.measure.chain import closest_passed, measure_views, measured_at_count
from spare_twin.measure.layers import LayerMeasurement
from spare_twin.measure.level import levelled_image
from spare_twin.measure.process import MeasureProcess
from spare_twin.measure.serve import measure_recording
from spare_twin.nets import checkpoint as ckpt
from spare_twin.nets.registry import decode
from spare_twin.observe.chain import ChainObservation
from spare_twin.observe.profile import ProfileConfig
from spare_twin.observe.views import PosedViews
from spare_twin.predict.abstain import MIN_ARC_DEG, hold_network, measurement_estimate, network_estimate, note_parts
from spare_twin.predict.combine import combined, network_count_over
from spare_twin.predict.early import check_options, measuring_request, print_scale_or_default
from spare_twin.predict.estimate import FIELDS, Estimate, Prediction
from spare_twin.predict.images import predict_images


def _refuse(value, name: str, why: str) -> None:
    if value is not None:
        raise SpareTwinError(f"{name}: {why}")


def predict_recording(
    rec_dir: str | Path,
    model_path: str | Path | None = None,
    frame: int | None = None,
    camera: str | None = None,
    print_scale: float | None = None,
    n_links: int | None = None,
    device: str = "cpu",
    progress: bool = True,
    yaw_hypotheses: int | None = None,
    T_world_base: np.ndarray | None = None,
    camera_poses: dict | None = None,
    answer: str = "combined",
    outside_rig: bool = False,
    parts: PartDims | None = None,
    measuring: MeasureProcess | None = None,
) -> Prediction:
    """`predict`'s answer for a recording folder. The profile model (the default) and the measurement
    read the recording's posed views (`observe.views.recording_views`: `frame` for a rig, `camera` for
    a sweep) through `predict_views`; image networks read the recording itself (`predict.images`:
    `yaw_hypotheses`, `T_world_base`, `camera_poses`; `n_links` for a lengths-only model). Options
    that do not apply to the model or answer chosen are refused, but for `T_world_base` and
    `camera_poses` (`compare`'s twin-aligned diagnostic), which only posed image networks read: the
    profile path finds the chain's base on the table itself. An image network refuses a capture from
    other cameras than its training rig unless `outside_rig` (a diagnostic). The print scale is
    `print_scale` or the default, the printed parts `parts` (`predict.parts.read_parts`) or the
    defaults: the recording's own object configuration is never read. `measuring`: the process that
    `predict.early.start_measuring` set measuring this recording with these options (the profile path
    collects its observation and measurement, the same as its own; the caller closes it)."""
    check_options(frame, print_scale, n_links, yaw_hypotheses, device, answer, parts)
    scale = print_scale_or_default(print_scale)
    parts = parts or PartDims()
    if answer == "measurement":
        _refuse(model_path, "model", "--answer measurement runs no network")
    net = model = None
    if answer != "measurement":
        model_path = model_path or ckpt.default_model("predict")
        model, net, ck = ckpt.load_model(model_path, device)
    if net is None or net.arch == "profile":
        why = "applies to image networks only (the profile network and the measurement have no yaw to guess)"
        _refuse(yaw_hypotheses, "yaw_hypotheses", why)
        _refuse(n_links, "n_links", "applies to lengths-only models only; this answer counts the links itself")
        why = "applies to image networks only (the profile network reads any capture)"
        _refuse(outside_rig or None, "outside_rig", why)
        request = measuring_request(rec_dir, frame, camera, print_scale, parts, progress)
        obs, m = measuring.recording(request) if measuring is not None else measure_recording(*request)
        name = str(model_path) if model_path else None
        return answer_of(obs, m, model, net, name, answer, scale, device, rec_dir, parts)
    if net.arch != "conv3d_per_n":
        _refuse(n_links, "n_links", f"applies to lengths-only models only; {Path(model_path).name} counts the links")
    return predict_images(
        rec_dir,
        model,
        net,
        ck,
        str(model_path),
        answer,
        frame,
        camera,
        scale,
        n_links,
        device,
        progress,
        yaw_hypotheses or 4,
        T_world_base,
        camera_poses,
        outside_rig,
        parts=parts,
    )


def predict_views(
    seen: PosedViews,
    model=None,
    net=None,
    model_name: str | None = None,
    answer: str = "combined",
    print_scale: float = DEFAULT_PRINT_SCALE,
    device: str = "cpu",
    recording: str | Path = "",
    progress: bool = False,
    parts: PartDims = PartDims(),
) -> Prediction:
    """The core: posed views in memory -> the chain observed and measured (`measure.chain.measure_views`)
    with the geometry of the printed `parts` -> the yaw-free profile network (`model`, `net`: a loaded
    profile checkpoint; None with `answer="measurement"`) -> the answer `answer` asks for, with both
    estimates and their sources."""
    obs, m = measure_views(seen, print_scale, progress, min_arc_deg=MIN_ARC_DEG, parts=parts)
    return answer_of(obs, m, model, net, model_name, answer, print_scale, device, recording, parts)


def answer_of(
    obs: ChainObservation,
    m: LayerMeasurement,
    model,
    net,
    model_name: str | None,
    answer: str,
    print_scale: float,
    device: str = "cpu",
    recording: str | Path = "",
    parts: PartDims = PartDims(),
) -> Prediction:
    """The prediction of an observation and its measurement: the profile network run on the
    observation where `answer` asks for it, the estimates held to what they can answer, combined.
    `parts`: what the observation was made with (the network's evidence says where it was trained
    on others, `predict.abstain.note_parts`)."""
    import torch

    # the network reads the profile levelled by the layers' comb (`measure.level`), not the points alone
    image = levelled_image(obs.object, obs.profile, m.comb_zero, print_scale, ProfileConfig.for_parts(parts))
    levelled = "levelled by its layers' comb, " if m.comb_zero is not None and obs.reason is None else ""
    common = dict(
        answer_kind=answer,
        input=f"profile ({levelled}{obs.source}, {obs.views} views)",
        model=model_name,
        recording=str(recording),
        print_scale=print_scale,
        network_input=image,
        T_world_profile=obs.T_world_profile,
        parts=parts,
    )
    measurement = measurement_estimate(obs, m)  # measured whatever the answer: its evidence holds the network too
    if obs.reason is not None:  # nothing to show the network: the answer is no answer, whichever was asked
        none = Estimate.none(f"no chain in view: {obs.reason}")
        timings = {**obs.timings_s, "network": 0.0}
        return Prediction(none, None, None, measurement, timings_s=timings, **common)
    network, res = None, None
    t0 = time.perf_counter()
    if answer != "measurement":
        with torch.no_grad():
            res = decode(model, net, {"x": torch.from_numpy(image[None]).to(device)})
        network = note_parts(hold_network(network_estimate(res, 0, net), obs, m), parts)
    timings = {**obs.timings_s, "network": round(time.perf_counter() - t0, 4)}
    if answer == "network":
        chosen, source = network, _all(network, "network")
    elif answer == "measurement":
        chosen, source = measurement, _all(measurement, "measurement")
    else:
        at_network_count = None
        count = network_count_over(m, network, measurement)
        if count is not None:  # two links the layers ran into one: measured again where they step apart
            t0 = time.perf_counter()
            at_network_count = measurement_estimate(obs, measured_at_count(obs, print_scale, count, parts))
            timings["measurement"] = round(timings.get("measurement", 0.0) + time.perf_counter() - t0, 3)
        passed = closest_passed(m, parts)
        closest = None if passed is None else measurement_estimate(obs, passed)
        chosen, source = combined(m, network, measurement, at_network_count, closest)
    return Prediction(chosen, source, network, measurement, timings_s=timings, **common)


def _all(e: Estimate, name: str) -> dict | None:
    return None if e.n_links is None else {f: name for f in FIELDS}
