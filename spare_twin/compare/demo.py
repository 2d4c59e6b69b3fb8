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
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from spare_twin.capture.simulated import SensorCaptureConfig, simulated_capture
from spare_twin.compare.result import Comparison, summary_row
from spare_twin.compare.sim_vs_real import compare
from spare_twin.config import ChainSpec
from spare_twin.nets.predict import Prediction, predict_recording
from spare_twin.object.folder import build_object
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


@dataclass(frozen=True)
class DemoResult:
    """What the demo made and what it found."""

    object_dir: Path
    urdf_name: str
    rrd: Path
    rig_prediction: Prediction
    """The shipped model on the training rig's render of the twin."""
    comparison: Comparison
    seconds: float

    def summary(self) -> str:
        """The demo's report: true vs sim vs real, in paper units."""
        c, rig = self.comparison, self.rig_prediction
        lines = [
            f"spare-twin demo finished in {self.seconds:.0f} s (paper units, base first)",
            *c.summary_rows({"truth": "true (printed)"}),
            summary_row("sim, training rig", rig.n_links, rig.link_lengths_pu, c.truth.score(rig)),
            *c.summary_rows(
                {
                    "sim": "sim, same cameras",
                    "real": "real (sensor capture)",
                    "real_estimated_frame": "real, predict's own frame",
                }
            ),
            "  joint angles from articulated registration, error vs truth: "
            + ", ".join(f"{a:.1f}" for a in c.joint_angle_errors_deg)
            + " deg",
            f"  printable files: {self.object_dir}/ (STLs, {self.urdf_name}, ASSEMBLY.md, preview.png)",
            f"  Rerun recording: {self.rrd}  (open with `rerun {self.rrd}`)",
        ]
        return "\n".join(lines)


def run_demo(
    out: str | Path, model: str | Path | None = None, step: Callable[[int, str], None] = lambda i, what: None
) -> DemoResult:
    """Run the whole chain into `out`; `step(i, what)` announces each of the STEPS stages."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    spec = DEMO_CHAIN

    step(
        1,
        f"printable object: {spec.n_links} moving links, "
        + ", ".join(f"{x:.0f}" for x in spec.link_lengths_mm)
        + " mm",
    )
    obj = build_object(spec, out / "object")

    step(2, "twin simulation: the training rig's 8 cameras")
    rig_rec = out / "sim_rig"
    render_recording(obj.root, rig_rec, RenderConfig(frames=RIG_FRAMES, seed=SEED))

    stages = iter(range(3, 6))
    real_rec = simulated_capture(
        obj.root, out, SensorCaptureConfig(seed=SEED), step=lambda what: step(next(stages), what)
    )

    step(6, "predict: the shipped model on the twin and on the capture")
    rig_pred = predict_recording(rig_rec, model, progress=False)

    step(7, "compare: twin fitted to the real cloud, rendered through the same cameras, both scored")
    rrd = out / "compare.rrd"
    result = compare(obj.root, real_rec, model=model, rrd=rrd, sim_dir=out / "sim_twin")
    return DemoResult(obj.root, obj.urdf_path.name, rrd, rig_pred, result, time.perf_counter() - t0)
