"""The main job end to end on embedded defaults (`spare-twin demo`):

1. the printable object of a default chain (STLs, URDF, assembly notes, preview);
2. its twin rendered by the 8-camera training rig;
3. a simulated-sensor recording of the "printed" object: one hand-held camera with the RealSense
   noise model fitted to real frames, poses hidden as a real sensor's are;
4. that recording exported as a 7-Scenes folder and imported back, as a real capture would be;
5. registration: camera poses, TSDF fusion, the object on the table;
6. predictions of the shipped model on the twin and on the "real" recording;
7. compare: the URDF twin fitted to the real cloud, rendered through the same cameras, both
   predictions scored against the printed configuration, and a Rerun recording of it all.

The summary's real row is `predict` on the capture alone (no object folder, nothing from the fit);
the row that re-aligns the real cameras onto the fitted printed twin is shown as a diagnostic. The
whole comparison is kept as `compare.json` beside the Rerun recording.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from spare_twin.capture.simulated import SensorCaptureConfig, simulated_capture
from spare_twin.compare.inputs import DEMO, check_demo
from spare_twin.compare.result import Comparison, summary_row
from spare_twin.compare.sim_vs_real import compare
from spare_twin.config import ChainSpec
from spare_twin.io import write_json_atomic
from spare_twin.nets.checkpoint import default_model, load_model
from spare_twin.object.folder import build_object
from spare_twin.output import writing
from spare_twin.predict.estimate import Prediction
from spare_twin.predict.run import predict_recording
from spare_twin.sim.render import RenderConfig, render_recording

#: The demo's object: a 3-link chain as the paper's distribution makes them (lengths in range, scaled
#: to sum to 3), fixed so every run shows the same object.
DEMO_CHAIN = ChainSpec(
    n_links=3,
    link_lengths_pu=(1.45, 0.7, 0.5, 0.35),
    colors=("black", "red", "blue", "yellow"),
    name="demo_chain",
)
RIG_FRAMES = 20
SEED = 0
STEPS = 7
#: The summary's labels of `predict` on the capture alone, and of the diagnostic that needs the twin.
REAL_LABEL = "real (capture, predict alone)"
ALIGNED_LABEL = "diagnostic: real, twin-aligned"


@dataclass(frozen=True)
class DemoResult:
    """What the demo made and what it found."""

    object_dir: Path
    urdf_name: str
    rrd: Path
    rig_prediction: Prediction
    """The shipped model on the training rig's render of the twin."""
    comparison: Comparison
    """`compare` on the capture: `real` is `predict` on it alone, `real_twin_aligned` the diagnostic."""
    seconds: float

    def summary(self) -> str:
        """The demo's report: true vs sim vs real, in paper units."""
        c, rig = self.comparison, self.rig_prediction
        lines = [
            f"spare-twin demo finished in {self.seconds:.0f} s (paper units, base first)",
            *c.summary_rows({"truth": "true (printed)"}),
            summary_row("sim, training rig", rig.n_links, rig.link_lengths_pu, c.truth.score(rig)),
            *c.summary_rows({"sim": "sim, same cameras", "real": REAL_LABEL, "real_twin_aligned": ALIGNED_LABEL}),
        ]
        reason = c.real.to_json().get("reason")
        if reason:
            lines.append(f"  real: no count ({reason})")
        lines += [f"  {label}: {_sources(p)}" for label, p in (("sim, training rig", rig), ("real", c.real))]
        predicted = c.predicted_angle_errors_deg("real")
        if predicted is not None:
            errors = ", ".join(f"{a:.1f}" for a in predicted)
            lines.append(f"  joint angles from predict alone, error vs truth: {errors} deg")
        lines += [
            "  joint angles from articulated registration, error vs truth: "
            + ", ".join(f"{a:.1f}" for a in c.joint_angle_errors_deg)
            + " deg",
            f"  printable files: {self.object_dir}/ (STLs, {self.urdf_name}, ASSEMBLY.md, preview.png)",
            f"  Rerun recording: {self.rrd}  (open with `rerun {self.rrd}`)",
        ]
        return "\n".join(lines)


def _sources(p: Prediction) -> str:
    """Where an answer came from, and what each estimate said on its own (issue 27: every answer
    says its source)."""
    src = p.source_json()
    came = "no answer" if src is None else f"from the {src}" if isinstance(src, str) else "mixed, field by field"
    own = []
    for name, est in (("network", p.network), ("measurement", p.measurement)):
        if est is not None:
            own.append(f"{name} alone n = {est.n_links if est.n_links is not None else 'none'}")
    return came + (f" ({', '.join(own)})" if own else "")


def run_demo(
    out: str | Path,
    model: str | Path | None = None,
    step: Callable[[int, str], None] = lambda i, what: None,
    force: bool = False,
) -> DemoResult:
    """Run the whole chain into `out`; `step(i, what)` announces each of the STEPS stages.

    `out` is one output (`spare_twin.output`): absent, empty or an earlier demo's; `force` replaces
    anything else, and only once the new demo is complete (it is built beside `out`, then swapped in)."""
    model = Path(model or default_model("predict"))
    check_demo(out, model, force)
    load_model(model)  # a bad checkpoint is refused now, not after minutes of work
    t0 = time.perf_counter()
    spec = DEMO_CHAIN
    with writing(out, DEMO, (model,), force) as tmp:
        step(
            1,
            f"printable object: {spec.n_links} moving links, "
            + ", ".join(f"{x:.0f}" for x in spec.link_lengths_mm)
            + " mm",
        )
        obj = build_object(spec, tmp / "object")

        step(2, "twin simulation: the training rig's 8 cameras")
        rig_rec = tmp / "sim_rig"
        render_recording(obj.root, rig_rec, RenderConfig(frames=RIG_FRAMES, seed=SEED))

        stages = iter(range(3, 6))
        real_rec = simulated_capture(
            obj.root, tmp, SensorCaptureConfig(seed=SEED), step=lambda what: step(next(stages), what)
        )

        step(6, "predict: the shipped model on the twin and on the capture")
        rig_pred = predict_recording(rig_rec, model, progress=False)

        step(7, "compare: twin fitted to the real cloud, rendered through the same cameras, both scored")
        result = compare(obj.root, real_rec, model=model, rrd=tmp / "compare.rrd", sim_dir=tmp / "sim_twin")
        # what the demo reports names the folder it is about to be in, not the one it is built in
        out = Path(out)

        def moved(p: Prediction) -> Prediction:
            return replace(p, recording=str(out / Path(p.recording).relative_to(tmp)))

        rig_pred = moved(rig_pred)
        result = replace(
            result,
            sim=moved(result.sim),
            real=moved(result.real),
            real_twin_aligned=moved(result.real_twin_aligned),
            sim_recording=out / "sim_twin",
            rrd=str(out / "compare.rrd"),
        )
        write_json_atomic(tmp / "compare.json", result.to_json())
    return DemoResult(
        out / "object", obj.urdf_path.name, out / "compare.rrd", rig_pred, result, time.perf_counter() - t0
    )
