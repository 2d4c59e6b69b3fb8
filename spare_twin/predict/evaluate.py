"""`spare-twin evaluate`: a network's own figures and, where a measurement stands beside it, the
figures of the answer `predict` gives (the network overruled by the measurement).

The network alone is `spare_twin.nets.evaluate`; the combination needs the measurement and so lives
here, above nets. Both come from one pass over the split: the profile network's samples carry the
layer measurement of the same observed points (`nets.profile_train`, cached), and `combine.overrule`
applies it to all the network's predictions at once, so the combined figure costs no more network
time than the network's own. The headline (the DESIGN.md keys at the top level) is the network's.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import torch

from spare_twin.io import write_json_atomic
from spare_twin.nets import checkpoint as ckpt
from spare_twin.nets import evaluate as net_evaluate
from spare_twin.nets.evaluate import EVALUATE, RECORDED, Evaluation, evaluation_of, recorded_metrics, write_outputs
from spare_twin.output import writing
from spare_twin.predict.combine import overrule
from spare_twin.predict.evaluate_inputs import check_evaluate

#: Which estimate the top-level `count_accuracy` and `E_L` are: the network's own.
HEADLINE = "network"
#: The prefix of the combined answer's figures where a shipped checkpoint records them.
WITH_MEASUREMENT = "with_measurement_"
#: Why there is no combined figure for a model that has no measurement beside it.
NO_MEASUREMENT = "no measurement beside this network: predict answers with the network alone"


@dataclass(frozen=True)
class SourcesEvaluation:
    """The network's own evaluation and the combined answer's (None where the network has no
    measurement beside it); `evaluate --json` prints `to_json()`."""

    network: Evaluation
    combined: Evaluation | None
    shipped: str | None = None

    def to_json(self) -> dict:
        head = self.network.to_json()
        out = {k: head.pop(k) for k in ("count_accuracy", "E_L", "instances", "split")}
        out["headline"] = HEADLINE
        out["network"] = _figures(self.network)
        out["combined"] = None if self.combined is None else _figures(self.combined)
        if self.combined is None:
            out["combined_reason"] = NO_MEASUREMENT
        out.update(head)  # the network's E_L_end_to_end, per_n, ... at the top level, as before
        if self.shipped is not None:
            out["shipped"] = self.shipped
        return out


def _figures(ev: Evaluation) -> dict:
    d = ev.to_json()
    keys = ("count_accuracy", "E_L", "E_L_end_to_end", "E_L_n_known", "per_n", "confusion_matrix", "confusion_png")
    return {k: d[k] for k in keys if k in d}


def combined_evaluation(network: Evaluation) -> Evaluation | None:
    """The figures of `predict`'s answer on the same instances: the network's predictions overruled by
    the measurement each sample carries (`combine.overrule`); None where the samples carry none.
    The n-known lengths are the network's alone, so the combined answer has no E_L_n_known."""
    pred = network.predictions
    if "measured_n" not in pred:
        return None
    res = {k: torch.as_tensor(pred[k]) for k in ("pred_n", "probabilities", "lengths_e2e", "angles") if k in pred}
    slots = {k: torch.as_tensor(v) for k, v in pred.items() if k.startswith("measured_")}
    answer = overrule(res, slots)
    combined = {k: v for k, v in pred.items() if k != "lengths_known"}
    combined.update({k: answer[k].numpy() for k in ("pred_n", "lengths_e2e")})
    return evaluation_of(combined, network.split, network.model, network.preset, network.data)


def recorded(result: SourcesEvaluation) -> dict:
    """What a shipped checkpoint records: the network's own figures under the plain names, the combined
    answer's beside them as `with_measurement_*` (after them in the card's order and in
    models/index.json's sorted keys alike)."""
    out = recorded_metrics(result.network)
    if result.combined is not None:
        combined = recorded_metrics(result.combined)
        tail = {k: out.pop(k) for k in ("instances", "split", "data")}
        out.update({f"{WITH_MEASUREMENT}{k}": combined[k] for k in RECORDED if combined[k] is not None})
        out.update(tail)
    return out


def evaluate_model(
    model_path: str | Path | None,
    data_dir: str | Path,
    split: str = "test",
    device: str = "auto",
    batch_size: int = 16,
    out_dir: str | Path | None = None,
    max_samples: int | None = None,
    ship: str | None = None,
    default_for: Sequence[str] = (),
    command: str = "",
    models_dir: Path = ckpt.MODELS_DIR,
    progress: bool = True,
    force: bool = False,
) -> SourcesEvaluation:
    """The network alone and combined with its measurement (see the module doc) over `split`, on a
    seeded random subset of `max_samples` if given; under `out_dir` (an output, `spare_twin.output`)
    evaluation.json and the confusion matrices (confusion_matrix.png: the network's,
    confusion_matrix_combined.png). With `ship`: the figures recorded in a copy of the checkpoint,
    shipped to `models_dir` as <ship>.pt with a model card, the default for the tasks in `default_for`."""
    check_evaluate(model_path, data_dir, batch_size, max_samples, ship, default_for)  # before minutes of work
    model_path = model_path or ckpt.default_model("predict")
    outputs = (
        contextlib.nullcontext(None)
        if out_dir is None
        else writing(out_dir, EVALUATE, (model_path, data_dir), force)  # checked before the inference
    )
    with outputs as tmp:
        network = net_evaluate.evaluate(model_path, data_dir, split, device, batch_size, None, max_samples, progress)
        result = SourcesEvaluation(network, combined_evaluation(network))
        if tmp is not None:
            result = SourcesEvaluation(
                write_outputs(result.network, tmp, Path(out_dir)),
                None
                if result.combined is None
                else write_outputs(result.combined, tmp, Path(out_dir), "confusion_matrix_combined.png"),
            )
            write_json_atomic(tmp / "evaluation.json", result.to_json())
    if ship is None:
        return result
    shipped = net_evaluate.ship_evaluated(network.model, recorded(result), ship, default_for, command, models_dir)
    return replace(result, shipped=str(shipped))
