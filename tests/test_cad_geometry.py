"""The printed parts, measured from the STL files that get printed."""

import json

import numpy as np
import pytest
import trimesh

from spare_twin.config import PartDims, sample_chain
from spare_twin.object.checks import hole_radius_mm, measured_pin_clearance_mm, rod_radius_mm
from spare_twin.object.parts import COUPON_CLEARANCES_MM, build_parts, clearance_coupon, coupon_hole_x_mm
from spare_twin.object.stl import to_trimesh


def load_stl(path) -> trimesh.Trimesh:
    return trimesh.load(path, file_type="stl", process=True)


def test_every_stl_is_one_closed_solid_flat_on_the_bed(object_dirs):
    for n, obj in object_dirs.items():
        stls = sorted(obj.root.glob("*.stl"))
        # base post, foot, n links, n pins, coupon
        assert len(stls) == 2 + 2 * n + 1
        for path in stls:
            mesh = load_stl(path)
            assert mesh.is_watertight, path
            assert mesh.volume > 0, path
            assert len(mesh.split(only_watertight=False)) == 1, path
            lo, hi = mesh.bounds
            assert abs(lo[2]) < 1e-4, f"{path} not on the bed"
            size = hi - lo
            assert size[0] <= 200 and size[1] <= 200 and size[2] <= 200, path


def test_measured_link_lengths_equal_configuration(object_dirs):
    for n, obj in object_dirs.items():
        L = obj.spec.link_lengths_mm
        t = obj.spec.parts.link_thickness_mm
        base = load_stl(obj.root / "link0_base.stl")
        # Base: table (the post's flat end, x = 0) to the first hole's axis.
        assert base.bounds[0][0] == pytest.approx(0.0, abs=1e-4)
        hole_x = _hole_centres_x(base, z=1.0)
        assert hole_x == pytest.approx([L[0]], abs=0.01)
        for k in range(1, n + 1):
            mesh = load_stl(obj.root / f"link{k}.stl")
            centres = _hole_centres_x(mesh, z=1.0)
            if k < n:
                assert centres == pytest.approx([0.0, L[k]], abs=0.01)
            else:  # last link: axis to tip
                assert centres == pytest.approx([0.0], abs=0.01)
                assert mesh.bounds[1][0] == pytest.approx(L[k], abs=0.01)
            assert mesh.bounds[1][2] == pytest.approx(t + obj.spec.parts.layer_gap_mm, abs=1e-4)


def _hole_centres_x(mesh, z):
    section = mesh.section(plane_origin=[0, 0, z], plane_normal=[0, 0, 1])
    planar, _ = section.to_2D(to_2D=np.eye(4))
    holes = [interior for poly in planar.polygons_full for interior in poly.interiors]
    return sorted(float(np.mean(np.asarray(h.coords)[:-1, 0])) for h in holes)


@pytest.mark.parametrize("clearance", [0.3, 0.15, 0.45])
def test_pin_clearance_measured_from_meshes_equals_configuration(clearance):
    spec = sample_chain(3, seed=1, parts=PartDims(pin_clearance_mm=clearance))
    parts = build_parts(spec)
    meshes = {p.name: to_trimesh(p.solid) for p in parts}
    for joint in range(1, 4):
        assert measured_pin_clearance_mm(spec, meshes, joint) == pytest.approx(clearance, abs=1e-4)
    # The pin is a press fit in the child: its hole is the pin's nominal diameter.
    child = meshes["link1"]
    assert hole_radius_mm(child, (0, 0), 1.0) == pytest.approx(spec.parts.pin_diameter_mm / 2, abs=1e-4)
    assert rod_radius_mm(meshes["pin_joint1"], (0, 0), 5.0) == pytest.approx(spec.parts.pin_diameter_mm / 2, abs=1e-4)


def test_pin_length_matches_the_stack_it_passes_through(object_dirs):
    spec = object_dirs[2].spec
    p = spec.parts
    pin = load_stl(object_dirs[2].root / "pin_joint1.stl")
    # Head flush in the parent's counterbore, tip flush with the child's far face.
    assert pin.bounds[1][2] == pytest.approx(2 * p.link_thickness_mm + p.layer_gap_mm, abs=1e-4)


def test_clearance_coupon_holes_step_through_the_range():
    p = PartDims()
    coupon = to_trimesh(clearance_coupon(p))
    assert coupon.is_watertight
    radii = [
        hole_radius_mm(coupon, (coupon_hole_x_mm(p, i), 0.0), p.link_thickness_mm / 2)
        for i in range(len(COUPON_CLEARANCES_MM))
    ]
    assert np.allclose(np.array(radii) - p.pin_diameter_mm / 2, COUPON_CLEARANCES_MM, atol=1e-4)


def test_print_report_lists_every_part(object_dirs):
    obj = object_dirs[4]
    report = json.loads((obj.root / "print_report.json").read_text())
    files = {e["file"] for e in report["parts"]}
    assert files == {p.name for p in obj.root.glob("*.stl")} - {"clearance_coupon.stl"}
    assert report["passed"] and all(report["checks"].values())
    assert report["pin_clearance_mm"]["measured_per_joint"] == pytest.approx([0.3] * 4, abs=1e-4)
    for e in report["parts"]:
        assert e["watertight"] and len(e["bbox_mm"]) == 3 and e["volume_mm3"] > 0


def test_walls_are_at_least_the_minimum(object_dirs):
    """Measured: the thinnest material around a joint hole, from a section of the parent link."""
    spec = object_dirs[2].spec
    p = spec.parts
    mesh = load_stl(object_dirs[2].root / "link1.stl")
    L = spec.link_lengths_mm[1]
    z_top = p.link_thickness_mm - 0.05  # inside the counterbore
    counterbore = hole_radius_mm(mesh, (L, 0.0), z_top)
    section = mesh.section(plane_origin=[0, 0, z_top], plane_normal=[0, 0, 1])
    outline_y = np.abs(np.asarray(section.vertices)[:, 1]).max()
    assert outline_y - counterbore >= spec.printer.min_wall_mm
    floor = p.link_thickness_mm - (p.pin_head_height_mm + p.counterbore_extra_mm)
    assert floor >= spec.printer.min_wall_mm


def test_parts_print_without_supports(object_dirs):
    """No surface faces downwards anywhere above the bed: nothing overhangs, nothing needs support."""
    for obj in (object_dirs[1], object_dirs[6]):
        for path in sorted(obj.root.glob("*.stl")):
            mesh = load_stl(path)
            down = mesh.face_normals[:, 2] < -1e-6
            heights = mesh.triangles[down][:, :, 2]
            assert down.any() and np.abs(heights).max() < 1e-4, f"{path.name} overhangs at z = {heights.max():.2f} mm"
