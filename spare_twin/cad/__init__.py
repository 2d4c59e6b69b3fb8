"""CAD for the printable object: manifold3d parts with revolute pin joints, checks, STL export.

Every part is modelled in its *print frame* (millimetres, flat on the bed at z = 0, no overhangs
that need support) and carries `T_link_part`, the rigid transform that places it in its URDF link's
frame. The STL files and the URDF therefore share one geometry.
"""

from spare_twin.cad.parts import Part, build_parts, clearance_coupon

__all__ = ["Part", "build_parts", "clearance_coupon"]
