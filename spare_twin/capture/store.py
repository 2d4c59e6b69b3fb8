"""Atomic updates of an existing recording (registration results, calibrated poses).

The new state is built in a temporary sibling folder whose images are hard links to the old ones
(no copy of the pictures), then renamed into place with `spare_twin.io.atomic_dir`; so a failure or
Ctrl-C at any point leaves the old recording exactly as it was.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

from spare_twin.io import atomic_dir, write_bytes_atomic
from spare_twin.recording import Recording


def _link_tree(src: Path, dst: Path, skip: set[str]) -> None:
    for dirpath, _dirnames, filenames in os.walk(src):
        rel = Path(dirpath).relative_to(src)
        (dst / rel).mkdir(parents=True, exist_ok=True)
        for name in filenames:
            relf = (rel / name).as_posix()
            if relf in skip or name.startswith("."):
                continue
            try:
                os.link(Path(dirpath) / name, dst / rel / name)
            except OSError:  # another file system, or links not allowed: copy instead
                shutil.copy2(Path(dirpath) / name, dst / rel / name)


def update_recording(root: str | Path, meta: dict, files: dict[str, bytes], remove: tuple[str, ...] = ()) -> Recording:
    """Replace `recording.json` by `meta` and write `files` (relative path -> bytes), all at once.

    Files not named keep their content (hard-linked); those in `remove` are left out. The result is opened and validated before
    it replaces the old folder.
    """
    root = Path(root)
    Recording.open(root)  # a clear error if it is not a recording at all
    with atomic_dir(root) as tmp:
        _link_tree(root, tmp, skip={"recording.json", *files, *remove})
        for rel, data in files.items():
            write_bytes_atomic(tmp / rel, data)
        write_bytes_atomic(tmp / "recording.json", (json.dumps(meta, indent=2) + "\n").encode())
        rec = Recording.open(tmp)
        rec.validate()
    return Recording.open(root)


def npy_bytes(array) -> bytes:
    import io

    import numpy as np

    b = io.BytesIO()
    np.save(b, np.asarray(array), allow_pickle=False)
    return b.getvalue()


class OpenEndedWriter:
    """A `RecordingWriter` for streams of unknown length (live sensors, .bag replay).

    Frames go to disk as they arrive (under the writer's temporary folder); `close(n)` fixes the
    frame count and timestamps and renames the recording into place. Used as a context manager, an
    exception leaves nothing at the destination. (Kept here, outside recording.py, because it only
    sets the count that the base class otherwise takes up front.)
    """

    def __init__(self, root, camera, fps: float, source: dict, depth_scale: float, max_frames: int = 10**7):
        from spare_twin.recording import RecordingWriter

        self._w = RecordingWriter(
            root, [camera], n_frames=1, fps=fps, source=source, depth_scale=depth_scale, timestamps_s=[0.0]
        )
        self.camera = camera.name
        self.count = 0
        self.timestamps_s: list[float] = []
        self.max_frames = max_frames

    def __enter__(self) -> OpenEndedWriter:
        self._w.__enter__()
        return self

    def add(self, color_rgb, depth_u16, timestamp_s: float) -> None:
        import cv2
        import numpy as np

        from spare_twin.io import encode_png

        png = encode_png(cv2.cvtColor(np.ascontiguousarray(color_rgb, np.uint8), cv2.COLOR_RGB2BGR))
        self._w.add_encoded(self.camera, self.count, png, depth_u16)
        self.timestamps_s.append(float(timestamp_s))
        self.count += 1

    def __exit__(self, exc_type, exc, tb):
        from spare_twin.errors import SpareTwinError

        if exc_type is None:
            if self.count == 0:
                exc_type, exc = SpareTwinError, SpareTwinError(f"{self._w.root}: no frames received; nothing written")
                self._w.__exit__(exc_type, exc, None)
                raise exc
            # a frame interrupted half-way (colour written, depth not) must not survive
            for kind in ("color", "depth"):
                for f in (self._w.tmp / "cameras" / self.camera / kind).glob("*.png"):
                    if int(f.stem) >= self.count:
                        f.unlink()
            t0 = self.timestamps_s[0]
            self._w.n_frames = self.count
            self._w.meta["frames"] = self.count
            self._w.meta["timestamps_s"] = [t - t0 for t in self.timestamps_s]
        return self._w.__exit__(exc_type, exc, tb)
