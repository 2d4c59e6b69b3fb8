"""`CaptureEffects` applied to one render: the hooks `render_recording` calls.

`EffectsRun` holds what one capture drew (the print's perturbation, the dark links' return, the
principal-point offset, the clutter count) and applies each effect at its place in the render:
the object folder it loads, the intrinsics, the hand-held path, the desk, every clean depth image,
the poses the recording keeps, and what the ground truth and the source record. With no effect on,
every hook returns its input unchanged and draws nothing, so a plain render keeps its bytes.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from spare_twin.config import ChainSpec
from spare_twin.object.folder import ObjectFolder
from spare_twin.sim.active_sensor import (
    DEFAULT_BASELINE_M,
    SENSOR_BASELINE_M,
    dark_dropout,
    flying_pixels,
    shadow_mask,
)
from spare_twin.sim.effects import NO_EFFECTS, CaptureEffects, effect_rng
from spare_twin.sim.handheld import HandheldPath
from spare_twin.sim.print_physics import draw_perturbation, perturbed_object
from spare_twin.sim.rig import axis_angle
from spare_twin.sim.scene import ClutterConfig

#: The image width the effects' pixel sizes are given at.
REF_WIDTH_PX = 640


class EffectsRun:
    """The effects of one capture (seeded by the render's seed)."""

    def __init__(
        self,
        effects: CaptureEffects,
        seed: int,
        spec: ChainSpec,
        width: int,
        sensor: str | None = None,
        empty: bool = False,
    ):
        self.effects = effects if effects is not None else NO_EFFECTS
        self.seed = seed
        self.spec = spec
        self.width = width
        fx = self.effects
        self.print = None
        if (fx.joint_play or fx.print_error) and not empty:
            self.print = draw_perturbation(spec.n_links, fx, seed)
        self.baseline_m = fx.baseline_m
        if self.baseline_m is None:
            self.baseline_m = SENSOR_BASELINE_M.get(sensor or "", DEFAULT_BASELINE_M)
        self.dark_return = None
        self.dark_labels = np.zeros(0, np.uint8)
        if fx.dark_plastic:
            self.dark_return = float(effect_rng(seed, "dark_plastic").uniform(*fx.dark_return))
            self.dark_labels = np.asarray(
                [k + 1 for k, c in enumerate(spec.colors) if c in fx.dark_colors], dtype=np.uint8
            )
        self.principal_offset_px = np.zeros(2)
        if fx.principal_point:
            limit = fx.principal_offset_px * width / REF_WIDTH_PX
            self.principal_offset_px = effect_rng(seed, "principal_point").uniform(-limit, limit, size=2)
        self.clutter_drawn = 0
        if fx.clutter:
            lo, hi = fx.clutter_count
            self.clutter_drawn = int(effect_rng(seed, "clutter").integers(lo, hi + 1))

    @property
    def active(self) -> bool:
        return self.effects.active

    @property
    def needs_labels(self) -> bool:
        """Whether the depth hooks need each pixel's link (dark plastic)."""
        return self.dark_return is not None and len(self.dark_labels) > 0

    # -- the object -------------------------------------------------------------------------------
    @contextmanager
    def object_folder(self, obj: ObjectFolder) -> Iterator[ObjectFolder]:
        """The object to load: `obj` itself, or a perturbed copy in a fresh temporary folder (a unique
        path, as pybullet caches URDFs and meshes by path), removed afterwards."""
        if self.print is None:
            yield obj
            return
        tmp = tempfile.mkdtemp(prefix="spare-twin-print-")
        try:
            yield perturbed_object(obj, self.print, tmp)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)

    def link_poses(self, T_world_link: np.ndarray) -> np.ndarray:
        """Where each link's geometry is (the frames a renderer reports, times what the print moved)."""
        if self.print is None:
            return T_world_link
        return T_world_link @ self.print.W_link_geometry

    # -- the camera -------------------------------------------------------------------------------
    def intrinsics(self, K: np.ndarray) -> np.ndarray:
        if not self.effects.principal_point:
            return K
        K = np.array(K, dtype=np.float64, copy=True)
        K[:2, 2] += self.principal_offset_px
        return K

    def handheld_path(self, path: HandheldPath) -> HandheldPath:
        fx = self.effects
        if not fx.hand:
            return path
        return dataclasses.replace(
            path, radius_wander_m=fx.radius_wander_m, height_wander_m=fx.height_wander_m, roll_deg=fx.roll_deg
        )

    def recorded_pose(self, T_world_camera: np.ndarray, frame: int) -> np.ndarray:
        """The pose a tracker reports for `frame`: the true one turned and moved a little."""
        fx = self.effects
        if not fx.pose_error:
            return T_world_camera
        rng = effect_rng(self.seed, "pose_error", frame)
        axis = rng.normal(size=3)
        angle = math.radians(rng.normal(scale=fx.pose_error_deg))
        T = np.array(T_world_camera, dtype=np.float64, copy=True)
        T[:3, :3] = axis_angle(axis / np.linalg.norm(axis), angle) @ T[:3, :3]
        T[:3, 3] += rng.normal(scale=fx.pose_error_mm / 1000.0, size=3)
        return T

    # -- the desk ---------------------------------------------------------------------------------
    def clutter_config(self, count: int) -> ClutterConfig:
        """`count` items 12 cm out (the plain desk), or with clutter on at least the drawn number, as
        close as `clutter_gap_m` to the chain."""
        if not self.effects.clutter:
            return ClutterConfig(count=count)
        return ClutterConfig(count=max(count, self.clutter_drawn), r_min_m=0.06, margin_m=self.effects.clutter_gap_m)

    # -- the sensor -------------------------------------------------------------------------------
    def depth(self, depth_m: np.ndarray, labels: np.ndarray | None, K: np.ndarray, camera: int, frame: int):
        """A clean depth image as the active sensor reads it (before its noise model)."""
        fx = self.effects
        if not (fx.shadows or fx.flying_pixels or fx.dark_plastic):
            return depth_m
        clean = depth_m
        d = depth_m
        if fx.flying_pixels:
            band = max(int(round(fx.flying_band_px * depth_m.shape[-1] / REF_WIDTH_PX)), 1)
            d = flying_pixels(d, effect_rng(self.seed, "flying_pixels", camera, frame), fx.flying_prob, band)
        if fx.shadows:
            d = np.where(shadow_mask(clean, float(K[0, 0]), self.baseline_m), 0.0, d).astype(np.float32)
        if self.needs_labels and labels is not None:
            rng = effect_rng(self.seed, "dark_plastic", camera, frame)
            d = dark_dropout(d, labels, self.dark_labels, self.dark_return, rng)
        return d

    # -- what the recording keeps -----------------------------------------------------------------
    def source(self) -> dict:
        """The effects and what was drawn, for the recording's source."""
        drawn: dict = {}
        if self.print is not None:
            drawn["print"] = self.print.to_dict()
        if self.effects.shadows:
            drawn["baseline_m"] = self.baseline_m
        if self.dark_return is not None:
            drawn["dark_return"] = round(self.dark_return, 6)
            drawn["dark_links"] = [int(k) - 1 for k in self.dark_labels]
        if self.effects.principal_point:
            drawn["principal_offset_px"] = np.round(self.principal_offset_px, 6).tolist()
        if self.effects.clutter:
            drawn["clutter_count"] = self.clutter_drawn
        return {**self.effects.to_dict(), "drawn": drawn}

    def ground_truth(self) -> dict[str, np.ndarray]:
        """Arrays for ground_truth.npz: the print's perturbation (the nominal configuration stays as is)."""
        if self.print is None:
            return {}
        p = self.print
        return {
            "effects_W_link_geometry": p.W_link_geometry,
            "effects_tilt_deg": p.tilt_deg,
            "effects_shift_mm": p.shift_mm,
            "effects_scale": np.asarray(p.scale),
            "effects_level_deg": np.asarray(p.level_deg),
        }
