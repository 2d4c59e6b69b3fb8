"""The printable object: manifold3d parts with revolute pin joints (`parts`), their checks
(`checks`), STL export (`stl`), the chain's kinematics (`kinematics`), the URDF built from the very
same meshes (`urdf`), a preview render (`preview`), the object folder that holds them (`folder`,
whose `make_object` is `spare-twin object`; `files`: what it must hold, checked without reading a
mesh) and the build-time benchmark (`bench`).

Every part is modelled in its *print frame* (millimetres, flat on the bed at z = 0, no overhangs
that need support) and carries `T_link_part`, the rigid transform that places it in its URDF link's
frame. The STL files and the URDF therefore share one geometry.
"""
