"""The object folder: everything `spare-twin object` writes for one chain, and its reader.

object.json          the configuration (ChainSpec) plus the derived joint layout
link0_base.stl ...   one binary STL per printable part, millimetres, flat for printing
clearance_coupon.stl a test bar for choosing the pin clearance before printing the object
<name>.urdf          the URDF twin whose visuals and collisions are those STLs
print_report.json    per part: file, bounding box, volume, watertight, checks
ASSEMBLY.md          print settings and assembly steps for this object
preview.png          the assembled object at a random pose, rendered from the URDF
"""

from __future__ import annotations

import dataclasses
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from spare_twin.config import DESIGN_CONTRACT_LENGTHS_KEY, LENGTHS_KEY, ChainSpec, design_walls_mm, sample_chain
from spare_twin.errors import SpareTwinError
from spare_twin.io import encode_png, read_json, write_bytes_atomic, write_json_atomic
from spare_twin.object import checks, kinematics
from spare_twin.object.files import OBJECT_FORMAT, object_files
from spare_twin.object.kinematics import joint_limits_rad, joint_origin, keepout_height_m
from spare_twin.object.parts import (
    CIRCLE_SEGMENTS,
    COUPON_CLEARANCES_MM,
    build_parts,
    clearance_coupon,
    pin_shaft_length_mm,
)
from spare_twin.object.preview import render_preview
from spare_twin.object.stl import stl_bytes, to_trimesh
from spare_twin.object.urdf import build_robot, joint_name, link_name, urdf_bytes
from spare_twin.output import writing


@dataclass(frozen=True)
class ObjectFolder:
    """A built object folder, as the simulation and comparison stages see it."""

    root: Path
    spec: ChainSpec
    urdf_path: Path

    @property
    def link_names(self) -> list[str]:
        return [link_name(k) for k in range(self.spec.n_links + 1)]

    @property
    def joint_names(self) -> list[str]:
        return [joint_name(k) for k in range(1, self.spec.n_links + 1)]

    @property
    def joint_limits_rad(self) -> np.ndarray:
        return joint_limits_rad(self.spec)

    @property
    def keepout_height_m(self) -> float:
        return keepout_height_m(self.spec)

    @property
    def printed_lengths_m(self) -> np.ndarray:
        """(n + 1,) link lengths of the printed object (metres), base first."""
        return kinematics.printed_lengths_m(self.spec)

    @property
    def link_half_width_m(self) -> float:
        return kinematics.link_half_width_m(self.spec)


def object_json(spec: ChainSpec) -> dict:
    limits = joint_limits_rad(spec)
    joints = [
        {
            "name": joint_name(k),
            "parent": link_name(k - 1),
            "child": link_name(k),
            "origin_xyz_m": joint_origin(spec, k)[:3, 3].tolist(),
            "axis": [0.0, 1.0, 0.0],
            "limits_rad": limits[k - 1].tolist(),
        }
        for k in range(1, spec.n_links + 1)
    ]
    derived = {
        "link_lengths_mm": list(spec.link_lengths_mm),
        "layer_pitch_mm": spec.layer_pitch_mm,
        "pin_shaft_length_mm": pin_shaft_length_mm(spec.parts),
        "keepout_height_m": keepout_height_m(spec),
        "joints": joints,
    }
    config = spec.to_dict()
    # DESIGN.md's object-folder contract: the paper-unit lengths under its key too (config.py says why)
    config[DESIGN_CONTRACT_LENGTHS_KEY] = config[LENGTHS_KEY]
    return {"format": OBJECT_FORMAT, **config, "derived": derived}


#: Tessellation of the simulation's copy of the parts: the same solids with 16-gon circles, which
#: pybullet's CPU renderer draws about twice as fast as the 64-gon printing meshes.
SIM_CIRCLE_SEGMENTS = 16


def _write_parts_and_urdf(spec: ChainSpec, folder: Path, circle_segments: int):
    parts = build_parts(spec, circle_segments)
    meshes = {p.name: to_trimesh(p.solid) for p in parts}
    files = {p.name: f"{p.name}.stl" for p in parts}
    for p in parts:
        write_bytes_atomic(folder / files[p.name], stl_bytes(meshes[p.name]))
    urdf_path = folder / f"{spec.name}.urdf"
    write_bytes_atomic(urdf_path, urdf_bytes(build_robot(spec, parts, meshes, files)))
    write_json_atomic(folder / "object.json", object_json(spec))
    return parts, meshes, files


def build_sim_twin(spec: ChainSpec, folder: str | Path, circle_segments: int = SIM_CIRCLE_SEGMENTS) -> ObjectFolder:
    """Just what the simulation loads (object.json, STLs, URDF), with a coarser tessellation.

    Use a fresh folder per object: pybullet caches URDFs and meshes by path.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    _write_parts_and_urdf(spec, folder, circle_segments)
    return load_object(folder, verify_meshes=False)  # just written from the solids: nothing to doubt


def build_object(
    spec: ChainSpec,
    out_dir: str | Path,
    preview: bool = True,
    progress=None,
    force: bool = False,
    inputs: tuple[str | Path | None, ...] = (),
) -> ObjectFolder:
    """Write the whole object folder under the output rule (`spare_twin.output.writing`): `out_dir` must be
    absent, empty or an earlier object folder (`force` replaces anything else but `inputs`, the files the
    spec was read from); on any error it is left as it was."""
    out_dir = Path(out_dir)
    step = progress or (lambda what: None)
    with writing(out_dir, "object", inputs=inputs, force=force) as tmp:
        step(BUILD_STEPS[0])
        parts, meshes, files = _write_parts_and_urdf(spec, tmp, CIRCLE_SEGMENTS)
        step(BUILD_STEPS[1])
        coupon = to_trimesh(clearance_coupon(spec.parts))
        write_bytes_atomic(tmp / "clearance_coupon.stl", stl_bytes(coupon))

        step(BUILD_STEPS[2])
        report = print_report(spec, parts, meshes, files, coupon)
        failed = [p["file"] for p in report["parts"] if not p["passed"]]
        if failed:
            raise SpareTwinError(f"parts fail the print checks: {', '.join(failed)}")
        write_json_atomic(tmp / "print_report.json", report)

        step(BUILD_STEPS[3])
        write_bytes_atomic(tmp / "ASSEMBLY.md", assembly_md(spec, report).encode())
        if preview:
            step(PREVIEW_STEP)
            rgb = render_preview(spec, tmp / f"{spec.name}.urdf", seed=spec.seed or 0)
            write_bytes_atomic(tmp / "preview.png", encode_png(rgb[:, :, ::-1].copy(), compression=6))
    return load_object(out_dir)


@dataclass(frozen=True)
class ObjectSummary:
    """What `make_object` built: the folder, whether its parts passed the print checks, its files."""

    folder: ObjectFolder
    print_checks_passed: bool
    files: tuple[str, ...]

    def to_json(self) -> dict:
        spec = self.folder.spec
        return {
            "out": str(self.folder.root),
            "n_links": spec.n_links,
            LENGTHS_KEY: list(spec.link_lengths_pu),
            "link_lengths_mm": [round(x, 3) for x in spec.link_lengths_mm],
            "print_scale": spec.print_scale,
            "urdf": self.folder.urdf_path.name,
            "print_checks_passed": self.print_checks_passed,
            "files": list(self.files),
        }


def object_spec(
    n_links: int | None = None,
    seed: int = 0,
    config: str | Path | None = None,
    print_scale: float | None = None,
    clearance_mm: float | None = None,
    bed_mm: tuple[float, float] | None = None,
    name: str | None = None,
) -> ChainSpec:
    """The chain to build: sampled from the paper's distribution (n_links, seed) or read from a
    configuration file (config), then with the given print settings replaced."""
    if (n_links is None) == (config is None):
        raise SpareTwinError("n_links, config: give exactly one (a sampled chain or a configuration file)")
    spec = ChainSpec.from_json_file(config) if config is not None else sample_chain(n_links, seed=seed)
    changes: dict = {}
    if print_scale is not None:
        changes["print_scale"] = print_scale
    if name is not None:
        changes["name"] = name
    if clearance_mm is not None:
        changes["parts"] = dataclasses.replace(spec.parts, pin_clearance_mm=clearance_mm)
    if bed_mm is not None:
        changes["printer"] = dataclasses.replace(spec.printer, bed_x_mm=bed_mm[0], bed_y_mm=bed_mm[1])
    return dataclasses.replace(spec, **changes) if changes else spec


def make_object(
    out_dir: str | Path,
    n_links: int | None = None,
    seed: int = 0,
    config: str | Path | None = None,
    print_scale: float | None = None,
    clearance_mm: float | None = None,
    bed_mm: tuple[float, float] | None = None,
    name: str | None = None,
    preview: bool = True,
    progress=None,
    force: bool = False,
) -> ObjectSummary:
    """`spare-twin object`: the chain of `object_spec` built into `out_dir` (`build_object`), summarised."""
    spec = object_spec(n_links, seed, config, print_scale, clearance_mm, bed_mm, name)
    obj = build_object(spec, out_dir, preview=preview, progress=progress, force=force, inputs=(config,))
    report = read_json(obj.root / "print_report.json")
    # hidden files (the output rule's marker) are bookkeeping, not part of what was made
    files = tuple(sorted(p.name for p in obj.root.iterdir() if p.is_file() and not p.name.startswith(".")))
    return ObjectSummary(obj, bool(report["passed"]), files)


#: The progress steps `build_object` reports, in order (the last one only with a preview).
BUILD_STEPS = ("modelling parts", "writing STL files", "checking printability", "writing assembly notes")
PREVIEW_STEP = "rendering preview"


def load_object(root: str | Path, verify_meshes: bool = True) -> ObjectFolder:
    """The object folder at `root`, its meshes verified (`verify_meshes`) before anything uses them:
    a truncated or swapped STL would otherwise render or compare as a wrong object without a word."""
    root = Path(root)
    files = object_files(root)
    if verify_meshes:
        verify_meshes_against_report(root, files.mesh_names)
    return ObjectFolder(root=root, spec=files.spec, urdf_path=files.urdf_path)


#: How far a part's mesh may be from what print_report.json measured (STL stores float32 coordinates).
BBOX_TOLERANCE_MM = 0.01
VOLUME_TOLERANCE = 1e-3


def verify_meshes_against_report(root: Path, links: list[str]) -> None:
    """Every part's STL loads, is watertight and is the part print_report.json describes (its bounding
    box and volume); without a report (a folder built by hand), the link meshes load and are watertight."""
    report_path = root / "print_report.json"
    expected: dict[str, dict] = {name: {} for name in links}
    if report_path.is_file():
        report = read_json(report_path)
        try:
            expected = {e["file"]: e for e in report["parts"] if isinstance(e["file"], str)}
            for e in expected.values():
                e["bbox_mm"], e["volume_mm3"] = [float(x) for x in e["bbox_mm"]], float(e["volume_mm3"])
        except (KeyError, TypeError, ValueError):
            raise SpareTwinError(f"{report_path}: not a print report (parts with file, bbox_mm, volume_mm3)") from None
        for name in links:
            if name not in expected:
                raise SpareTwinError(f"{report_path}: does not list {name}")
    for name, entry in expected.items():
        _verify_mesh(root / name, entry)


def _verify_mesh(path: Path, entry: dict) -> None:
    mesh = _load_stl(path)
    if not mesh.is_watertight:
        raise SpareTwinError(f"{path}: the mesh is not watertight (damaged or edited?)")
    if not entry:
        return
    size = mesh.bounds[1] - mesh.bounds[0]
    want = np.asarray(entry["bbox_mm"])
    if size.shape != want.shape or np.abs(size - want).max() > BBOX_TOLERANCE_MM:
        shown = " x ".join(f"{x:.1f}" for x in size)
        raise SpareTwinError(
            f"{path}: a {shown} mm part, not the {' x '.join(f'{x:.1f}' for x in want)} mm one print_report.json "
            "lists under this name (another part's file?)"
        )
    if abs(mesh.volume - entry["volume_mm3"]) > VOLUME_TOLERANCE * abs(entry["volume_mm3"]):
        raise SpareTwinError(
            f"{path}: volume {mesh.volume:.1f} mm^3, not the {entry['volume_mm3']:.1f} mm^3 print_report.json "
            "lists (another part's file?)"
        )


def _load_stl(path: Path) -> trimesh.Trimesh:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise SpareTwinError(f"{path}: cannot read ({exc.strerror})") from None
    # a binary STL says how many triangles follow: a file cut short is caught here, whatever a reader makes of it
    count = int.from_bytes(data[80:84], "little") if len(data) >= 84 else -1
    binary = not data.lstrip().startswith(b"solid") or len(data) == 84 + 50 * count
    if binary and len(data) != 84 + 50 * count:
        raise SpareTwinError(f"{path}: not a whole STL file ({len(data)} bytes; truncated or empty?)")
    try:
        mesh = trimesh.load(io.BytesIO(data), file_type="stl", force="mesh")
    except Exception as exc:  # trimesh raises what its parsers raise; any of it means "not a mesh we can use"
        raise SpareTwinError(f"{path}: not a readable STL ({type(exc).__name__})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise SpareTwinError(f"{path}: not a readable STL (no triangles)")
    return mesh


def print_report(spec, parts, meshes, files, coupon) -> dict:
    entries = [checks.part_report(spec, p, meshes[p.name], files[p.name]) for p in parts]
    measured = [checks.measured_pin_clearance_mm(spec, meshes, k) for k in range(1, spec.n_links + 1)]
    walls = design_walls_mm(spec.parts)
    min_wall = spec.printer.min_wall_mm
    c = spec.parts.pin_clearance_mm
    summary = {
        "fits_bed": all(e["checks"]["fits_bed"] for e in entries),
        "watertight": all(e["watertight"] for e in entries),
        "min_wall": min(walls.values()) >= min_wall - 1e-9,
        "pin_clearance": all(abs(mc - c) < 0.01 for mc in measured),
    }
    return {
        "object": spec.name,
        "print_scale": spec.print_scale,
        "bed_mm": [spec.printer.bed_x_mm, spec.printer.bed_y_mm, spec.printer.max_height_mm],
        "parts": entries,
        "walls_mm": {k: round(v, 4) for k, v in walls.items()},
        "min_wall_mm": min_wall,
        "pin_clearance_mm": {"configured": c, "measured_per_joint": [round(x, 5) for x in measured]},
        "coupon": {
            "file": "clearance_coupon.stl",
            "clearances_mm": list(COUPON_CLEARANCES_MM),
            "bbox_mm": [round(float(x), 4) for x in coupon.bounds[1] - coupon.bounds[0]],
            "watertight": bool(coupon.is_watertight),
        },
        "checks": summary,
        "passed": all(summary.values()) and all(e["passed"] for e in entries),
    }


def assembly_md(spec: ChainSpec, report: dict) -> str:
    p = spec.parts
    lines = [
        f"# Assembling {spec.name}",
        "",
        f"{spec.n_links} moving links on a base; print scale {spec.print_scale} m per paper metre.",
        "",
        "## Print",
        "",
        "PLA, 0.2 mm layers, 0.4 mm nozzle, 2 perimeters, 20 % infill, no supports. Every part lies flat",
        "as exported; print the pins standing on their heads. First print `clearance_coupon.stl` with one",
        f"pin: the holes are, from the notched end, {', '.join(f'{c:.2f}' for c in COUPON_CLEARANCES_MM)} mm of radial",
        f"clearance. This object uses {p.pin_clearance_mm} mm; if the pin does not turn freely in that hole,",
        "rebuild with `--clearance` set to the smallest hole it turns freely in.",
        "",
        "| file | colour | size (mm) |",
        "|---|---|---|",
    ]
    for e in report["parts"]:
        colour = spec.colors[e["link"]] if e["link"] is not None else "any"
        lines.append(f"| {e['file']} | {colour} | {' x '.join(f'{x:.1f}' for x in e['bbox_mm'])} |")
    lines += [
        "",
        "## Assemble",
        "",
        "1. Press `link0_base.stl` (the post) into the socket of `foot.stl` until it stands on the table.",
        "2. For each joint k = 1, 2, ...: lay link k with its spacer ring against the face of link k-1",
        "   that has no counterbore; push `pin_joint<k>` from the counterbore side through link k-1 into",
        "   link k until the head sits flush in the counterbore. The pin turns in link k-1 and is held",
        "   tight by link k (a drop of glue in link k's hole if it is loose).",
        "3. Check that every joint turns freely through its whole range.",
        "",
        "Link lengths (distance between pin axes; base: table to first axis; last: axis to tip), mm:",
        "",
        ", ".join(f"L{i} = {x:.2f}" for i, x in enumerate(spec.link_lengths_mm)),
        "",
    ]
    return "\n".join(lines)
