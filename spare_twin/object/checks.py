"""Printability checks and measurements taken from the part meshes themselves."""

from __future__ import annotations

import numpy as np
import trimesh

from spare_twin.config import ChainSpec, counterbore_depth_mm
from spare_twin.object.parts import Part


def hole_radius_mm(mesh: trimesh.Trimesh, center_xy, z_mm: float) -> float:
    """Inscribed radius of the hole around `center_xy`, from a horizontal section at height z.

    The distance from the axis to the nearest section edge is the largest pin that fits there.
    """
    segments = _section_segments(mesh, z_mm)
    return float(_segment_distances(segments, np.asarray(center_xy, float)).min())


def rod_radius_mm(mesh: trimesh.Trimesh, center_xy, z_mm: float) -> float:
    """Largest distance from the axis to a rod's section at height z (the pin's outer radius)."""
    segments = _section_segments(mesh, z_mm)
    return float(np.linalg.norm(segments.reshape(-1, 2) - np.asarray(center_xy, float), axis=1).max())


def _section_segments(mesh: trimesh.Trimesh, z_mm: float) -> np.ndarray:
    lines = trimesh.intersections.mesh_plane(mesh, plane_normal=[0, 0, 1], plane_origin=[0, 0, z_mm])
    if len(lines) == 0:
        raise ValueError(f"no section at z = {z_mm} mm")
    return np.asarray(lines)[:, :, :2]


def _segment_distances(segments: np.ndarray, p: np.ndarray) -> np.ndarray:
    a, b = segments[:, 0], segments[:, 1]
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-30), 0, 1)
    return np.linalg.norm(a + t[:, None] * ab - p, axis=1)


def measured_pin_clearance_mm(spec: ChainSpec, meshes: dict[str, trimesh.Trimesh], joint: int) -> float:
    """Radial clearance of joint k: parent's hole (inscribed) minus the pin shaft (circumscribed)."""
    p = spec.parts
    parent = "link0_base" if joint == 1 else f"link{joint - 1}"
    length = spec.link_lengths_mm[joint - 1]
    # Below the counterbore, the parent's hole is the clearance hole.
    z_hole = (p.link_thickness_mm - counterbore_depth_mm(p)) / 2
    hole = hole_radius_mm(meshes[parent], (length, 0.0), z_hole)
    shaft = rod_radius_mm(meshes[f"pin_joint{joint}"], (0.0, 0.0), p.pin_head_height_mm + 1.0)
    return hole - shaft


def part_report(spec: ChainSpec, part: Part, mesh: trimesh.Trimesh, file: str) -> dict:
    """One entry of print_report.json: measured size, volume and the checks it passes."""
    pr = spec.printer
    lo, hi = mesh.bounds
    size = hi - lo
    footprint = sorted(size[:2])
    bed = sorted((pr.bed_x_mm, pr.bed_y_mm))
    bodies = len(mesh.split(only_watertight=False))
    checks = {
        "watertight": bool(mesh.is_watertight),
        "single_solid": bodies == 1,
        "positive_volume": bool(mesh.volume > 0),
        "flat_on_bed": bool(abs(lo[2]) < 1e-6),
        "fits_bed": bool(footprint[0] <= bed[0] and footprint[1] <= bed[1] and size[2] <= pr.max_height_mm),
    }
    return {
        "file": file,
        "kind": part.kind,
        "link": part.link,
        "bbox_mm": [round(float(x), 4) for x in size],
        "volume_mm3": round(float(mesh.volume), 3),
        "watertight": checks["watertight"],
        "checks": checks,
        "passed": all(checks.values()),
    }
