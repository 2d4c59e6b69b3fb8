"""How long a 6-link object takes to build: the geometry alone, the whole object folder, and the
whole `spare-twin object` command in a new process (what a user waits for)."""

from __future__ import annotations

import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from spare_twin.config import sample_chain
from spare_twin.errors import SpareTwinError
from spare_twin.object.folder import build_object
from spare_twin.object.parts import build_parts
from spare_twin.object.stl import to_trimesh
from spare_twin.validate import check_whole


@dataclass(frozen=True)
class ObjectBench:
    """Median seconds per 6-link object over `objects` seeds."""

    objects: int
    geometry_s: float
    object_folder_s: float
    whole_cli_s: float
    python_startup_s: float
    cli_over_geometry: float

    def to_json(self) -> dict:
        return asdict(self)


def bench_object(repeats: int = 5) -> ObjectBench:
    """Time `repeats` 6-link objects (seeds 0..repeats-1) three ways, and a bare interpreter start."""
    check_whole("repeats", repeats)
    geometry, folder, cli = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(repeats):
            spec = sample_chain(6, seed=seed)
            t0 = time.perf_counter()
            meshes = [to_trimesh(p.solid) for p in build_parts(spec)]
            geometry.append(time.perf_counter() - t0)
            if not all(m.is_watertight for m in meshes):
                raise SpareTwinError(f"seed {seed}: a part is not watertight")
            t0 = time.perf_counter()
            build_object(spec, Path(tmp) / f"lib{seed}")
            folder.append(time.perf_counter() - t0)
            argv = ["object", "--links", "6", "--seed", str(seed), "--out", str(Path(tmp) / f"cli{seed}")]
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "spare_twin.cli", *argv], check=True, capture_output=True)
            cli.append(time.perf_counter() - t0)
        # Baseline in the same run: a bare interpreter that only imports the package's CLI.
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import spare_twin.cli"], check=True)
        startup = time.perf_counter() - t0
    med = statistics.median
    return ObjectBench(
        objects=repeats,
        geometry_s=round(med(geometry), 4),
        object_folder_s=round(med(folder), 4),
        whole_cli_s=round(med(cli), 4),
        python_startup_s=round(startup, 4),
        cli_over_geometry=round(med(cli) / med(geometry), 2),
    )
