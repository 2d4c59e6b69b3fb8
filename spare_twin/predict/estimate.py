"""What `predict` says of a recording, as types: one `Estimate` per estimator (a network, the
measurement) and the `Prediction` that holds the answer, both estimates and which fields of the
answer came from which (`predict --json`, version 2, docs/design.md)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from spare_twin.config import PartDims
from spare_twin.predict.parts import TRAINED_PARTS, parts_json, parts_words

#: `predict --json`'s format and version.
FORMAT = "spare-twin-prediction"
VERSION = 2
#: What `--answer` may ask for: the network overruled by the measurement where that finds a chain
#: (`predict.combine`), or either estimate alone.
ANSWERS = ("combined", "network", "measurement")
#: The answer's fields that an estimate gives (the JSON's `source` names the estimate of each).
FIELDS = ("n_links", "link_lengths_pu", "joint_angles_rad")
#: Decimals kept in the JSON: far below any estimate's precision, and what makes the output the same
#: bytes on every machine (float reductions differ in the last bits).
JSON_DECIMALS = 6


def rounded(values) -> tuple[float, ...] | None:
    return None if values is None else tuple(round(float(v), JSON_DECIMALS) for v in values)


def _list(values) -> list | None:
    return None if values is None else list(values)


@dataclass(frozen=True)
class NetworkEvidence:
    """What a network's count rests on."""

    probabilities: tuple[float, ...] | None
    """One per count class (n = 1..6); None for a lengths-only model."""
    yaw_hypotheses_deg: tuple[float, ...] | None = None
    """Image networks on a recording from other cameras: the rotations of the found object frame
    tried (the most confident output is kept); None where the input has no yaw to guess (the
    yaw-free profile network, a recording from the training rig)."""
    yaw_deg: float | None = None
    """The yaw hypothesis whose output was kept."""
    outside_training: str | None = None
    """Set where the network was run on a kind of capture it was not trained on (`predict
    --outside-rig`, a diagnostic): which kind, and what it was trained on."""
    other_parts: str | None = None
    """Set where the chain was printed with other parts than the network was trained on (`predict
    --parts`): what it was trained on (`predict.abstain.note_parts`)."""

    def to_json(self) -> dict:
        out: dict = {"probabilities": _list(rounded(self.probabilities))}
        if self.yaw_hypotheses_deg is not None:
            out["yaw_hypotheses_deg"] = list(self.yaw_hypotheses_deg)
            out["yaw_deg"] = self.yaw_deg
        if self.outside_training is not None:
            out["outside_training"] = self.outside_training
        if self.other_parts is not None:
            out["other_parts"] = self.other_parts
        return out


@dataclass(frozen=True)
class MeasurementEvidence:
    """What the layer measurement's count rests on (`spare_twin.measure.layers`)."""

    rms_m: float | None
    """RMS distance of the points outside their link plates; None where nothing was fitted."""
    points_per_layer: tuple[int, ...]
    """Link points in each layer 0, 1, ..; the count is the highest well-populated layer."""

    def to_json(self) -> dict:
        return {
            "rms_m": None if self.rms_m is None else round(float(self.rms_m), JSON_DECIMALS),
            "points_per_layer": list(self.points_per_layer),
        }


@dataclass(frozen=True)
class Estimate:
    """One estimator's estimate of the chain: count, lengths in paper units, joint angles, and its
    evidence; a reason where it gives no count."""

    n_links: int | None
    """Moving links; None: no answer (see `reason`)."""
    link_lengths_pu: tuple[float, ...] | None
    """n + 1 lengths in paper units, base first."""
    joint_angles_rad: tuple[float, ...] | None
    """n relative joint angles of the observed pose, where the estimator gives them."""
    evidence: NetworkEvidence | MeasurementEvidence | None = None
    reason: str | None = None
    """Why there is no count; set exactly when `n_links` is None."""

    def __post_init__(self):
        if (self.n_links is None) != (self.reason is not None):
            raise ValueError(f"Estimate: a reason goes with no count and only then ({self.n_links}, {self.reason!r})")

    @classmethod
    def none(cls, reason: str, evidence: NetworkEvidence | MeasurementEvidence | None = None) -> Estimate:
        return cls(None, None, None, evidence, reason)

    def to_json(self) -> dict:
        out: dict = {
            "n_links": self.n_links,
            "link_lengths_pu": _list(rounded(self.link_lengths_pu)),
            "joint_angles_rad": _list(rounded(self.joint_angles_rad)),
        }
        if self.evidence is not None:
            out.update(self.evidence.to_json())
        if self.reason is not None:
            out["reason"] = self.reason
        return out


@dataclass(frozen=True)
class Prediction:
    """What `predict` says of a recording (`predict --json`): the answer, the network's estimate and
    the measurement's, and which of them gave each field of the answer."""

    answer: Estimate
    """The estimate `--answer` asked for (its evidence is the estimates' own, under `network` and
    `measurement`)."""
    source: dict[str, str] | None
    """Per answer field (`FIELDS`), the estimate it came from: "network", "measurement", or "measurement
    at the network's count" (the chain measured again at a count the network is sure of, more than
    the layers counted: `predict.combine.MEASURED_AT_NETWORK_COUNT`). None where there is no answer."""
    network: Estimate | None
    """The network's own estimate; None where no network ran (`--answer measurement`, no chain in view)."""
    measurement: Estimate | None
    """The measurement's own estimate; None where it was not run (an image network with `--answer
    network`, or in its training rig)."""
    answer_kind: str
    """What was asked for: one of `ANSWERS`."""
    input: str
    """How the recording became the estimators' input."""
    model: str | None
    """The network's checkpoint; None where none was read (`--answer measurement`)."""
    recording: str
    print_scale: float
    """Physical metres per paper metre: the one `link_lengths_mm` is at."""
    network_input: np.ndarray | None = field(default=None, repr=False, compare=False)
    """(V, H, W) views (or the chain's profile) the network saw (for logging; not JSON)."""
    timings_s: dict = field(default_factory=dict, compare=False)
    """Seconds per step ("registration", "observation", "measurement", "network"); not JSON: it
    differs per run."""
    T_world_profile: np.ndarray | None = field(default=None, repr=False, compare=False)
    """The chain's profile frame (base on the table, x along the chain's plane, z up) in the
    recording's world, where the chain was observed (for logging)."""
    parts: PartDims = field(default_factory=PartDims)
    """The part dimensions the chain was observed and measured with (`predict --parts`)."""

    @property
    def n_links(self) -> int | None:
        return self.answer.n_links

    @property
    def link_lengths_pu(self) -> tuple[float, ...] | None:
        return self.answer.link_lengths_pu

    @property
    def link_lengths_mm(self) -> tuple[float, ...] | None:
        if self.answer.link_lengths_pu is None:
            return None
        return tuple(round(1000.0 * self.print_scale * v, 3) for v in self.answer.link_lengths_pu)

    @property
    def joint_angles_rad(self) -> tuple[float, ...] | None:
        return self.answer.joint_angles_rad

    @property
    def reason(self) -> str | None:
        return self.answer.reason

    @property
    def probabilities(self) -> tuple[float, ...] | None:
        """The network's count probabilities, where a count network ran (its evidence, not the answer's)."""
        ev = self.network.evidence if self.network is not None else None
        return ev.probabilities if isinstance(ev, NetworkEvidence) else None

    def source_json(self) -> str | dict | None:
        """`source` in the JSON: one name where every field came from one estimate, else per field."""
        if self.source is None:
            return None
        names = set(self.source.values())
        return names.pop() if len(names) == 1 else dict(self.source)

    def to_json(self) -> dict:
        out: dict = {
            "format": FORMAT,
            "version": VERSION,
            "n_links": self.n_links,
            "link_lengths_pu": _list(rounded(self.link_lengths_pu)),
            "link_lengths_mm": _list(self.link_lengths_mm),
            "joint_angles_rad": _list(rounded(self.joint_angles_rad)),
            "source": self.source_json(),
        }
        if self.reason is not None:
            out["reason"] = self.reason
        out["network"] = None if self.network is None else self.network.to_json()
        out["measurement"] = None if self.measurement is None else self.measurement.to_json()
        out["input"] = self.input
        out["model"] = self.model
        out["recording"] = self.recording
        out["answer"] = self.answer_kind
        out["print_scale"] = self.print_scale
        out["parts"] = parts_json(self.parts)
        return out

    def in_words(self) -> list[str]:
        """The same as `to_json`, as lines for a person."""
        lines = [f"answer ({self.answer_kind}): {_estimate_words(self.answer, self.print_scale)}"]
        if self.source is not None:
            src = self.source_json()
            words = f"the {src}" if isinstance(src, str) else "; ".join(f"{k} from the {v}" for k, v in src.items())
            lines.append(f"  from: {words}")
        for name, est in (("network", self.network), ("measurement", self.measurement)):
            lines.append(f"{name}: " + ("not run" if est is None else _estimate_words(est, None)))
        lines.append(f"input: {self.input}; model: {self.model or 'none'}")
        given = "the default parts" if self.parts == TRAINED_PARTS else "the parts given"
        lines.append(f"parts: {parts_words(self.parts)} ({given})")
        return lines


def _estimate_words(e: Estimate, print_scale: float | None) -> str:
    if e.n_links is None:
        text = f"no answer: {e.reason}"
    else:
        text = f"{e.n_links} moving links"
        if e.link_lengths_pu is not None:
            text += "; lengths (paper units, base first): " + ", ".join(f"{v:.3f}" for v in e.link_lengths_pu)
            if print_scale is not None:
                text += " = " + ", ".join(f"{1000 * print_scale * v:.1f}" for v in e.link_lengths_pu) + " mm"
        if e.joint_angles_rad is not None:
            text += "; joint angles (deg): " + ", ".join(f"{np.degrees(a):.1f}" for a in e.joint_angles_rad)
    ev = e.evidence
    if isinstance(ev, NetworkEvidence) and ev.probabilities is not None:
        k = int(np.argmax(ev.probabilities))
        text += f" (count probability {ev.probabilities[k]:.3f} on {k + 1})"
    if isinstance(ev, NetworkEvidence) and ev.other_parts is not None:
        text += f" [{ev.other_parts}]"
    if isinstance(ev, NetworkEvidence) and ev.outside_training is not None:
        text += f" [diagnostic, outside its training: {ev.outside_training}]"
    elif isinstance(ev, MeasurementEvidence) and ev.rms_m is not None:
        text += f" (RMS {1000 * ev.rms_m:.1f} mm off the plates; points per layer {list(ev.points_per_layer)})"
    return text
