"""Writing recordings: a new one (`RecordingWriter`, of known length or a stream that ends when it
ends) and an atomic update of an existing one (`update_recording`: registration results, calibrated
poses).

Both go through the one output rule (`spare_twin.output.writing`): the new folder is built under a
hidden temporary sibling and swapped into place when complete, so a failure, Ctrl-C or SIGKILL at any
point leaves what was at the destination exactly as it was (a killed run's temporary is removed by the
next run). A new recording refuses to replace anything but an earlier output of the same command, and
keeps what the user added to that one; an update keeps everything it does not update.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from spare_twin.errors import SpareTwinError
from spare_twin.io import encode_png, write_bytes_atomic
from spare_twin.output import check_output, output_command, writing
from spare_twin.recording.format import (
    FORMAT,
    SIM_DEPTH_SCALE,
    VERSION,
    Camera,
    depth_to_uint16,
    frame_file_name,
    npy_bytes,
    npz_bytes,
)
from spare_twin.recording.reader import Recording


def _json_bytes(meta: dict) -> bytes:
    return (json.dumps(meta, indent=2) + "\n").encode()


class RecordingWriter:
    """Writes a recording under a temporary name; leaving the `with` block renames it into place.

    Use as a context manager: on an exception nothing at `root` changes. `kind` is the command whose
    output this is (written in the output marker: "render", "capture import"); `inputs` are the files
    and folders it is made from (the recording may not be one, lie inside one or contain one), and
    `force` lets it replace a folder that is not an earlier output of `kind` (see `spare_twin.output`).

    With `n_frames` None the recording is a stream of unknown length (a live sensor, a .bag replay)
    from one camera without per-frame poses: `append` adds the next frame, and the frame count and
    timestamps are those of the frames appended when the block ends. A frame cut off half-way (colour
    written, depth not) is dropped; a stream with no frame at all is an error and writes nothing.
    """

    def __init__(
        self,
        root: str | Path,
        cameras: list[Camera],
        n_frames: int | None,
        fps: float,
        source: dict,
        depth_scale: float = SIM_DEPTH_SCALE,
        object_config: dict | None = None,
        rig: str | None = None,
        timestamps_s: list[float] | None = None,
        png_compression: int = 1,
        kind: str = "recording",
        inputs: Iterable[str | Path | None] = (),
        force: bool = False,
    ):
        names = [c.name for c in cameras]
        if len(set(names)) != len(names) or not names:
            raise SpareTwinError(f"camera names must be unique and non-empty: {names}")
        if n_frames is None:
            if len(cameras) != 1 or cameras[0].poses == "per_frame" or timestamps_s is not None:
                raise SpareTwinError("a stream of unknown length has one camera, no per-frame poses and no timestamps")
        elif n_frames <= 0:
            raise SpareTwinError("a recording needs at least one frame")
        self.root = Path(root)
        self.cameras = cameras
        self.n_frames = n_frames
        self.depth_scale = float(depth_scale)
        self.png_compression = png_compression
        self._fps = float(fps)
        self._stream_times_s: list[float] = []
        self._poses = {}
        if n_frames is not None:
            self._poses = {c.name: np.full((n_frames, 4, 4), np.nan) for c in cameras if c.poses == "per_frame"}
            if timestamps_s is None:
                timestamps_s = list(np.arange(n_frames) / fps)
        self._meta = {
            "format": FORMAT,
            "version": VERSION,
            "frames": None if n_frames is None else int(n_frames),
            "fps": self._fps,
            "depth_scale": self.depth_scale,
            "timestamps_s": None if timestamps_s is None else [float(t) for t in timestamps_s],
            "source": source,
            "object": object_config,
            "rig": rig,
            "cameras": [c.to_dict() for c in cameras],
        }
        self._ctx = writing(self.root, kind, inputs=tuple(inputs), force=force)
        self._tmp: Path | None = None

    def __enter__(self) -> RecordingWriter:
        self._tmp = self._ctx.__enter__()
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            try:
                self._finish()
            except BaseException as err:  # the temporary folder goes, the destination stays as it was
                self._ctx.__exit__(type(err), err, err.__traceback__)
                raise
        return self._ctx.__exit__(exc_type, exc, tb)

    @property
    def frames_written(self) -> int:
        """Frames appended so far to a stream (`n_frames` None); the fixed count otherwise."""
        return len(self._stream_times_s) if self.n_frames is None else self.n_frames

    def _file(self, cam: str, kind: str, frame: int) -> Path:
        assert self._tmp is not None, "use RecordingWriter as a context manager"
        return self._tmp / "cameras" / cam / kind / frame_file_name(frame)

    def _write_png(self, cam: str, kind: str, frame: int, img: np.ndarray) -> None:
        write_bytes_atomic(self._file(cam, kind, frame), encode_png(img, self.png_compression))

    def add_frame(
        self,
        cam: str,
        frame: int,
        color_rgb: np.ndarray,
        depth_m: np.ndarray,
        segmentation: np.ndarray | None = None,
        T_world_camera: np.ndarray | None = None,
    ) -> None:
        import cv2

        self._write_png(cam, "color", frame, cv2.cvtColor(np.asarray(color_rgb, np.uint8), cv2.COLOR_RGB2BGR))
        self._write_png(cam, "depth", frame, depth_to_uint16(depth_m, self.depth_scale))
        if segmentation is not None:
            self._write_png(cam, "segmentation", frame, np.asarray(segmentation, np.uint8))
        if T_world_camera is not None:
            self._poses[cam][frame] = T_world_camera

    def add_encoded(self, cam: str, frame: int, color_png: bytes, depth_u16: np.ndarray) -> None:
        """Store already-encoded colour and raw uint16 depth (importers: no lossy round trip)."""
        write_bytes_atomic(self._file(cam, "color", frame), color_png)
        self._write_png(cam, "depth", frame, np.asarray(depth_u16, np.uint16))

    def append(self, color_rgb: np.ndarray, depth_u16: np.ndarray, timestamp_s: float) -> None:
        """The next frame of a stream: 8-bit RGB colour, raw uint16 depth, the sensor's timestamp."""
        import cv2

        if self.n_frames is not None:
            raise SpareTwinError(f"{self.root}: append is for streams of unknown length; use add_frame")
        png = encode_png(cv2.cvtColor(np.ascontiguousarray(color_rgb, np.uint8), cv2.COLOR_RGB2BGR))
        self.add_encoded(self.cameras[0].name, len(self._stream_times_s), png, depth_u16)
        self._stream_times_s.append(float(timestamp_s))

    def append_encoded(self, color_png: bytes, depth_png: bytes, timestamp_s: float) -> None:
        """`append` of a frame already stored as a recording stores it (a replay copies its files:
        nothing decoded, nothing encoded again)."""
        if self.n_frames is not None:
            raise SpareTwinError(f"{self.root}: append is for streams of unknown length; use add_frame")
        cam, frame = self.cameras[0].name, len(self._stream_times_s)
        write_bytes_atomic(self._file(cam, "color", frame), color_png)
        write_bytes_atomic(self._file(cam, "depth", frame), depth_png)
        self._stream_times_s.append(float(timestamp_s))

    def set_pose(self, cam: str, frame: int, T_world_camera: np.ndarray) -> None:
        self._poses[cam][frame] = T_world_camera

    def set_ground_truth(self, **arrays: np.ndarray) -> None:
        assert self._tmp is not None, "use RecordingWriter as a context manager"
        write_bytes_atomic(self._tmp / "ground_truth.npz", npz_bytes(arrays))

    def _end_stream(self) -> None:
        count = len(self._stream_times_s)
        if count == 0:
            raise SpareTwinError(f"{self.root}: no frames received; nothing written")
        cam = self.cameras[0].name
        for kind in ("color", "depth"):
            for f in (self._tmp / "cameras" / cam / kind).glob("*.png"):
                if int(f.stem) >= count:
                    f.unlink()
        t0 = self._stream_times_s[0]
        self.n_frames = count
        self._meta["frames"] = count
        self._meta["timestamps_s"] = [t - t0 for t in self._stream_times_s]

    def _finish(self) -> None:
        if self.n_frames is None:
            self._end_stream()
        for cam, poses in self._poses.items():
            if np.isnan(poses).any():
                raise SpareTwinError(f"{self.root}: camera {cam} is missing per-frame poses")
            write_bytes_atomic(self._tmp / "cameras" / cam / "T_world_camera.npy", npy_bytes(poses))
        write_bytes_atomic(self._tmp / "recording.json", _json_bytes(self._meta))
        Recording.open(self._tmp).validate()


def check_updatable(root: str | Path, writes: Iterable[str] = ()) -> Path:
    """`root` as `update_recording` would take it, writing the files `writes` (relative paths), or a
    one-line error naming it: for a command to call before its work."""
    final = check_output(root, output_command(root) or "recording", force=True, in_place=True)
    for rel in writes:
        _refuse_linked_folders(Path(root), Path(root), rel)
    return final


def _refuse_linked_folders(root: Path, copy: Path, rel: str) -> None:
    """Writing `rel` through a link to a folder would change that folder, outside the recording and in
    place: refused, naming the user's path (`copy`: the recording or its temporary copy)."""
    for up in reversed(Path(rel).parents[:-1]):
        if (copy / up).is_symlink():
            raise SpareTwinError(
                f"{root / up}: is a symbolic link, and the update writes {rel} inside it, which would change "
                "the folder it points to; make it a real folder"
            )


def update_recording(root: str | Path, meta: dict, files: dict[str, bytes], remove: tuple[str, ...] = ()) -> Recording:
    """Replace `recording.json` by `meta` and write `files` (relative path -> bytes), all at once.

    Everything else in the folder stays as it was (`spare_twin.output.writing` with `in_place`: hard
    links, hidden files, links kept as links, empty folders); those in `remove` are left out. The result
    is opened and validated before it replaces the old folder.
    """
    root = Path(root)
    Recording.open(root)  # a clear error if it is not a recording at all
    check_updatable(root)
    # the same command's output again (its marker kept), so the swap keeps what produced it
    with writing(root, output_command(root) or "recording", force=True, in_place=True) as tmp:
        for rel in (*files, *remove):
            _refuse_linked_folders(root, tmp, rel)
        for rel in remove:
            (tmp / rel).unlink(missing_ok=True)
        for rel, data in files.items():
            write_bytes_atomic(tmp / rel, data)
        write_bytes_atomic(tmp / "recording.json", _json_bytes(meta))
        try:
            Recording.open(tmp).validate()
        except SpareTwinError as exc:  # about the folder the user named, not the temporary
            raise SpareTwinError(str(exc).replace(str(tmp), str(root))) from None
    return Recording.open(root)
