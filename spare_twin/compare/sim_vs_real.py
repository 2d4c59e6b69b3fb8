"""Sim vs real for one printed object: `spare-twin compare`.

1. The real recording is registered (poses, TSDF fusion, the object on the table) unless it already is.
2. Articulated registration fits the object's URDF twin to the fused real cloud: base pose on the
   table and joint angles (`spare_twin.compare.articulated`).
3. The twin, posed so, is rendered through the very cameras of the real recording: a simulated
   recording with the same intrinsics, poses and frame count, but no sensor noise.
4. The same network runs on both recordings through the same path (`predict_recording`) and both
   predictions are scored against the configuration that was printed. The real side (`real`) is
   `predict` on the real recording alone, exactly as a user runs it, told the parts the object was
   printed with (`predict --parts`): what the user printed, never its lengths.
5. A diagnostic (`real_twin_aligned`): the network once more on the real recording, its cameras
   re-aligned onto the fitted printed twin and its base frame taken from the fit. It needs the true
   object, so it measures what the capture path costs, not what `predict` can do. The profile
   network (the default) reads neither a placed base nor placed cameras: for it the diagnostic is the
   real answer itself, and is not run twice.
"""

from __future__ import annotations

import os
import sys
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from spare_twin import __version__
from spare_twin.capture.pipeline import fuse_recording, register_recording
from spare_twin.compare.articulated import ArticulatedFit, FitConfig, fit_articulated
from spare_twin.compare.depth_fit import DepthScorer, DepthView, transformed
from spare_twin.compare.inputs import SIM_TWIN, check_compare
from spare_twin.compare.rerun_log import ComparisonLog, log_comparison
from spare_twin.compare.result import Comparison, Truth
from spare_twin.errors import SpareTwinError
from spare_twin.nets import checkpoint as ckpt
from spare_twin.object.folder import ObjectFolder, load_object
from spare_twin.object.kinematics import printed_lengths_m
from spare_twin.predict.images import capture_refusal
from spare_twin.predict.run import predict_recording
from spare_twin.recording import Camera, Recording, RecordingWriter
from spare_twin.sim.twin import Twin


@dataclass(frozen=True)
class CompareConfig:
    """Settings of `compare`."""

    sim_near_m: float = 0.02
    sim_far_m: float = 3.0
    rrd_every: int = 1
    """Log every n-th frame of the two recordings to the .rrd."""
    fit_views: int = 20
    """Depth frames of the real recording, spread over it, that the articulated fit renders and compares."""

    def settings(self) -> dict:
        """Everything that shapes a comparison besides its inputs and model: a batch reuses a
        finished comparison only when these match."""
        return {"compare": asdict(self), "fit": asdict(FitConfig()), "version": __version__}


def render_twin_through(
    obj: ObjectFolder,
    joint_angles_rad,
    T_world_base: np.ndarray,
    real: Recording,
    out_dir: Path,
    cfg: CompareConfig,
    inputs: tuple = (),
    force: bool = False,
) -> None:
    """The posed twin seen by the real recording's cameras (frames, intrinsics, poses), no noise;
    `T_world_base` is the twin's base pose in the real recording's world. `out_dir` is an output of
    kind SIM_TWIN made from `inputs` (`spare_twin.output`)."""
    T_base_world = np.linalg.inv(T_world_base)
    cameras, poses = [], {}
    for c in real.cameras:
        T_world_camera = real.camera_poses(c.name)
        if T_world_camera is None:
            raise SpareTwinError(f"{real.root}: camera {c.name} has no poses to render the twin through")
        poses[c.name] = np.stack([T_base_world @ T for T in T_world_camera])
        cameras.append(Camera(c.name, c.width, c.height, c.K, None, "per_frame"))
    # relative to the twin's recording, so it stays true when a whole folder (the demo's) moves
    twin_of = os.path.relpath(os.path.abspath(real.root), os.path.abspath(out_dir))
    source = {"kind": "sim", "sensor_model": "pybullet-tinyrenderer", "twin_of": twin_of}
    with (
        Twin() as twin,
        RecordingWriter(
            out_dir,
            cameras,
            real.n_frames,
            real.fps,
            source,
            object_config=obj.spec.to_dict(),
            rig=None,
            timestamps_s=list(real.timestamps_s),
            kind=SIM_TWIN,
            inputs=inputs,
            force=force,
        ) as rec,
    ):
        twin.load(obj)
        twin.set_joints(joint_angles_rad)
        for f in tqdm(range(real.n_frames), desc="sim twin", unit="frame", file=sys.stderr, leave=False):
            for c in cameras:
                frame = twin.render(
                    poses[c.name][f], c.K, c.width, c.height, cfg.sim_near_m, cfg.sim_far_m, segmentation=True
                )
                rec.add_frame(c.name, f, frame.rgb, frame.depth_m, frame.segmentation, T_world_camera=poses[c.name][f])
        n = obj.spec.n_links
        rec.set_ground_truth(
            joint_angles_rad=np.tile(np.asarray(joint_angles_rad, np.float64), (real.n_frames, 1)),
            link_lengths_pu=np.asarray(obj.spec.link_lengths_pu),
            n_links=np.asarray(n),
            print_scale=np.asarray(obj.spec.print_scale),
        )


#: The fused object must stand at least this share of the printed base's height: lower, the
#: segmenter kept only a fragment of the chain (thin links fused apart from each other).
FRAGMENT_HEIGHT_SHARE = 0.8
#: Scene points this high above the table can belong to the object (the segmenter's cut, metres).
ABOVE_TABLE_M = 0.008
#: ... and this far beyond the chain's length from the found object (metres).
REACH_MARGIN_M = 0.02


def object_cloud(real: Recording, obj: ObjectFolder) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points (N, 3) in the object frame, colours (N, 3), T_world_object) of the registered object.

    The printed base is a vertical post of known height, so an object cloud lower than most of it is
    a fragment (the segmenter split the thin chain): then the fit gets every scene point above the
    table within the chain's length of the fragment, which holds the whole chain wherever it lies."""
    points, colors, T_world_object = fuse_recording(real, object_only=True)
    T_object_world = np.linalg.inv(T_world_object)
    cloud = transformed(points, T_object_world)
    lengths_m = printed_lengths_m(obj.spec)
    if len(cloud) and cloud[:, 2].max() >= FRAGMENT_HEIGHT_SHARE * lengths_m[0]:
        return cloud, colors, T_world_object
    scene, scene_colors, _ = fuse_recording(real, object_only=False)
    scene = transformed(scene, T_object_world)
    reach = float(lengths_m.sum()) + REACH_MARGIN_M
    centre = cloud[:, :2].mean(axis=0) if len(cloud) else np.zeros(2)
    keep = (
        (scene[:, 2] > ABOVE_TABLE_M) & (scene[:, 2] < reach) & (np.linalg.norm(scene[:, :2] - centre, axis=1) < reach)
    )
    print(
        f"compare: the registered object is {cloud[:, 2].max() if len(cloud) else 0.0:.3f} m high, lower than "
        f"the printed base ({lengths_m[0]:.3f} m): fitting every point above the table within "
        f"{reach:.2f} m of it ({int(keep.sum())} points)",
        file=sys.stderr,
    )
    return scene[keep], scene_colors[keep], T_world_object


def depth_views(real: Recording, T_object_world: np.ndarray, count: int) -> list[DepthView]:
    """`count` depth frames spread over every posed camera of `real`, posed in the object frame."""
    return [view for _, view in _posed_depth_views(real, T_object_world, count)]


def fit_view_keys(real: Recording, count: int) -> list[tuple[str, int]]:
    """(camera, frame) of each of `depth_views(real, ..., count)`, in its order."""
    return [key for key, _ in _posed_depth_views(real, np.eye(4), count, read=False)]


def aligned_camera_poses(
    obj: ObjectFolder, real: Recording, fit: ArticulatedFit, T_world_object: np.ndarray, fitted: dict | None = None
) -> dict:
    """{(camera, frame): T_world_camera} for every posed frame of `real`, re-aligned onto the fitted
    twin (`depth_fit.DepthScorer.align_views`). Whole-frame registration leaves the cameras a few
    millimetres and a degree or two apart; the network's views, fused in its voxel grid, want them
    consistent with each other. `fitted` ({(camera, frame): T_object_camera}) are frames the fit
    has aligned already (`ArticulatedFit.view_poses`): they are kept, the others aligned here."""
    fitted = fitted or {}
    keyed = _posed_depth_views(real, np.linalg.inv(T_world_object), real.n_frames)
    todo = [(key, view) for key, view in keyed if key not in fitted]
    out = {key: T_world_object @ T for key, T in fitted.items()}
    if todo:
        with DepthScorer(obj, [view for _, view in todo]) as scorer:
            for _ in range(2):  # the second round takes the last millimetre (as in the fit)
                scorer.align_views(fit.params)
            out.update({key: T_world_object @ view.T_cloud_camera for (key, _), view in zip(todo, scorer.views)})
    return {key: out[key] for key, _ in keyed}


def _posed_depth_views(real: Recording, T_object_world: np.ndarray, count: int, read: bool = True) -> list:
    """[((camera, frame), DepthView)] of `count` frames spread over each posed camera (views None
    without `read`)."""
    out = []
    for c in real.cameras:
        poses = real.camera_poses(c.name)
        if poses is None:
            continue
        for f in np.unique(np.linspace(0, real.n_frames - 1, count).round().astype(int)):
            T = T_object_world @ poses[f]
            view = DepthView(real.depth_m(c.name, int(f)), np.asarray(c.K), T) if read else None
            out.append(((c.name, int(f)), view))
    return out


def compare(
    object_dir: str | Path,
    real_dir: str | Path,
    model: str | Path | None = None,
    rrd: str | Path | None = None,
    sim_dir: str | Path | None = None,
    cfg: CompareConfig = CompareConfig(),
    force: bool = False,
) -> Comparison:
    """Sim vs real for the printed object in `object_dir` and its recording `real_dir` (see the module
    doc); the twin's recording goes to `sim_dir` (default `<real_dir>_sim_twin` beside it), the Rerun
    log to `rrd` when given. Both are outputs (`spare_twin.output`: `force` replaces what is not an
    earlier one); every input and output is checked before anything is written, the real recording's
    registration included."""
    model = model or ckpt.default_model("predict")
    checked = check_compare(object_dir, real_dir, model, rrd, sim_dir, force)
    real, sim_dir, inputs = checked.real, checked.sim_dir, checked.inputs
    obj = load_object(object_dir)  # verifies the meshes: a broken STL would fit and render a wrong twin
    _, net, ck = ckpt.load_model(model)  # a bad checkpoint is refused now, not after minutes of work
    refusal = None if net.arch == "profile" else capture_refusal(real, ck["meta"].get("rig"), str(model), net.mode)
    if refusal is not None:  # the real side would be refused after the registration and the fit
        raise SpareTwinError(refusal)
    timings: dict[str, float] = {}
    clock = _Clock(timings)
    if real.registration is None:
        print("compare: registering the real recording (poses, fusion, object)", file=sys.stderr)
        with clock("registration"):
            register_recording(real.root, find="require", progress=True)
        real = Recording.open(real_dir)
    with clock("fusion"):
        cloud_obj, colors, T_world_object = object_cloud(real, obj)
    T_object_world = np.linalg.inv(T_world_object)

    print("compare: fitting the URDF twin to the real cloud", file=sys.stderr)
    with clock("articulated fit"):
        fit = fit_articulated(obj, cloud_obj, views=depth_views(real, T_object_world, cfg.fit_views))
    fitted = dict(zip(fit_view_keys(real, cfg.fit_views), fit.view_poses))
    T_world_base = T_world_object @ fit.T_object_base

    with clock("sim twin"):
        render_twin_through(obj, fit.joint_angles_rad, T_world_base, real, sim_dir, cfg, inputs, force)

    print("compare: running the network on the real and the sim recording", file=sys.stderr)
    with clock("predict"):
        # The real side is `predict` on the recording alone: nothing from the object folder or the fit
        # but the parts it was printed with (what a user says with `predict --parts`), never its lengths.
        real_pred = predict_recording(real.root, model, progress=False, parts=obj.spec.parts)
        # The sim twin stands at its recording's origin by construction.
        sim_pred = predict_recording(sim_dir, model, progress=False, parts=obj.spec.parts)
    if net.arch == "profile":  # it reads no placed base or cameras: the diagnostic is the real answer itself
        aligned_pred = real_pred
    else:
        with clock("twin-aligned diagnostic"):
            aligned_pred = predict_recording(
                real.root,
                model,
                progress=False,
                T_world_base=T_world_base,
                camera_poses=aligned_camera_poses(obj, real, fit, T_world_object, fitted),
                parts=obj.spec.parts,
            )
    gt = real.ground_truth()
    truth = Truth(
        obj.spec.n_links,
        tuple(obj.spec.link_lengths_pu),
        None if gt is None else tuple(float(a) for a in np.asarray(gt["joint_angles_rad"])[0]),
    )
    result = Comparison(truth, sim_pred, real_pred, aligned_pred, fit, T_world_object, sim_dir, cfg.settings())
    if rrd is not None:
        with clock("rrd"):
            _write_rrd(
                rrd, result, obj, cloud_obj, colors, real, Recording.open(sim_dir), cfg, (*inputs, sim_dir), force
            )
        result = replace(result, rrd=str(rrd))
    return replace(result, timings_s=timings)


class _Clock:
    """`with clock(stage):` adds the stage's wall-clock seconds to `timings[stage]`."""

    def __init__(self, timings: dict[str, float]):
        self.timings = timings

    @contextmanager
    def __call__(self, stage: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.timings[stage] = self.timings.get(stage, 0.0) + time.perf_counter() - t0


def _write_rrd(
    rrd,
    result: Comparison,
    obj: ObjectFolder,
    cloud_obj,
    colors,
    real: Recording,
    sim: Recording,
    cfg: CompareConfig,
    inputs: tuple,
    force: bool,
) -> None:
    fit = result.fit
    # Everything in the twin's base frame: the cloud moves by the fitted base pose.
    T_base_object = np.linalg.inv(fit.T_object_base)
    cloud = cloud_obj @ T_base_object[:3, :3].T + T_base_object[:3, 3]
    log_comparison(
        rrd,
        ComparisonLog(
            result=result.to_json(),
            real_cloud=cloud,
            real_cloud_rgb=colors,
            twin_meshes=[],  # the twin is the object's URDF, through Rerun's URDF support
            real_input=result.real.network_input,
            sim_input=result.sim.network_input,
            real_twin_aligned_input=result.real_twin_aligned.network_input,
            real_rec=real,
            sim_rec=sim,
            urdf_path=obj.urdf_path,
        ),
        every=cfg.rrd_every,
        inputs=inputs,
        force=force,
    )
