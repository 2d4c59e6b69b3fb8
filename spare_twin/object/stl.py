"""Manifold -> trimesh conversion and deterministic binary STL bytes."""

from __future__ import annotations

import struct

import manifold3d as m3d
import numpy as np
import trimesh

STL_HEADER = b"spare-twin binary STL, millimetres".ljust(80, b" ")


def to_trimesh(solid: m3d.Manifold) -> trimesh.Trimesh:
    mesh = solid.to_mesh()
    vertices = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(mesh.tri_verts, dtype=np.int64)
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False)


def stl_bytes(mesh: trimesh.Trimesh) -> bytes:
    """Binary STL with a fixed header, so the same mesh always gives the same bytes."""
    tris = np.asarray(mesh.triangles, dtype=np.float32)
    normals = np.asarray(mesh.face_normals, dtype=np.float32)
    record = np.zeros(len(tris), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    record["n"] = normals
    record["v"] = tris
    return STL_HEADER + struct.pack("<I", len(tris)) + record.tobytes()
