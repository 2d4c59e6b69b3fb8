"""preview.png: the assembled object at a random pose, rendered from its URDF with pybullet."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spare_twin.config import ChainSpec
from spare_twin.object.kinematics import forward_kinematics, printed_lengths_m, sample_pose


def render_preview(
    spec: ChainSpec, urdf_path: str | Path, width: int = 800, height: int = 600, seed: int = 0
) -> np.ndarray:
    """uint8 (H, W, 3) RGB. Deterministic for the same spec, URDF and seed (CPU TinyRenderer)."""
    import pybullet as pb

    angles = sample_pose(spec, np.random.default_rng(seed))
    poses = forward_kinematics(spec, angles)
    client = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(urdf_path), useFixedBase=True, physicsClientId=client)
        for k, angle in enumerate(angles):
            pb.resetJointState(body, k, float(angle), physicsClientId=client)
        table = pb.createVisualShape(
            pb.GEOM_BOX, halfExtents=[0.4, 0.4, 0.002], rgbaColor=[0.78, 0.74, 0.68, 1], physicsClientId=client
        )
        pb.createMultiBody(baseVisualShapeIndex=table, basePosition=[0, 0, -0.002], physicsClientId=client)
        origins = poses[:, :3, 3]
        lengths = printed_lengths_m(spec)
        tips = np.array([p[:3, 3] + p[:3, 2] * lengths[k] for k, p in enumerate(poses)])
        pts = np.vstack([origins, tips, [[0, 0, 0]]])
        target = (pts.min(0) + pts.max(0)) / 2
        extent = float(np.linalg.norm(pts.max(0) - pts.min(0)))
        view = pb.computeViewMatrixFromYawPitchRoll(
            cameraTargetPosition=target.tolist(),
            distance=max(extent, 0.1) * 1.6,
            yaw=35.0,
            pitch=-20.0,
            roll=0.0,
            upAxisIndex=2,
        )
        proj = pb.computeProjectionMatrixFOV(fov=40.0, aspect=width / height, nearVal=0.01, farVal=5.0)
        _, _, rgba, _, _ = pb.getCameraImage(
            width,
            height,
            view,
            proj,
            renderer=pb.ER_TINY_RENDERER,
            lightDirection=[1.0, -1.0, 2.0],
            shadow=1,
            physicsClientId=client,
        )
    finally:
        pb.disconnect(client)
    return np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[:, :, :3]
