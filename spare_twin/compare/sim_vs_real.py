"""Sim vs real for one printed object: `spare-twin compare`.

1. The real recording is registered (poses, TSDF fusion, the object on the table) unless it already is.
2. Articulated registration fits the object's URDF twin to the fused real cloud: base pose on the
   table and joint angles (`spare_twin.compare.articulated`).
3. The twin, posed so, is rendered through the very cameras of the real recording: a simulated
   recording with the same intrinsics, poses and frame count, but no sensor noise.
4. The same network runs on both recordings through the same path (`predict_recording`), the real
   views placed by camera poses re-aligned onto the fitted twin, and both predictions are scored
   against the configuration that was printed.
"""

from __future__ import annotations

import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from spare_twin import __version__
from spare_twin.config import COLORS, LABEL_SLOTS


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
        from spare_twin.compare.articulated import FitConfig

        return {"compare": asdict(self), "fit": asdict(FitConfig()), "version": __version__}


def padded(lengths) -> np.ndarray:
    out = np.zeros(LABEL_SLOTS)
    if lengths:
        out[: len(lengths)] = lengths
    return out


def score(truth: dict, pred: dict) -> dict:
    """Count right or wrong, E_L with the paper's end-to-end rule, and per-link errors (paper units)."""
    from spare_twin.nets.metrics import length_errors

    n_true, n_pred = truth["n_links"], pred.get("n_links")
    if pred.get("link_lengths_m") is None or n_pred is None:
        return {"count_correct": n_pred == n_true, "E_L": None, "per_link_m": None}
    t, p = padded(truth["link_lengths_m"]), padded(pred["link_lengths_m"])
    e_l = float(length_errors(t[None], p[None], [n_true], [n_pred])[0])
    return {
        "count_correct": bool(n_pred == n_true),
        "E_L": e_l,
        "per_link_m": [float(x) for x in (p - t)[: max(n_true, n_pred) + 1]],
    }


def render_twin_through(
    obj, joint_angles_rad, T_world_base: np.ndarray, real, out_dir: Path, cfg: CompareConfig
) -> None:
    """The posed twin seen by the real recording's cameras (frames, intrinsics, poses), no noise."""
    from tqdm import tqdm

    from spare_twin.recording import Camera, RecordingWriter
    from spare_twin.sim.twin import Twin

    T_base_world = np.linalg.inv(T_world_base)
    cameras, poses = [], {}
    for c in real.cameras:
        per_frame = np.stack([T_base_world @ real.T_world_camera(c.name, f) for f in range(real.n_frames)])
        poses[c.name] = per_frame
        cameras.append(Camera(c.name, c.width, c.height, c.K, None, "per_frame"))
    source = {"kind": "sim", "sensor_model": "pybullet-tinyrenderer", "twin_of": str(real.root)}
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
            link_lengths_m=np.asarray(obj.spec.link_lengths_pu),
            n_links=np.asarray(n),
            print_scale=np.asarray(obj.spec.print_scale),
        )


def depth_views(real, T_object_world: np.ndarray, count: int) -> list:
    """`count` depth frames spread over every posed camera of `real`, posed in the object frame."""
    return [view for _, view in _posed_depth_views(real, T_object_world, count)]


def aligned_camera_poses(obj, real, fit, T_world_object: np.ndarray) -> dict:
    """{(camera, frame): T_world_camera} for every posed frame of `real`, re-aligned onto the fitted
    twin (`depth_fit.DepthScorer.align_views`). Whole-frame registration leaves the cameras a few
    millimetres and a degree or two apart; the network's views, fused in its voxel grid, want them
    consistent with each other."""
    from spare_twin.compare.depth_fit import DepthScorer

    keyed = _posed_depth_views(real, np.linalg.inv(T_world_object), real.n_frames)
    with DepthScorer(obj, [view for _, view in keyed]) as scorer:
        for _ in range(2):  # the second round takes the last millimetre (as in the fit)
            scorer.align_views(fit.params)
        return {key: T_world_object @ view.T_cloud_camera for (key, _), view in zip(keyed, scorer.views)}


def _posed_depth_views(real, T_object_world: np.ndarray, count: int) -> list:
    from spare_twin.compare.depth_fit import DepthView

    out = []
    for c in real.cameras:
        if c.poses == "unknown":
            continue
        for f in np.unique(np.linspace(0, real.n_frames - 1, count).round().astype(int)):
            T = T_object_world @ real.T_world_camera(c.name, int(f))
            out.append(((c.name, int(f)), DepthView(real.depth_m(c.name, int(f)), np.asarray(c.K), T)))
    return out


def compare(object_dir, real_dir, model=None, rrd=None, sim_dir=None, cfg: CompareConfig = CompareConfig()) -> dict:
    from spare_twin.capture.pipeline import fuse_recording, register_recording
    from spare_twin.compare.articulated import fit_articulated
    from spare_twin.nets.predict import predict_recording
    from spare_twin.object.folder import load_object
    from spare_twin.recording import Recording

    obj = load_object(object_dir)
    real = Recording.open(real_dir)
    if not real.meta.get("registration"):
        print("compare: registering the real recording (poses, fusion, object)", file=sys.stderr)
        register_recording(real.root, find="require", progress=True)
        real = Recording.open(real_dir)
    points, colors, T_world_object = fuse_recording(real, object_only=True)
    T_object_world = np.linalg.inv(T_world_object)
    cloud_obj = points @ T_object_world[:3, :3].T + T_object_world[:3, 3]

    print("compare: fitting the URDF twin to the real cloud", file=sys.stderr)
    fit = fit_articulated(obj, cloud_obj, views=depth_views(real, T_object_world, cfg.fit_views))
    T_world_base = T_world_object @ fit.T_world_base

    sim_dir = Path(sim_dir) if sim_dir else Path(real.root).with_name(Path(real.root).name + "_sim_twin")
    render_twin_through(obj, fit.joint_angles_rad, T_world_base, real, sim_dir, cfg)

    print("compare: running the network on the real and the sim recording", file=sys.stderr)
    # Both sides in the same object frame: the sim twin stands at its origin by construction, the real
    # views are placed by the registered base pose. `real_estimated_frame` is what `predict` alone
    # makes of the recording, with its own frame estimate and yaw hypotheses.
    sim_pred = predict_recording(sim_dir, model, progress=False, return_input=rrd is not None)
    real_pred = predict_recording(
        real.root,
        model,
        progress=False,
        return_input=rrd is not None,
        T_world_base=T_world_base,
        camera_poses=aligned_camera_poses(obj, real, fit, T_world_object),
    )
    own_pred = predict_recording(real.root, model, progress=False)
    truth = {"n_links": obj.spec.n_links, "link_lengths_m": list(obj.spec.link_lengths_pu)}
    gt = real.ground_truth()
    truth["joint_angles_rad"] = None if gt is None else [float(a) for a in np.asarray(gt["joint_angles_rad"])[0]]

    keep = ("n_links", "link_lengths_m", "probabilities", "joint_angles_rad")
    result = {
        "truth": truth,
        "sim": {k: sim_pred.get(k) for k in keep},
        "real": {k: real_pred.get(k) for k in keep},
        "real_estimated_frame": {k: own_pred.get(k) for k in keep + ("input", "yaw_deg")},
        "registration": {
            "joint_angles_rad": [float(a) for a in fit.joint_angles_rad],
            "T_world_base": T_world_base.tolist(),
            "rmse_m": fit.rmse_m,
            "inlier_fraction": fit.inlier_fraction,
            "depth_error_m": fit.depth_error_m,
            "camera_corrections_mm_deg": [list(c) for c in fit.view_corrections],
        },
        "errors": {
            "sim": score(truth, sim_pred),
            "real": score(truth, real_pred),
            "real_estimated_frame": score(truth, own_pred),
            "joint_angles_deg": None,
        },
        "sim_recording": str(sim_dir),
        "model": real_pred.get("model"),
        "settings": cfg.settings(),
    }
    if truth["joint_angles_rad"] is not None:
        diff = np.asarray(fit.joint_angles_rad) - np.asarray(truth["joint_angles_rad"])
        result["errors"]["joint_angles_deg"] = [float(np.degrees(abs((d + np.pi) % (2 * np.pi) - np.pi))) for d in diff]
    if rrd is not None:
        _write_rrd(rrd, result, obj, cloud_obj, colors, fit, real, Recording.open(sim_dir), sim_pred, real_pred, cfg)
        result["rrd"] = str(rrd)
    return result


def _write_rrd(rrd, result, obj, cloud_obj, colors, fit, real, sim, sim_pred, real_pred, cfg) -> None:
    from spare_twin.compare.articulated import twin_link_meshes
    from spare_twin.compare.rerun_log import ComparisonLog, log_comparison
    from spare_twin.object.kinematics import forward_kinematics

    # Everything in the twin's base frame: the cloud moves by the fitted base pose.
    T_base_object = np.linalg.inv(fit.T_world_base)
    cloud = cloud_obj @ T_base_object[:3, :3].T + T_base_object[:3, 3]
    poses = forward_kinematics(obj.spec, fit.joint_angles_rad)
    meshes = []
    for k, mesh in enumerate(twin_link_meshes(obj)):
        mesh.apply_transform(poses[k])
        meshes.append(
            (np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.uint32), COLORS[obj.spec.colors[k]])
        )
    log_comparison(
        rrd,
        ComparisonLog(
            result=result,
            real_cloud=cloud,
            real_cloud_rgb=colors,
            twin_meshes=meshes,
            real_input=real_pred["network_input"],
            sim_input=sim_pred["network_input"],
            real_rec=real,
            sim_rec=sim,
        ),
        every=cfg.rrd_every,
    )


def summary_row(name: str, prediction: dict, errors: dict | None = None) -> str:
    """One line of a sim-vs-real summary: count, lengths (paper units) and, when scored, right/WRONG and E_L."""
    lengths = ", ".join(f"{x:.3f}" for x in (prediction.get("link_lengths_m") or []))
    tail = ""
    if errors is not None and errors.get("E_L") is not None:
        tail = f"  count {'right' if errors['count_correct'] else 'WRONG'}, E_L {errors['E_L']:.4f}"
    return f"  {name:<26s} n = {prediction['n_links']}  lengths [{lengths}]{tail}"


SUMMARY_SIDES = {"truth": "truth", "sim": "sim", "real": "real", "real_estimated_frame": "real, predict's own frame"}


def format_summary(result: dict, names: dict[str, str] = SUMMARY_SIDES) -> str:
    lines = [
        summary_row(name, result[side], None if side == "truth" else result["errors"][side])
        for side, name in names.items()
        if result.get(side) is not None
    ]
    ja = result["errors"].get("joint_angles_deg")
    if ja is not None:
        lines.append("  joint angles from registration: error " + ", ".join(f"{a:.1f}" for a in ja) + " deg")
    return "\n".join(lines)
