"""Where `live`'s frames come from: a recording folder replayed at its own frame rate, a RealSense
`.bag` read frame by frame (`capture.bag`, the reader `capture import --layout bag` uses), or a live
RealSense through `capture record`'s own device set-up.

Every source is opened (and checked) before anything is written, then iterated: `frames()` yields
`StreamFrame`s paced at the source's own rate (a replay or a bag: its timestamps divided by `speed`;
a sensor: as it delivers them) until it ends or `stop` is set. A frame that cannot be read is a
one-line error naming it. A replay yields `StoredFrame`s: its files' bytes, checked but decoded only
when the tracker takes the frame.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from spare_twin.capture.bag import BagReader
from spare_twin.capture.frames import check_depth
from spare_twin.capture.record import RecordConfig, o3d_camera, o3d_depth_scale, o3d_frame_arrays, start_realsense
from spare_twin.errors import SpareTwinError
from spare_twin.live.config import LIVE
from spare_twin.output import RRD, check_output
from spare_twin.recording import Recording, RecordingWriter


@dataclass(frozen=True)
class StreamFrame:
    """One frame as it arrives: 8-bit RGB colour, the sensor's raw uint16 depth, its time."""

    index: int
    """Arrival order from 0: the frame's number in the recording `live` writes."""
    color_rgb: np.ndarray
    depth_u16: np.ndarray
    t_s: float
    """Seconds since the stream's first frame, in the source's own clock (a replay's timestamps)."""

    def write_to(self, writer: RecordingWriter) -> None:
        """Append this frame to the recording `live` writes."""
        writer.append(self.color_rgb, self.depth_u16, self.t_s)


@dataclass(frozen=True)
class StoredFrame:
    """A replayed frame as its recording stores it: the files' bytes, copied into the recording `live`
    writes as they are, and decoded only if the tracker takes the frame. Decoding and encoding again
    every frame cost the reader 60 ms a frame on the loaded 2-core machine, more than the 33 ms a
    30 fps stream leaves it; most frames of a fast stream are dropped from the estimate anyway."""

    index: int
    t_s: float
    color_png: bytes
    depth_png: bytes
    rec: Recording
    cam: str

    @cached_property
    def color_rgb(self) -> np.ndarray:
        return self.rec.color(self.cam, self.index)

    @cached_property
    def depth_u16(self) -> np.ndarray:
        depth = self.rec.depth_raw(self.cam, self.index)
        check_depth(depth, self.rec.depth_scale, self.rec.path(self.cam, "depth", self.index))
        return depth

    def write_to(self, writer: RecordingWriter) -> None:
        writer.append_encoded(self.color_png, self.depth_png, self.t_s)


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"


def png_checked(path: Path, size: tuple[int, int]) -> bytes:
    """The bytes of the PNG at `path`, checked without decoding it: the signature, `size` (width,
    height) in its header, and its end chunk (a file cut off mid-way has none); else a one-line error."""
    try:
        data = path.read_bytes()
    except OSError as err:
        raise SpareTwinError(f"{path}: cannot read ({err.strerror or err})") from None
    if not data.startswith(_PNG_SIGNATURE) or data[12:16] != b"IHDR":
        raise SpareTwinError(f"{path}: not a PNG image")
    got = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if got != size:
        raise SpareTwinError(f"{path}: size {got[0]}x{got[1]} differs from the camera's ({size[0]}x{size[1]})")
    if not data.endswith(_PNG_END):
        raise SpareTwinError(f"{path}: not a readable image (cut off: no PNG end chunk)")
    return data


@dataclass(frozen=True)
class StreamInfo:
    """What the recording `live` writes needs to know of a source."""

    K: np.ndarray
    width: int
    height: int
    depth_scale: float
    """Metres per depth unit."""
    fps: float
    source: dict
    """The recording's `source` entry."""
    path: Path | None
    """The file or folder read (an input of the output rule), None for a sensor."""


class Source:
    """A stream of frames; `frames(stop)` is iterated once."""

    info: StreamInfo

    def frames(self, stop: threading.Event) -> Iterator[StreamFrame]:
        raise NotImplementedError

    def close(self) -> None:
        """Release the device or file (called once the stream has ended)."""


def _paced(t_s: float, start: float, speed: float, stop: threading.Event) -> None:
    """Wait until stream time `t_s` (at `speed` times its rate) has come since wall time `start`;
    speed 0: no waiting."""
    if speed > 0:
        wait = start + t_s / speed - time.monotonic()
        if wait > 0:
            stop.wait(wait)


class ReplaySource(Source):
    """A recording folder's first camera, frame by frame at its timestamps / `speed` (0: as fast
    as the frames are taken, none dropped)."""

    def __init__(self, rec_dir: str | Path, speed: float = 1.0):
        root = Path(rec_dir)
        if not root.exists():
            raise SpareTwinError(f"{root}: no such recording folder")
        rec = Recording.open(root)
        if len(rec.cameras) != 1:
            raise SpareTwinError(
                f"{root}: live replays one moving camera; this recording has {len(rec.cameras)} cameras (a rig)"
            )
        cam = rec.cameras[0]
        self.rec, self.cam, self.speed = rec, cam.name, float(speed)
        self.info = StreamInfo(
            np.asarray(cam.K, np.float64),
            cam.width,
            cam.height,
            rec.depth_scale,
            rec.fps,
            {**rec.source, "layout": "live", "replayed": str(root.resolve())},
            root,
        )

    def frames(self, stop: threading.Event) -> Iterator[StoredFrame]:
        times = self.rec.timestamps_s
        start = time.monotonic()
        size = (self.info.width, self.info.height)
        for f in range(self.rec.n_frames):
            if stop.is_set():
                return
            t_s = float(times[f] - times[0])
            _paced(t_s, start, self.speed, stop)
            color = png_checked(self.rec.path(self.cam, "color", f), size)
            depth = png_checked(self.rec.path(self.cam, "depth", f), size)
            yield StoredFrame(f, t_s, color, depth, self.rec, self.cam)


class BagSource(Source):
    """A RealSense .bag (`capture.bag.BagReader`, the reader `capture import` uses), paced at its
    timestamps / `speed`."""

    def __init__(self, path: str | Path, speed: float = 1.0):
        self.path, self.speed = Path(path), float(speed)
        self.reader = BagReader(self.path)
        s = self.reader.stream
        self.info = StreamInfo(s.K, s.width, s.height, s.depth_scale, s.fps or 30.0, self.reader.source, self.path)

    def frames(self, stop: threading.Event) -> Iterator[StreamFrame]:
        start = time.monotonic()
        for k, (color, depth, t_s) in enumerate(self.reader.frames()):
            if stop.is_set():
                return
            _paced(t_s, start, self.speed, stop)
            check_depth(depth, self.info.depth_scale, f"{self.path}: frame {k}")
            yield StreamFrame(k, color, depth, t_s)

    def close(self) -> None:
        self.reader.close()


class RealSenseSource(Source):
    """A live RealSense, set up as `capture record` sets it up (`capture.record.start_realsense`)."""

    def __init__(self, cfg: RecordConfig = RecordConfig()):
        self.sensor = start_realsense(cfg)
        md = self.sensor.get_metadata()
        cam = o3d_camera(md)
        source = {"kind": "sensor", "sensor_model": md.device_name or "Intel RealSense", "layout": "live",
                  "serial": md.serial_number}  # fmt: skip
        depth_scale = o3d_depth_scale(md)
        self.info = StreamInfo(cam.K, cam.width, cam.height, depth_scale, float(md.fps) or 30.0, source, None)

    def frames(self, stop: threading.Event) -> Iterator[StreamFrame]:
        t0, k, size = None, 0, (self.info.height, self.info.width)
        while not stop.is_set():
            im = self.sensor.capture_frame(True, True)
            stamp_s = self.sensor.get_timestamp() * 1e-6
            t0 = stamp_s if t0 is None else t0
            color, depth = o3d_frame_arrays(im, size, f"RealSense: frame {k}")
            check_depth(depth, self.info.depth_scale, f"RealSense: frame {k}")
            yield StreamFrame(k, color, depth, stamp_s - t0)
            k += 1

    def close(self) -> None:
        self.sensor.stop_capture()


def open_live(
    out: str | Path,
    replay: str | Path | None = None,
    bag: str | Path | None = None,
    speed: float = 1.0,
    rrd: str | Path | None = None,
    connect: str | None = None,
    force: bool = False,
) -> Source:
    """What `live` checks and opens before anything else: the outputs (`out`, the recording; `rrd`, the
    view) and the source (`open_source`), opened. It needs neither torch nor the measurement, so that
    `spare-twin live` says "no device" or "no such folder" before it loads them (5 s)."""
    if rrd is not None and connect is not None:
        raise SpareTwinError("rrd, connect: give one place for the view, not both")
    check_output(out, LIVE, tuple(p for p in (replay, bag) if p is not None), force)
    if rrd is not None:
        check_output(rrd, RRD, (), force)
    return open_source(replay, bag, speed)


def open_source(replay: str | Path | None, bag: str | Path | None, speed: float = 1.0) -> Source:
    """The source `live` reads: `replay` (a recording folder), `bag` (a .bag file) or, with neither,
    the first RealSense connected; one-line errors for a missing folder, no device, a bad speed."""
    if replay is not None and bag is not None:
        raise SpareTwinError("--replay, --bag: give one source, not both")
    if not (isinstance(speed, (int, float)) and np.isfinite(speed) and speed >= 0):
        raise SpareTwinError(f"--speed {speed}: must be 0 (as fast as frames are taken) or a positive factor")
    if replay is not None:
        return ReplaySource(replay, speed)
    if bag is not None:
        return BagSource(bag, speed)
    return RealSenseSource()
