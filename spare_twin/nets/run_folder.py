"""What a training run's folder may be (`train`'s `out_dir`): light to import (no torch), so
`spare-twin train` refuses a folder it would not write at once, not after 3-5 s of imports;
`nets.train` checks through the same functions."""

from __future__ import annotations

from pathlib import Path

#: What a run folder holds (and the temporaries of their atomic writes): a folder of these is a run.
#: samples-<split>.npz: the observed samples of the networks that observe theirs (`nets.profile_train`).
RUN_FILES = ("last.pt", "best.pt", "model.pt", "history.json", "learning_curve.png", "MODEL_CARD.md", "samples-")


def touches_data(out_dir: Path, data_dirs: list[Path]) -> Path | None:
    """The data folder the run folder is, is inside or holds (never written, force or not), or None."""
    out = Path(out_dir).resolve()
    for d in data_dirs:
        data = Path(d).resolve()
        if out == data or data in out.parents or out in data.parents:
            return Path(d)
    return None


def run_folder_problem(out_dir: Path, data_dirs: list[Path], resume: bool) -> str | None:
    """Why `out_dir` cannot take a new run (or, with `resume`, is no run to continue), or None."""
    out_dir = Path(out_dir)
    last_path = out_dir / "last.pt"
    touched = touches_data(out_dir, data_dirs)
    if touched is not None:
        return f"out_dir {out_dir}: is, is inside or holds the data folder {touched}; write the run elsewhere"
    if resume:
        return None if last_path.is_file() else f"resume: {last_path} does not exist (nothing to resume)"
    if last_path.exists():
        return f"out_dir {out_dir}: already holds a run (resume it, or write to another folder)"
    if out_dir.exists() and not out_dir.is_dir():
        return f"out_dir {out_dir}: exists and is not a folder"
    if out_dir.is_dir():
        other = [p.name for p in out_dir.iterdir() if not p.name.lstrip(".").startswith(RUN_FILES)]
        if other:
            return f"out_dir {out_dir}: not empty and not a training run (holds {other[0]}); write to a new folder"
    return None


def replaceable(out_dir: Path, data_dirs: list[Path]) -> bool:
    """A run folder problem that `force` may settle: any but touching the data folder."""
    return not touches_data(out_dir, data_dirs) and run_folder_problem(out_dir, data_dirs, resume=False) is not None


def refused_run_folder(out_dir: Path, data_dirs: list[Path], resume: bool, force: bool) -> str | None:
    """The run folder problem `train` refuses `out_dir` for (`force` settles any but touching the data
    folder, and not on `resume`), or None."""
    if force and not resume and replaceable(out_dir, data_dirs):
        return None
    return run_folder_problem(out_dir, data_dirs, resume)
