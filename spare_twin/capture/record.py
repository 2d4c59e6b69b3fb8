"""Live capture from an Intel RealSense through open3d, and the stream writer shared with .bag replay.

open3d's `RealSenseSensor.capture_frame(align_depth_to_color=True)` resamples depth into the colour
camera's pixel grid, so one set of intrinsics (the device's colour intrinsics, read from the device)
describes both images. Frames are written to disk as they arrive; Ctrl-C stops the capture and the
recording is finalised with every frame received so far.
"""

from __future__ import annotations

import itertools
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spare_twin.capture.checks import positive, whole
from spare_twin.capture.frames import K_from, check_depth
from spare_twin.errors import SpareTwinError
from spare_twin.open3d_loader import quiet_open3d
from spare_twin.output import check_output
from spare_twin.recording import Camera, Recording, RecordingWriter

RECORD = "capture record"


@dataclass(frozen=True)
class RecordConfig:
    """Live RealSense capture settings."""

    width: int = 640
    height: int = 480
    fps: int = 30
    max_frames: int | None = None
    """stop after this many frames (None: until Ctrl-C)."""
    duration_s: float | None = None
    """stop after this many seconds (None: until Ctrl-C)."""
    serial: str = ""
    """device serial number; empty: the first device."""
    bag: str | None = None
    """also save the raw stream to this .bag file (open3d's recorder)."""
    visual_preset: str = ""
    """RealSense visual preset name, e.g. RS2_L500_VISUAL_PRESET_SHORT_RANGE; empty: device default."""

    def __post_init__(self):
        for name in ("width", "height", "fps"):
            whole(name, getattr(self, name), 1)
        if self.max_frames is not None:
            whole("max_frames", self.max_frames, 1)
        if self.duration_s is not None:
            positive("duration_s", self.duration_s)


def _tensor_np(image) -> np.ndarray:
    """open3d t.geometry.Image (or Tensor) to numpy, on the CPU."""
    t = image.as_tensor() if hasattr(image, "as_tensor") else image
    return np.asarray(t.cpu().numpy() if hasattr(t, "cpu") else t)


def o3d_frame_arrays(im, size: tuple[int, int], where: str) -> tuple[np.ndarray, np.ndarray]:
    """An open3d t.geometry.RGBDImage as (uint8 RGB colour, uint16 depth), checked to be `size` (H, W)."""
    color = _tensor_np(im.color)
    depth = _tensor_np(im.depth)
    depth = depth[..., 0] if depth.ndim == 3 else depth
    if color.shape[:2] != size or depth.shape != size:
        raise SpareTwinError(
            f"{where}: colour {color.shape[:2]} / depth {depth.shape} do not match the stream's {size[0]}x{size[1]}"
        )
    if color.ndim == 2:
        color = np.repeat(color[..., None], 3, axis=2)
    if color.dtype != np.uint8:  # some streams deliver 16-bit colour
        color = (color / 257).astype(np.uint8)
    return color[..., :3], depth.astype(np.uint16)


def o3d_camera(md) -> Camera:
    """The camera open3d's RGBD video metadata `md` describes (its colour intrinsics; depth is aligned to them)."""
    Km = np.asarray(md.intrinsics.intrinsic_matrix, dtype=np.float64)
    K = K_from(Km[0, 0], Km[1, 1], Km[0, 2], Km[1, 2])
    return Camera("cam0", int(md.width), int(md.height), K, None, "unknown")


def o3d_depth_scale(md) -> float:
    """Metres per depth unit from open3d's RGBD video metadata `md` (which keeps units per metre)."""
    return 1.0 / float(md.depth_scale)


def stream_to_recording(
    frames,
    camera: Camera,
    fps: float,
    depth_scale: float,
    out: str | Path,
    source: dict,
    opts,
    expected_frames: int | None,
    kind: str = RECORD,
    inputs: tuple = (),
    force: bool = False,
) -> Recording:
    """Write a stream of frames into a one-camera recording as they come.

    `frames` yields (uint8 RGB colour, uint16 depth, seconds) of `camera`'s size and intrinsics, with
    `depth_scale` metres per depth unit, at about `fps`. Stops at the end of the iterator, after
    `opts.max_frames`, or on Ctrl-C (then keeps what was received). `opts` has `max_frames`, `stride`
    and `progress` (an `ImportOptions`, or any object with them). `kind`, `inputs` and `force` are
    the output rule's (`RecordingWriter`).
    """
    from tqdm import tqdm

    where = source.get("path", "sensor")
    limit = getattr(opts, "max_frames", None)
    stride = max(1, getattr(opts, "stride", 1))
    stopped = False
    with RecordingWriter(
        out, [camera], None, float(fps) / stride, source, depth_scale=depth_scale, kind=kind, inputs=inputs,
        force=force,
    ) as writer:  # fmt: skip
        bar = tqdm(
            total=expected_frames,
            desc=f"{source.get('layout', 'record')}",
            unit="frame",
            file=sys.stderr,
            disable=not getattr(opts, "progress", True),
        )
        try:
            for k, (color, depth, t_s) in enumerate(frames):
                if k % stride:
                    continue
                if writer.frames_written == 0:
                    check_depth(depth, depth_scale, f"{where} (first frame)")
                writer.append(color, depth, t_s)
                bar.update(1)
                if limit is not None and writer.frames_written >= limit:
                    break
        except KeyboardInterrupt:
            stopped = True  # finalise below with every frame received so far
        finally:
            bar.close()
    if stopped:
        print(f"stopped by Ctrl-C after {writer.frames_written} frames; recording finalised", file=sys.stderr)
    return Recording.open(out)


def start_realsense(cfg: RecordConfig = RecordConfig()):
    """The first (or `cfg.serial`'s) RealSense, configured by `cfg` and capturing (recording its raw
    stream to `cfg.bag` where set): an open3d RealSenseSensor; the caller stops it."""
    o3d = quiet_open3d()

    if not o3d.t.io.RealSenseSensor.list_devices():
        raise SpareTwinError("no Intel RealSense device found (check the USB 3 cable and `rs-enumerate-devices`)")
    config = {
        "serial": cfg.serial,
        "color_format": "RS2_FORMAT_RGB8",
        "color_resolution": f"{cfg.width},{cfg.height}",
        "depth_format": "RS2_FORMAT_Z16",
        "depth_resolution": f"{cfg.width},{cfg.height}",
        "fps": str(cfg.fps),
        "visual_preset": cfg.visual_preset,
    }
    sensor = o3d.t.io.RealSenseSensor()
    if not sensor.init_sensor(o3d.t.io.RealSenseSensorConfig(config), 0, cfg.bag or ""):
        raise SpareTwinError(
            f"RealSense: could not configure {cfg.width}x{cfg.height} at {cfg.fps} fps (unsupported mode?)"
        )
    if not sensor.start_capture(start_record=bool(cfg.bag)):
        raise SpareTwinError("RealSense: could not start capture")
    return sensor


def record_realsense(
    out: str | Path, cfg: RecordConfig = RecordConfig(), progress: bool = True, force: bool = False
) -> Recording:
    """Record from a live RealSense until Ctrl-C, `max_frames` or `duration_s`; returns the Recording.

    `out` follows the output rule (`spare_twin.output`), checked before the device is opened; `force`
    replaces what the rule would refuse.
    """
    import time

    inputs = (cfg.bag,) if cfg.bag else ()  # the raw .bag must not land inside the folder that is swapped in
    check_output(out, RECORD, inputs, force)
    sensor = start_realsense(cfg)
    t_end = None if cfg.duration_s is None else time.monotonic() + cfg.duration_s

    def frames(size: tuple[int, int]):
        for k in itertools.count():
            if t_end is not None and time.monotonic() >= t_end:
                return
            color, depth = o3d_frame_arrays(sensor.capture_frame(True, True), size, f"RealSense: frame {k}")
            yield color, depth, sensor.get_timestamp() * 1e-6

    class _Opts:
        max_frames = cfg.max_frames
        stride = 1

    _Opts.progress = progress
    try:
        md = sensor.get_metadata()
        source = {"kind": "sensor", "sensor_model": md.device_name or "Intel RealSense", "serial": md.serial_number,
                  "layout": "live"}  # fmt: skip
        depth_scale = o3d_depth_scale(md)
        return stream_to_recording(
            frames((int(md.height), int(md.width))), o3d_camera(md), float(md.fps), depth_scale, out, source, _Opts,
            cfg.max_frames, kind=RECORD, inputs=inputs, force=force,
        )  # fmt: skip
    finally:
        sensor.stop_capture()
