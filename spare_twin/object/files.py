"""The files an object folder must hold (`object_files`), checked without reading a mesh: light to
import (no trimesh), so `spare-twin compare` says "not an object folder" before it loads its stages;
`folder.load_object` checks the same way, then verifies the meshes."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from spare_twin.config import ChainSpec
from spare_twin.errors import SpareTwinError
from spare_twin.io import read_json

OBJECT_FORMAT = "spare-twin-object/1"


@dataclass(frozen=True)
class ObjectFiles:
    """What an object folder holds, found present (not yet read or verified)."""

    spec: ChainSpec
    urdf_path: Path
    mesh_names: list[str]
    """The link STLs, base first (`link0_base.stl`, `link1.stl`, ...)."""


def object_files(root: str | Path) -> ObjectFiles:
    """The object folder at `root`: its object.json read, its URDF and link STLs present; else a
    one-line error naming the folder or the file."""
    root = Path(root)
    if not root.is_dir():
        raise SpareTwinError(f"{root}: not a folder")
    meta_path = root / "object.json"
    if not meta_path.is_file():
        raise SpareTwinError(f"{root}: not an object folder (no object.json)")
    meta = read_json(meta_path)
    if not isinstance(meta, dict) or meta.get("format") != OBJECT_FORMAT:
        raise SpareTwinError(f"{meta_path}: not a {OBJECT_FORMAT} file")
    spec = ChainSpec.from_dict(meta, source=str(meta_path))
    urdf_path = root / f"{spec.name}.urdf"
    if not urdf_path.is_file():
        raise SpareTwinError(f"{urdf_path}: missing")
    mesh_names = ["link0_base.stl"] + [f"link{k}.stl" for k in range(1, spec.n_links + 1)]
    for name in mesh_names:
        if not (root / name).is_file():
            raise SpareTwinError(f"{root / name}: missing")
    return ObjectFiles(spec, urdf_path, mesh_names)
