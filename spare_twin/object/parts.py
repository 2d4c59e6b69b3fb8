"""The printed parts of a SPARE chain.

Joint design (why): every link is a flat plate in its own layer along the joint axes, so no two
links can ever pass through each other and the plates print flat without supports. Joint k joins
link k-1 (parent) to link k (child) with a separate printed pin:

* the pin's head sinks into a counterbore on the parent's outer (-y) face, flush with it;
* its shaft turns in the parent's clearance hole (radial clearance `pin_clearance_mm`) and is
  pressed into the child's hole (`press_fit_mm`), ending flush with the child's far (+y) face;
* a spacer ring on the child, around its hole, holds the two plates `layer_gap_mm` apart, so they
  turn without rubbing; the head has `counterbore_extra_mm` of axial play, so the joint never binds.

Polygon holes circumscribe their nominal circle and pins inscribe theirs, so the smallest gap in the
printed joint is exactly the configured clearance.

Frames: the link frame has its origin on the link's proximal joint axis, in the plate's mid-plane;
+z runs along the link, +y along the joint axis (towards the child layers). For the base (link 0)
the origin is on the table under the post. Part (print) frames have +z up from the bed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import manifold3d as m3d
import numpy as np

from spare_twin.config import ChainSpec, PartDims, counterbore_depth_mm, counterbore_diameter_mm

CIRCLE_SEGMENTS = 64

#: Plate parts lie with their +y face on the bed: part x -> link z, part y -> link -x, part z -> link -y.
R_LINK_PLATE = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
#: Pins stand on their head: part z -> link +y (the insertion direction), part x -> link z.
R_LINK_PIN = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])


@dataclass(frozen=True)
class Part:
    """One printable part: a closed manifold solid in its print frame (mm)."""

    name: str
    """File stem, e.g. `link2`, `pin_joint3`, `foot`."""
    kind: str
    """"link", "base", "foot", "pin" or "coupon"."""
    link: int | None
    """The URDF link the part is fixed to (None for the coupon)."""
    solid: m3d.Manifold
    T_link_part_mm: np.ndarray
    """4x4 pose of the print frame in the link frame, millimetres."""


def _pose(R: np.ndarray, t_mm) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t_mm
    return T


def hole(radius_mm: float, height_mm: float, z0_mm: float = -1.0, segments: int = CIRCLE_SEGMENTS) -> m3d.Manifold:
    """A cylinder cutter whose polygon *circumscribes* the nominal circle (the hole is never smaller)."""
    r = radius_mm / math.cos(math.pi / segments)
    return m3d.Manifold.cylinder(height_mm, r, r, segments).translate((0.0, 0.0, z0_mm))


def rod(radius_mm: float, height_mm: float, segments: int = CIRCLE_SEGMENTS) -> m3d.Manifold:
    """A solid cylinder whose polygon is *inscribed* in the nominal circle (never larger)."""
    return m3d.Manifold.cylinder(height_mm, radius_mm, radius_mm, segments)


def _disc(radius_mm: float, x_mm: float, segments: int) -> m3d.CrossSection:
    return m3d.CrossSection.circle(radius_mm, segments).translate((x_mm, 0.0))


def _plate_outline(p: PartDims, length_mm: float, last: bool, segments: int) -> m3d.CrossSection:
    """Stadium from the proximal axis (x = 0) to the distal axis, or to the tip for the last link."""
    r = p.link_width_mm / 2
    end = max(length_mm - r, 0.0) if last else length_mm
    return m3d.CrossSection.batch_hull([_disc(r, 0.0, segments), _disc(r, end, segments)])


def _distal_joint_cut(p: PartDims, x_mm: float, segments: int) -> m3d.Manifold:
    """Clearance hole through the plate plus the counterbore for the pin head on the top (-y) face."""
    t = p.link_thickness_mm
    through = hole(p.pin_diameter_mm / 2 + p.pin_clearance_mm, t + 2.0, segments=segments)
    depth = counterbore_depth_mm(p)
    counterbore = hole(counterbore_diameter_mm(p) / 2, depth + 1.0, t - depth, segments)
    return (through + counterbore).translate((x_mm, 0.0, 0.0))


def moving_link(p: PartDims, length_mm: float, last: bool, segments: int = CIRCLE_SEGMENTS) -> m3d.Manifold:
    """Link plate: press-fit hole and spacer ring at the proximal axis, pin joint at the distal axis."""
    t = p.link_thickness_mm
    plate = _plate_outline(p, length_mm, last, segments).extrude(t)
    spacer = rod(p.spacer_ring_diameter_mm / 2, p.layer_gap_mm, segments).translate((0.0, 0.0, t))
    solid = plate + spacer
    solid -= hole(p.pin_diameter_mm / 2 + p.press_fit_mm, t + p.layer_gap_mm + 2.0, segments=segments)
    if not last:
        solid -= _distal_joint_cut(p, length_mm, segments)
    return solid


def base_post(p: PartDims, length_mm: float, segments: int = CIRCLE_SEGMENTS) -> m3d.Manifold:
    """The base: a flat-ended post from the table (x = 0) to the first joint axis (x = length)."""
    r = p.link_width_mm / 2
    outline = m3d.CrossSection.batch_hull(
        [m3d.CrossSection.square((1e-3, p.link_width_mm)).translate((0.0, -r)), _disc(r, length_mm, segments)]
    )
    return outline.extrude(p.link_thickness_mm) - _distal_joint_cut(p, length_mm, segments)


def foot(p: PartDims) -> m3d.Manifold:
    """A square plate with a socket boss that holds the base post upright; the post reaches the table.

    Modelled in the base link frame (z up, origin on the table at the post's axis line).
    """
    s = p.foot_size_mm
    plate = m3d.Manifold.cube((s, s, p.foot_thickness_mm)).translate((-s / 2, -s / 2, 0.0))
    # The post's cross-section in the base frame: link_width along x, thickness along y.
    hx = p.link_width_mm / 2 + p.socket_fit_mm
    hy = p.link_thickness_mm / 2 + p.socket_fit_mm
    w = p.socket_wall_mm
    top = p.foot_thickness_mm + p.socket_height_mm
    boss = m3d.Manifold.cube((2 * (hx + w), 2 * (hy + w), top)).translate((-(hx + w), -(hy + w), 0.0))
    socket = m3d.Manifold.cube((2 * hx, 2 * hy, top + 2.0)).translate((-hx, -hy, -1.0))
    return (plate + boss) - socket


def pin(p: PartDims, shaft_length_mm: float, segments: int = CIRCLE_SEGMENTS) -> m3d.Manifold:
    """Head down on the bed, shaft up, with a small lead-in chamfer at the tip for pressing in."""
    r = p.pin_diameter_mm / 2
    head = rod(p.pin_head_diameter_mm / 2, p.pin_head_height_mm, segments)
    chamfer = min(0.4, r / 4)
    shaft = rod(r, shaft_length_mm - chamfer, segments).translate((0.0, 0.0, p.pin_head_height_mm))
    tip = m3d.Manifold.cylinder(chamfer, r, r - chamfer, segments).translate(
        (0.0, 0.0, p.pin_head_height_mm + shaft_length_mm - chamfer)
    )
    return head + shaft + tip


def pin_shaft_length_mm(p: PartDims) -> float:
    """From under the flush head, through the parent, the gap and the child, to the child's far face."""
    return 2 * p.link_thickness_mm + p.layer_gap_mm - p.pin_head_height_mm


#: Radial clearances on the test coupon, mm (the default 0.3 sits in the middle).
COUPON_CLEARANCES_MM = (0.10, 0.15, 0.20, 0.25, 0.30, 0.35, 0.40, 0.50)


def clearance_coupon(p: PartDims) -> m3d.Manifold:
    """A bar with one hole per clearance in COUPON_CLEARANCES_MM, smallest next to the notched end.

    Print it with one pin; the smallest hole the pin turns freely in is the clearance to configure.
    """
    length = coupon_hole_x_mm(p, len(COUPON_CLEARANCES_MM))  # one hole pitch past the last hole
    width = p.link_width_mm + 4.0
    t = p.link_thickness_mm
    bar = m3d.Manifold.cube((length, width, t)).translate((0.0, -width / 2, 0.0))
    for i, c in enumerate(COUPON_CLEARANCES_MM):
        bar -= hole(p.pin_diameter_mm / 2 + c, t + 2.0).translate((coupon_hole_x_mm(p, i), 0.0, 0.0))
    # A V-notch in the end nearest the smallest clearance tells the holes' order.
    notch = m3d.CrossSection([[(0.0, -2.0), (2.5, 0.0), (0.0, 2.0), (-1.0, 0.0)]]).extrude(t + 2.0)
    return bar - notch.translate((0.0, 0.0, -1.0))


def coupon_hole_x_mm(p: PartDims, index: int) -> float:
    """Distance of the coupon's hole `index` from its notched end (holes a pin head plus 4 mm apart)."""
    return (p.pin_head_diameter_mm + 4.0) * (index + 1)


def build_parts(spec: ChainSpec, circle_segments: int = CIRCLE_SEGMENTS) -> list[Part]:
    """Every printable part of the object, in assembly order (base first).

    `circle_segments` only changes the tessellation: the simulation renders the same parts with
    fewer segments, which pybullet's CPU renderer draws about twice as fast.
    """
    seg = circle_segments
    p = spec.parts
    lengths = spec.link_lengths_mm
    t, pitch = p.link_thickness_mm, spec.layer_pitch_mm
    plate_offset = (0.0, t / 2, 0.0)  # the plate's bed face (+y) is half a thickness from the mid-plane
    parts = [
        Part("link0_base", "base", 0, base_post(p, lengths[0], seg), _pose(R_LINK_PLATE, plate_offset)),
        Part("foot", "foot", 0, foot(p), np.eye(4)),
    ]
    shaft = pin_shaft_length_mm(p)
    for k in range(1, spec.n_links + 1):
        last = k == spec.n_links
        parts.append(
            Part(f"link{k}", "link", k, moving_link(p, lengths[k], last, seg), _pose(R_LINK_PLATE, plate_offset))
        )
        # The pin head's outer face is flush with the parent's -y face, one pitch behind this link.
        parts.append(Part(f"pin_joint{k}", "pin", k, pin(p, shaft, seg), _pose(R_LINK_PIN, (0.0, -pitch - t / 2, 0.0))))
    return parts
