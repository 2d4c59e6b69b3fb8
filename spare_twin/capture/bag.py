"""RealSense `.bag` files, read message by message as the file stores them (rosbags).

A .bag is a ROS 1 bag in librealsense's layout (file versions 2 to 4): per stream, images on
`/device_0/sensor_<s>/<Depth|Color>_<i>/image/data`, intrinsics on `.../info/camera_info`, the pose
against the device's reference stream on `.../tf/<group>`, the frame rate on `.../info`; the depth
unit on the depth sensor's `Depth Units` option; the device's name on `/device_0/info`.

Reading the file directly, not through librealsense's playback, is what makes an import lossless and
the same every time: the playback hands framesets on from its own threads through a one-deep queue
and a syncer, and on a loaded 2-core machine it lost one frame of four both in real time (open3d's
reader, release 0.6.5) and out of it (pyrealsense2, 0.6.6). Here a colour frame and a depth frame
are paired by their timestamps, each frame once, in the file's order; a frame left without a partner
is counted and said, never dropped silently.

Depth is resampled into the colour camera's grid (`capture.align`), so the colour camera's intrinsics
describe both images; where the two streams already share one camera it is passed on as it is.
"""

from __future__ import annotations

import re
import sys
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spare_twin.capture.align import align_depth
from spare_twin.capture.frames import K_from
from spare_twin.errors import SpareTwinError, first_line

#: The image topics of device 0's depth and colour streams: sensor index, stream kind, stream index.
_IMAGE_TOPIC = re.compile(r"^/device_0/sensor_(\d+)/(Depth|Color)_(\d+)/image/data$")
#: Colour encodings a bag may store, and how to make 8-bit RGB of them.
_TO_RGB = {"rgb8": lambda a: a, "bgr8": lambda a: a[..., ::-1], "rgba8": lambda a: a[..., :3],
           "bgra8": lambda a: a[..., 2::-1]}  # fmt: skip
_DEPTH_ENCODINGS = ("mono16", "16UC1")
#: librealsense's depth unit where a bag does not say (1 mm).
DEFAULT_DEPTH_SCALE = 0.001
#: Frames of one stream held back waiting for a partner, at most (a stream that stops for longer
#: than this has its oldest frames counted unpaired, so memory stays bounded).
_MAX_WAITING = 64


@dataclass(frozen=True)
class BagStream:
    """What a bag says of its streams: the colour camera's intrinsics (depth is resampled into it)."""

    K: np.ndarray
    """3x3 intrinsics in pixels (float64)."""
    width: int
    height: int
    depth_scale: float
    """Metres per depth unit."""
    fps: float
    """The colour stream's frame rate; 0 where the bag does not say."""
    device_name: str
    expected_frames: int
    """Framesets the bag can give at most: the fewer of its depth and colour images."""


@dataclass(frozen=True)
class _Camera:
    topic: str
    sensor: int
    K: np.ndarray
    width: int
    height: int
    fps: float
    T_stream_reference: np.ndarray | None
    """4x4, metres: the device's reference stream -> this stream (librealsense's extrinsics)."""
    frames: int


def _T_from_tf(tf) -> np.ndarray:
    """A geometry_msgs/Transform as a 4x4 matrix (librealsense writes its extrinsics this way)."""
    from scipy.spatial.transform import Rotation

    q = tf.rotation
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    T[:3, 3] = (tf.translation.x, tf.translation.y, tf.translation.z)
    return T


class BagReader:
    """An open .bag: `stream` says what it holds; `frames()` yields each depth and colour pair once,
    in order. Opening refuses (one line, naming the file) what is not a readable bag with a depth and
    a colour stream; use it as a context manager, or call `close()`."""

    def __init__(self, path: str | Path):
        from rosbags.rosbag1 import Reader
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        self.path = Path(path)
        if not self.path.is_file():
            raise SpareTwinError(f"{self.path}: no such file")
        self._bag = Reader(self.path)
        try:
            self._bag.open()
            # every message type as the bag itself defines it (librealsense adds its own)
            self._types = get_typestore(Stores.EMPTY)
            for c in self._bag.connections:
                self._types.register(get_types_from_msg(c.msgdef.data, c.msgtype))
            self._depth, self._colour, self.stream = self._read_streams()
            self._T_colour_depth = self._resampling()
        except SpareTwinError:
            self.close()
            raise
        except Exception as err:  # rosbags raises its own errors, and struct/value errors on bad bytes
            self.close()
            raise SpareTwinError(f"{self.path}: not a readable RealSense .bag file ({first_line(err)})") from None

    # -- what the bag holds --------------------------------------------------------------------------

    def _messages(self, topic_pattern: str):
        wanted = [c for c in self._bag.connections if re.fullmatch(topic_pattern, c.topic)]
        if not wanted:
            return  # rosbags reads every connection when given none: the whole bag
        for conn, _, raw in self._bag.messages(connections=wanted):
            yield conn.topic, self._types.deserialize_ros1(raw, conn.msgtype)

    def _read_streams(self) -> tuple[_Camera, _Camera, BagStream]:
        version = [m.data for _, m in self._messages(re.escape("/file_version"))]
        if not version:
            raise SpareTwinError(f"{self.path}: not a RealSense .bag (no /file_version)")
        if version[0] < 2:
            raise SpareTwinError(f"{self.path}: RealSense .bag file version {version[0]} is too old (2 or later)")
        streams: dict[str, tuple[int, str]] = {}
        for c in self._bag.connections:
            found = _IMAGE_TOPIC.match(c.topic)
            if found and found[2] not in streams:
                streams[found[2]] = (int(found[1]), c.topic.removesuffix("/image/data"))
        missing = [name for name, kind in (("depth", "Depth"), ("colour", "Color")) if kind not in streams]
        if missing:
            raise SpareTwinError(f"{self.path}: the bag has no {' and no '.join(missing)} stream")
        depth, colour = (self._camera(*streams[kind]) for kind in ("Depth", "Color"))
        name = next((m.value for m in self._all("/device_0/info") if m.key == "Name"), "")
        stream = BagStream(
            K=colour.K, width=colour.width, height=colour.height, depth_scale=self._depth_scale(depth.sensor),
            fps=colour.fps, device_name=name, expected_frames=min(depth.frames, colour.frames),
        )  # fmt: skip
        return depth, colour, stream

    def _resampling(self) -> np.ndarray | None:
        """T_colour_depth (4x4, metres) where depth must be resampled into the colour grid; None where
        the two streams share one camera (resampling would only blur it)."""
        d, c = self._depth, self._colour
        same_grid = (d.width, d.height) == (c.width, c.height) and np.allclose(d.K, c.K)
        if d.T_stream_reference is None or c.T_stream_reference is None:
            if not same_grid:
                raise SpareTwinError(f"{self.path}: depth and colour streams differ but the bag holds no extrinsics")
            return None
        T_colour_depth = c.T_stream_reference @ np.linalg.inv(d.T_stream_reference)
        return None if same_grid and np.allclose(T_colour_depth, np.eye(4), atol=1e-9) else T_colour_depth

    def _all(self, topic: str) -> list:
        return [m for _, m in self._messages(re.escape(topic))]

    def _camera(self, sensor: int, base: str) -> _Camera:
        infos = self._all(f"{base}/info/camera_info")
        if not infos:
            raise SpareTwinError(f"{self.path}: no intrinsics for {base} ({base}/info/camera_info)")
        ci = infos[-1]
        K = np.asarray(ci.K, np.float64).reshape(3, 3)
        rates = self._all(f"{base}/info")
        tfs = [m for _, m in self._messages(re.escape(base) + r"/tf/\d+")]
        frames = sum(c.msgcount for c in self._bag.connections if c.topic == f"{base}/image/data")
        return _Camera(
            topic=f"{base}/image/data", sensor=sensor, K=K_from(K[0, 0], K[1, 1], K[0, 2], K[1, 2]),
            width=int(ci.width), height=int(ci.height), fps=float(rates[-1].fps) if rates else 0.0,
            T_stream_reference=_T_from_tf(tfs[-1]) if tfs else None, frames=frames,
        )  # fmt: skip

    def _depth_scale(self, sensor: int) -> float:
        """The depth sensor's `Depth Units` option: a Float32 topic from file version 3, a property
        (key/value text) in version 2."""
        option = self._all(f"/device_0/sensor_{sensor}/option/Depth Units/value")
        if option:
            value = float(option[-1].data)
        else:
            props = [m for m in self._all(f"/device_0/sensor_{sensor}/property") if m.key == "Depth Units"]
            value = float(props[-1].value) if props else DEFAULT_DEPTH_SCALE
        if not (np.isfinite(value) and value > 0):
            raise SpareTwinError(f"{self.path}: depth units {value} is not a positive number of metres")
        # librealsense keeps it as float32: 0.001 comes back as 0.0010000000474974513
        return float(str(np.float32(value)))

    @property
    def source(self) -> dict:
        """The `source` entry of a recording made from this bag."""
        name = self.stream.device_name or "Intel RealSense"
        return {"kind": "sensor", "sensor_model": name, "layout": "bag", "path": str(self.path.resolve())}

    # -- frames ----------------------------------------------------------------------------------------

    def _image(self, msg, camera: _Camera) -> np.ndarray:
        """An Image message as (height, width[, channels]) pixels: uint16 depth or 8-bit RGB colour."""
        if (msg.width, msg.height) != (camera.width, camera.height):
            raise SpareTwinError(
                f"{self.path}: {camera.topic} frame {msg.header.seq} is {msg.width}x{msg.height}, "
                f"its stream says {camera.width}x{camera.height}"
            )
        data = np.asarray(msg.data, np.uint8).reshape(msg.height, msg.step)
        if camera is self._depth:
            if msg.encoding not in _DEPTH_ENCODINGS:
                raise SpareTwinError(f"{self.path}: depth encoding {msg.encoding} is not 16-bit ({_DEPTH_ENCODINGS})")
            depth = data[:, : 2 * msg.width].copy().view(">u2" if msg.is_bigendian else "<u2")
            return depth.astype(np.uint16)
        to_rgb = _TO_RGB.get(msg.encoding)
        if to_rgb is None:
            raise SpareTwinError(f"{self.path}: colour encoding {msg.encoding} is not one of {', '.join(_TO_RGB)}")
        channels = 4 if msg.encoding.endswith("a8") else 3
        pixels = data[:, : channels * msg.width].reshape(msg.height, msg.width, channels)
        return np.ascontiguousarray(to_rgb(pixels), dtype=np.uint8)

    def _depth_in_colour(self, depth_u16: np.ndarray) -> np.ndarray:
        if self._T_colour_depth is None:
            return depth_u16
        c = self._colour
        return align_depth(
            depth_u16, self._depth.K, c.K, self._T_colour_depth, (c.width, c.height), self.stream.depth_scale
        )

    def frames(self) -> Iterator[tuple[np.ndarray, np.ndarray, float]]:
        """(uint8 RGB colour, uint16 depth in the colour camera's grid, seconds since the first pair)
        for each colour frame and the depth frame nearest it in time, in the file's order, until the
        bag ends. A frame with no partner within half a frame period is left out and counted; the
        count is said on stderr at the end. A bag that cannot be read on is a one-line error."""
        d, c, t0_ns, k = self._depth, self._colour, None, 0
        try:
            for m_d, m_c, t_ns in self._pairs():
                t0_ns = t_ns if t0_ns is None else t0_ns
                yield self._image(m_c, c), self._depth_in_colour(self._image(m_d, d)), (t_ns - t0_ns) / 1e9
                k += 1
        except SpareTwinError:
            raise
        except Exception as err:  # a chunk cut off or corrupt: rosbags' own errors, struct errors
            raise SpareTwinError(f"{self.path}: unreadable after frame {k} ({first_line(err)})") from None

    def _pairs(self) -> Iterator[tuple[object, object, int]]:
        """(depth message, colour message, colour time in ns) paired by their header stamps."""
        d, c = self._depth.topic, self._colour.topic
        tolerance_ns = round(0.5e9 / (max(self._depth.fps, self._colour.fps) or 30.0))
        waiting: dict[str, deque] = {d: deque(), c: deque()}
        last_seq: dict[str, int] = {}
        unpaired = {d: 0, c: 0}
        for topic, msg in self._messages(f"{re.escape(d)}|{re.escape(c)}"):
            if last_seq.get(topic) == msg.header.seq:
                continue  # the same frame written again
            last_seq[topic] = msg.header.seq
            waiting[topic].append((msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec, msg))
            if len(waiting[topic]) > _MAX_WAITING:
                waiting[topic].popleft()
                unpaired[topic] += 1
            while waiting[d] and waiting[c]:
                (t_d, m_d), (t_c, m_c) = waiting[d][0], waiting[c][0]
                if abs(t_c - t_d) <= tolerance_ns:
                    waiting[d].popleft(), waiting[c].popleft()
                    yield m_d, m_c, t_c
                else:  # the earlier of the two can no longer find a partner
                    earlier = d if t_d < t_c else c
                    waiting[earlier].popleft()
                    unpaired[earlier] += 1
        for topic, queue in waiting.items():
            unpaired[topic] += len(queue)
        if any(unpaired.values()):
            rates = (self._depth.fps, self._colour.fps)
            why = f" (depth at {rates[0]:g} fps, colour at {rates[1]:g})" if rates[0] != rates[1] else ""
            print(
                f"{self.path}: {unpaired[d]} depth and {unpaired[c]} colour frames had no partner "
                f"within {tolerance_ns / 1e6:.1f} ms and were left out{why}",
                file=sys.stderr,
            )

    def close(self) -> None:
        if self._bag.bio is not None:
            self._bag.close()

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
