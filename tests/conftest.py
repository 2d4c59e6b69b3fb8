from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def object_dirs(tmp_path_factory):
    """Built object folders for n = 1..6 (one seed each), shared by the geometry and URDF tests."""
    from spare_twin.config import sample_chain
    from spare_twin.object.folder import build_object

    root = tmp_path_factory.mktemp("objects")
    return {n: build_object(sample_chain(n, seed=100 + n), root / f"n{n}", preview=(n == 3)) for n in range(1, 7)}


def run_cli(argv, capsys):
    """Run `spare-twin ARGV` in-process; returns (exit code, stdout, stderr)."""
    from spare_twin.cli import main

    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err
