"""Importers: public RGB-D layouts into a recording (`spare_twin.recording`).

Layouts (`import_folder(src, layout, out)`; `spare-twin capture import SRC --layout ...`):

- ``7scenes``  7-Scenes / tsdf-fusion: ``frame-NNNNNN.color.png|jpg``, ``frame-NNNNNN.depth.png``
  (uint16 mm; 65535 = no reading in 7-Scenes), optional ``frame-NNNNNN.pose.txt`` (4x4
  camera-to-world), an intrinsics file (``intrinsics.K.txt`` / ``camera-intrinsics.txt``) or
  ``ImportOptions.K``. Depth scale 0.001.
- ``tum``  TUM RGB-D: ``rgb.txt`` / ``depth.txt`` (timestamp + file) with ``rgb/`` and ``depth/``,
  associated by nearest timestamp; optional ``groundtruth.txt`` (tx ty tz qx qy qz qw). Also the bare
  pair naming ``N.png`` + ``N_depth.png``. Depth scale 1/5000. Intrinsics from ``ImportOptions.K``.
- ``open3d``  the folder Open3D's RealSense recorder / ``RSBagReader.save_frames`` writes:
  ``color/*.jpg|png``, ``depth/*.png``, ``camera_intrinsic.json`` or ``intrinsic.json``.
- ``bag``  a RealSense ``.bag`` file, every frameset in order (``spare_twin.capture.bag``).

Depth is copied as the sensor's own integers with the sensor's scale (never re-quantised); colour
PNGs are copied byte for byte when already 8-bit RGB. Every frame is checked: matching colour and
depth, equal sizes, readable images, non-empty depth and a plausible depth scale.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spare_twin.capture.bag import BagReader
from spare_twin.capture.checks import positive, whole
from spare_twin.capture.frames import check_depth
from spare_twin.capture.layouts import LAYOUTS, LISTERS, FrameFiles, Source
from spare_twin.capture.record import stream_to_recording
from spare_twin.errors import SpareTwinError
from spare_twin.io import encode_png, read_png
from spare_twin.output import check_output
from spare_twin.recording import Camera, Recording, RecordingWriter
from spare_twin.validate import check_pose

#: The command whose output an imported recording is (its output marker).
IMPORT = "capture import"


@dataclass(frozen=True)
class ImportOptions:
    """User overrides for an import; None means "from the source, or the layout's default"."""

    K: np.ndarray | None = None
    """3x3 intrinsics (pixels), overriding any intrinsics file."""
    depth_scale: float | None = None
    """metres per depth unit, overriding the layout's default."""
    fps: float | None = None
    """frame rate (Hz) when the source has no timestamps (default 30)."""
    max_frames: int | None = None
    """import at most this many frames (after `stride`)."""
    stride: int = 1
    """keep every stride-th frame."""
    progress: bool = True

    def __post_init__(self):
        if self.K is not None:
            K = np.asarray(self.K, dtype=np.float64)
            if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
                raise SpareTwinError("K: must be a finite 3x3 intrinsics matrix with positive focal lengths")
        if self.depth_scale is not None:
            positive("depth_scale", self.depth_scale, upper=1.0)
        if self.fps is not None:
            positive("fps", self.fps)
        whole("stride", self.stride, 1)
        if self.max_frames is not None:
            whole("max_frames", self.max_frames, 1)


# -- writing ------------------------------------------------------------------------------------


def _read_color(path: Path) -> tuple[np.ndarray, bytes | None]:
    """Decoded BGR uint8 image and, when the file is already an 8-bit RGB PNG, its bytes to copy."""
    import cv2

    data = path.read_bytes() if path.is_file() else None
    if data is None:
        raise SpareTwinError(f"{path}: no such file")
    if not data:  # OpenCV asserts on an empty buffer
        raise SpareTwinError(f"{path}: empty file (0 bytes), not an image")
    try:
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        img = None
    if img is None:
        raise SpareTwinError(f"{path}: not a readable image (corrupt or truncated?)")
    if img.dtype != np.uint8:
        raise SpareTwinError(f"{path}: colour must be 8-bit, got {img.dtype}")
    is_png = data[:8] == b"\x89PNG\r\n\x1a\n"
    if img.ndim == 3 and img.shape[2] == 3 and is_png:
        return img, data
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return img, None


def _read_depth(path: Path, invalid_value: int | None) -> np.ndarray:
    if path.is_file() and path.stat().st_size == 0:  # OpenCV would also log a warning of its own
        raise SpareTwinError(f"{path}: empty file (0 bytes), not an image")
    d = read_png(path)
    if d.dtype != np.uint16 or d.ndim != 2:
        raise SpareTwinError(f"{path}: depth must be a single-channel 16-bit PNG, got {d.dtype} with shape {d.shape}")
    if invalid_value is not None:
        d = np.where(d == invalid_value, np.uint16(0), d)
    return d


def import_folder(
    src: str | Path, layout: str, out: str | Path, opts: ImportOptions = ImportOptions(), force: bool = False
):
    """Import `src` in `layout` into a recording at `out`; returns the opened Recording.

    `out` follows the output rule (`spare_twin.output`): absent, empty or an earlier import, unless
    `force`; never the source, inside it or around it.
    """
    src = Path(src)
    if layout == "bag":
        return import_bag(src, out, opts, force=force)
    if layout not in LISTERS:
        raise SpareTwinError(f"layout {layout!r}: expected one of {', '.join(LAYOUTS)}")
    if not src.is_dir():
        raise SpareTwinError(f"{src}: not a folder")
    return write_source(LISTERS[layout](src), out, opts, inputs=(src,), force=force)


def _select(frames: list[FrameFiles], opts: ImportOptions) -> list[FrameFiles]:
    frames = frames[:: opts.stride]
    return frames if opts.max_frames is None else frames[: opts.max_frames]


def _frame(f: FrameFiles, source: Source, size: tuple[int, int], depth_scale: float):
    """A source frame decoded and checked: (BGR colour, its PNG bytes when copyable, raw depth)."""
    h, w = size
    bgr, raw_png = _read_color(f.color)
    if bgr.shape[:2] != (h, w):
        raise SpareTwinError(f"{f.color}: size {bgr.shape[1]}x{bgr.shape[0]} differs from the first frame ({w}x{h})")
    depth = _read_depth(f.depth, source.depth_invalid_value)
    if depth.shape != (h, w):
        raise SpareTwinError(
            f"{f.depth}: size {depth.shape[1]}x{depth.shape[0]} does not match its colour frame ({w}x{h})"
        )
    check_depth(depth, depth_scale, f.depth)
    return bgr, raw_png, depth


def write_source(
    source: Source, out: str | Path, opts: ImportOptions, inputs: tuple = (), force: bool = False
) -> Recording:
    """Read, check and write every selected frame of `source` (atomically); returns the Recording.

    Every frame is decoded and checked before anything is written, so a bad picture anywhere in a long
    capture is reported at once and leaves no trace.
    """
    from tqdm import tqdm

    frames = _select(source.frames, opts)
    K = opts.K if opts.K is not None else source.K
    if K is None:
        raise SpareTwinError(f"{frames[0].color.parent}: no intrinsics file found; pass the intrinsics K")
    depth_scale = opts.depth_scale if opts.depth_scale is not None else source.depth_scale
    if not depth_scale > 0:
        raise SpareTwinError(f"depth_scale {depth_scale}: must be positive")
    check_output(out, IMPORT, inputs, force)  # refused at once, not after reading every frame
    first, _ = _read_color(frames[0].color)
    h, w = first.shape[:2]
    if not (0 < K[0, 2] < w and 0 < K[1, 2] < h):
        where = "K:" if opts.K is not None else f"{frames[0].color.parent}: the intrinsics file's"
        raise SpareTwinError(f"{where} principal point ({K[0, 2]:g}, {K[1, 2]:g}) lies outside the {w}x{h} image")
    # a bar only where it can clear itself (leave=False on a terminal): an error must be the only line left
    quiet = not (opts.progress and sys.stderr.isatty())
    with tqdm(total=len(frames), desc="check", unit="frame", disable=quiet, file=sys.stderr, leave=False) as bar:
        for f in frames:
            _frame(f, source, (h, w), depth_scale)
            bar.update(1)
    has_poses = all(f.T_world_camera is not None for f in frames)
    for f in frames if has_poses else ():  # a layout's poses, whatever lister found them: rigid, plausible
        check_pose(f.T_world_camera, f"{f.color}: its pose")
    camera = Camera("cam0", w, h, K, None, "per_frame" if has_poses else "unknown")
    times = [f.timestamp_s for f in frames]
    fps = opts.fps or source.fps
    if all(t is not None for t in times) and len(times) > 1:
        ts = [t - times[0] for t in times]
        fps = fps or (len(ts) - 1) / max(ts[-1], 1e-9)
    else:
        fps = fps or 30.0
        ts = [i / fps for i in range(len(frames))]
    src_info = {
        "kind": "sensor",
        "sensor_model": source.sensor_model,
        "layout": source.layout,
        "path": str(frames[0].color.parent.resolve()),
        "source_frames": [f.name for f in frames],
        "depth_invalid_value": source.depth_invalid_value,
        **source.extra,
    }
    with RecordingWriter(
        out, [camera], len(frames), fps, src_info, depth_scale=depth_scale, timestamps_s=ts, kind=IMPORT,
        inputs=inputs, force=force,
    ) as writer:  # fmt: skip
        for i, f in enumerate(
            tqdm(frames, desc=f"import {source.layout}", unit="frame", disable=not opts.progress, file=sys.stderr)
        ):
            bgr, raw_png, depth = _frame(f, source, (h, w), depth_scale)
            writer.add_encoded("cam0", i, raw_png if raw_png is not None else encode_png(bgr), depth)
            if has_poses:
                writer.set_pose("cam0", i, f.T_world_camera)
    return Recording.open(out)


def import_bag(path: str | Path, out: str | Path, opts: ImportOptions = ImportOptions(), force: bool = False):
    """Read a RealSense .bag, every frameset in order, into a recording (poses unknown)."""
    path = Path(path)
    if not path.is_file():
        raise SpareTwinError(f"{path}: no such file")
    check_output(out, IMPORT, (path,), force)
    with BagReader(path) as reader:
        s = reader.stream
        camera = Camera("cam0", s.width, s.height, s.K, None, "unknown")
        return stream_to_recording(
            reader.frames(), camera, s.fps, s.depth_scale, out, reader.source, opts, s.expected_frames,
            kind=IMPORT, inputs=(path,), force=force,
        )  # fmt: skip
