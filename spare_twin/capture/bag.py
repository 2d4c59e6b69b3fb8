"""RealSense `.bag` files, read frame by frame through librealsense's own playback (pyrealsense2).

A .bag is played back by librealsense, which hands each frameset on through a queue one frameset
deep. By default it does so in real time, at the frames' recorded times, so a reader that stalls
loses frames. open3d's RSBagReader leaves real-time playback on and does not expose the switch: on
a loaded 2-core machine it lost one of four frames 2 s apart (release 0.6.5's CI). pyrealsense2 is
the same librealsense with `set_real_time(False)` exposed. Playback then waits for the reader, and
every frameset in the file arrives in order, whatever the load.

Depth is aligned to colour with librealsense's `align` (what open3d's reader does), so one set of
intrinsics, the colour camera's, describes both images. Times are the frames' own timestamps from the
first frame, so importing a bag twice gives the same files.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path

import numpy as np

from spare_twin.capture.frames import K_from
from spare_twin.errors import SpareTwinError

#: How long a playback that still says "playing" may go without a frameset before the reading ends
#: (librealsense's non-real-time playback is known to hang on some files with gaps).
STALL_S = 10.0
#: One wait for the next frameset; the loop checks whether playback has stopped in between.
_POLL_MS = 100


@dataclass(frozen=True)
class BagStream:
    """What a bag says of its stream: the colour camera's intrinsics (depth is aligned to it)."""

    K: np.ndarray
    """3x3 intrinsics in pixels (float64)."""
    width: int
    height: int
    depth_scale: float
    """Metres per depth unit."""
    fps: float
    device_name: str
    duration_s: float

    @property
    def expected_frames(self) -> int | None:
        """About how many framesets the bag holds (for a progress bar), None when unknown: its
        duration runs from the first frame's time to the last's."""
        return int(round(self.duration_s * self.fps)) + 1 if self.duration_s > 0 and self.fps > 0 else None


#: Colour formats a bag may store, and how to make 8-bit RGB of them.
_TO_RGB = {"rgb8": lambda a: a, "bgr8": lambda a: a[..., ::-1], "rgba8": lambda a: a[..., :3],
           "bgra8": lambda a: a[..., 2::-1]}  # fmt: skip


def _first_line(err: Exception) -> str:
    text = str(err).strip()
    return text.splitlines()[0] if text else "librealsense refused it"


def _same_camera(depth, color) -> bool:
    """Whether the depth and colour stream profiles see through one camera: the same intrinsics and
    distortion, and an identity transform between them."""
    d, c = depth.as_video_stream_profile().get_intrinsics(), color.as_video_stream_profile().get_intrinsics()
    same_intrinsics = (d.width, d.height, d.fx, d.fy, d.ppx, d.ppy, d.model) == (
        c.width, c.height, c.fx, c.fy, c.ppx, c.ppy, c.model
    ) and list(d.coeffs) == list(c.coeffs)  # fmt: skip
    T = depth.get_extrinsics_to(color)
    return same_intrinsics and np.allclose(T.rotation, np.eye(3).ravel()) and not np.any(T.translation)


class BagReader:
    """An open .bag: `stream` says what it holds; `frames()` yields each frameset once, in order.
    Opening refuses (one line, naming the file) what is not a readable bag with a depth and a
    colour stream; use it as a context manager, or call `close()`."""

    def __init__(self, path: str | Path):
        import pyrealsense2 as rs

        self.path = Path(path)
        if not self.path.is_file():
            raise SpareTwinError(f"{self.path}: no such file")
        self._rs, self._pipe = rs, rs.pipeline()
        config = rs.config()
        try:
            config.enable_device_from_file(str(self.path), repeat_playback=False)
            # Resolved before start: the playback device is the one `start` uses, so it is checked
            # and switched out of real time before its first frame is handed on (and a bag that is
            # refused is never played: stopping a playback just started crashed 1 run in 240).
            resolved = config.resolve(rs.pipeline_wrapper(self._pipe))
        except RuntimeError as err:
            raise SpareTwinError(f"{self.path}: not a readable RealSense .bag file ({_first_line(err)})") from None
        self._playback = resolved.get_device().as_playback()
        self.stream = self._stream(resolved)
        self._playback.set_real_time(False)
        try:
            self._pipe.start(config)
        except RuntimeError as err:
            raise SpareTwinError(f"{self.path}: not a readable RealSense .bag file ({_first_line(err)})") from None

    def _stream(self, profile) -> BagStream:
        rs = self._rs
        streams = {s.stream_type(): s for s in profile.get_streams()}
        wanted = (("depth", rs.stream.depth), ("colour", rs.stream.color))
        missing = [name for name, kind in wanted if kind not in streams]
        if missing:
            raise SpareTwinError(f"{self.path}: the bag has no {' and no '.join(missing)} stream")
        color, depth = streams[rs.stream.color], streams[rs.stream.depth]
        fmt = str(color.format()).rsplit(".", 1)[-1]
        if fmt not in _TO_RGB:
            raise SpareTwinError(f"{self.path}: colour format {fmt} is not one of {', '.join(_TO_RGB)}")
        if str(depth.format()).rsplit(".", 1)[-1] != "z16":
            raise SpareTwinError(f"{self.path}: depth format {depth.format()} is not z16")
        self._to_rgb = _TO_RGB[fmt]
        i = color.as_video_stream_profile().get_intrinsics()
        # Depth already in the colour camera's pixel grid needs no resampling, and librealsense's
        # align would still punch holes into it (pixel corners rounded to neighbours).
        self._align = None if _same_camera(depth, color) else rs.align(rs.stream.color)
        device = profile.get_device()
        name_key = rs.camera_info.name
        return BagStream(
            K=K_from(i.fx, i.fy, i.ppx, i.ppy),
            width=int(i.width),
            height=int(i.height),
            # librealsense keeps it as float32: 0.001 comes back as 0.0010000000474974513
            depth_scale=float(str(np.float32(device.first_depth_sensor().get_depth_scale()))),
            fps=float(color.fps()),
            device_name=device.get_info(name_key) if device.supports(name_key) else "",
            duration_s=self._playback.get_duration() / timedelta(seconds=1),
        )

    @property
    def source(self) -> dict:
        """The `source` entry of a recording made from this bag."""
        name = self.stream.device_name or "Intel RealSense"
        return {"kind": "sensor", "sensor_model": name, "layout": "bag", "path": str(self.path.resolve())}

    def frames(self) -> Iterator[tuple[np.ndarray, np.ndarray, float]]:
        """(uint8 RGB colour, uint16 depth aligned to it, seconds since the first frameset) for each
        frameset, until the bag ends."""
        rs, t0_ms, last_number, waited_s, pending = self._rs, None, None, 0.0, None
        while True:
            ok, frameset = self._pipe.try_wait_for_frames(_POLL_MS)
            if not ok:
                if self._playback.current_status() == rs.playback_status.stopped:
                    return
                waited_s += _POLL_MS / 1000
                if waited_s >= STALL_S:
                    print(f"{self.path}: playback stalled for {STALL_S:.0f} s; reading ends here", file=sys.stderr)
                    return
                continue
            waited_s = 0.0
            color, depth = frameset.get_color_frame(), frameset.get_depth_frame()
            if bool(color) != bool(depth) and self._align is None:
                # the syncer can hand a pair on as two halves (seen on a loaded machine for the first
                # frame): a half waits for the other half with the same timestamp
                half = color or depth
                other, pending = pending, (half, frameset.get_timestamp())
                if other is None or other[1] != frameset.get_timestamp():
                    continue
                pending = None
                color, depth = (half, other[0]) if color else (other[0], half)
            elif self._align is not None and color and depth:
                aligned = self._align.process(frameset)
                color, depth = aligned.get_color_frame(), aligned.get_depth_frame()
            if not color or not depth or color.get_frame_number() == last_number:
                if not (color and depth):
                    print(f"{self.path}: a frameset without its colour or depth half, skipped", file=sys.stderr)
                continue  # or one handed on again: no new frame
            last_number = color.get_frame_number()
            t0_ms = frameset.get_timestamp() if t0_ms is None else t0_ms
            rgb = np.array(self._to_rgb(np.asanyarray(color.get_data())), dtype=np.uint8)
            depth_u16 = np.array(np.asanyarray(depth.get_data()), dtype=np.uint16)
            yield rgb, depth_u16, (frameset.get_timestamp() - t0_ms) / 1000

    def close(self) -> None:
        self._pipe.stop()

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
