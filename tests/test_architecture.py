"""The layering and the style rules hold: import-linter's contracts, ruff (lint and format), no
function-local imports of the project's own modules in the library, and nobody reaches into a
recording's private parts."""

import ast
import subprocess
import sys
from pathlib import Path

from conftest import REPO

BIN = Path(sys.executable).parent
LIBRARY = REPO / "spare_twin"
#: Where the lazy import of library modules is the point: `spare-twin --help` must stay instant.
COMMAND_LAYER = (LIBRARY / "cli.py", LIBRARY / "commands", LIBRARY / "__main__.py")


def _run(*argv):
    return subprocess.run([str(BIN / argv[0]), *argv[1:]], cwd=REPO, capture_output=True, text=True)


def test_import_linter_contracts_are_kept():
    res = _run("lint-imports")
    assert res.returncode == 0, res.stdout[-4000:] + res.stderr[-2000:]
    assert "0 broken" in res.stdout


def test_ruff_lint_and_format_are_clean():
    lint = _run("ruff", "check", "spare_twin", "tests")
    assert lint.returncode == 0, lint.stdout[-4000:]
    fmt = _run("ruff", "format", "--check", "spare_twin", "tests")
    assert fmt.returncode == 0, fmt.stdout[-4000:]


def _library_files():
    for path in sorted(LIBRARY.rglob("*.py")):
        if not any(path == p or p in path.parents for p in COMMAND_LAYER):
            yield path


def test_library_imports_its_own_modules_at_the_top():
    local = []
    for path in _library_files():
        tree = ast.parse(path.read_text(), str(path))
        for fn in ast.walk(tree):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for node in ast.walk(fn):
                if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("spare_twin"):
                    local.append(f"{path.relative_to(REPO)}:{node.lineno} {node.module}")
                elif isinstance(node, ast.Import) and any(a.name.startswith("spare_twin") for a in node.names):
                    local.append(f"{path.relative_to(REPO)}:{node.lineno}")
    assert not local, "function-local imports of project modules:\n" + "\n".join(local)


def test_predict_does_not_import_the_object_and_dataset_stages():
    """`predict` loads a network and reads a recording: the mesh libraries the object stage builds
    with (trimesh, networkx, rtree: about 1 s of every `predict` process) stay out of it."""
    probe = (
        "import sys, spare_twin.commands.predict, spare_twin.predict.run;"
        "print(sorted(m for m in ('trimesh', 'networkx', 'rtree', 'spare_twin.dataset.build') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_nobody_reaches_into_a_recordings_private_parts():
    recording = {LIBRARY / "recording.py", *(LIBRARY / "recording").glob("*.py")}
    private = {"_poses", "_checked", "_w", "_ctx", "_finish", "_write_png"}
    offenders = []
    for path in [*LIBRARY.rglob("*.py"), *(REPO / "tests").glob("*.py")]:
        if path in recording:
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Attribute) and node.attr in private:
                offenders.append(f"{path.relative_to(REPO)}:{node.lineno} .{node.attr}")
    assert not offenders, "\n".join(offenders)


def test_the_library_never_drives_the_command_line():
    for path in _library_files():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom):
                assert not (node.module or "").startswith(("spare_twin.cli", "spare_twin.commands")), path


def test_open3d_is_imported_through_its_loader_without_its_plotly_viewer():
    """The library imports open3d only through `spare_twin.open3d_loader`: that defers open3d's plotly
    viewer (plotly and dash, most of open3d's import time) to its first use, where it is the real one."""
    bare = []
    for path in _library_files():
        if path.name == "open3d_loader.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            if any(name == "open3d" or name.startswith("open3d.") for name in names):
                bare.append(f"{path.relative_to(REPO)}:{node.lineno}")
    assert not bare, "open3d imported past spare_twin.open3d_loader:\n" + "\n".join(bare)
    probe = (
        "import sys; from spare_twin.open3d_loader import quiet_open3d; o3d = quiet_open3d();"
        "print(sorted(m for m in ('plotly', 'dash') if m in sys.modules));"
        "cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]]));"
        "fig = o3d.visualization.get_plotly_fig([cloud]);"
        "print(type(fig).__module__.split('.')[0], sorted(m for m in ('plotly', 'dash') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    assert out.splitlines() == ["[]", "plotly ['dash', 'plotly']"], out
