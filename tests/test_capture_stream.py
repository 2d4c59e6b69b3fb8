"""The live / .bag stream writer without hardware: frames as they come, Ctrl-C keeps them all."""

import types

import cv2
import numpy as np
import pytest
from capture_helpers import APC, APC_FRAMES


def _frames(n_before_interrupt):
    """(colour, depth, seconds) as a sensor hands them on, 30 fps from an arbitrary clock, then Ctrl-C."""
    for k in range(n_before_interrupt):
        n = APC_FRAMES[k % len(APC_FRAMES)]
        color = cv2.cvtColor(cv2.imread(str(APC / f"frame-{n:06d}.color.png")), cv2.COLOR_BGR2RGB)
        depth = cv2.imread(str(APC / f"frame-{n:06d}.depth.png"), cv2.IMREAD_UNCHANGED)
        yield color, depth, 5.0 + k / 30
    raise KeyboardInterrupt  # the user presses Ctrl-C


def _camera():
    from spare_twin.recording import Camera

    return Camera("cam0", 640, 480, np.loadtxt(APC / "intrinsics.K.txt"), None, "unknown")


def test_ctrl_c_finalises_with_every_frame(tmp_path, capsys):
    from spare_twin.capture.record import stream_to_recording
    from spare_twin.recording import Recording

    opts = types.SimpleNamespace(max_frames=None, stride=1, progress=False)
    source = {"kind": "sensor", "layout": "live"}
    stream_to_recording(_frames(3), _camera(), 30.0, 0.001, tmp_path / "live", source, opts, None)
    rec = Recording.open(tmp_path / "live")
    rec.validate()
    assert rec.n_frames == 3 and rec.depth_scale == pytest.approx(0.001)
    assert np.allclose(rec.timestamps_s, [0, 1 / 30, 2 / 30])
    raw = cv2.imread(str(APC / f"frame-{APC_FRAMES[2]:06d}.depth.png"), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(cv2.imread(str(rec.path("cam0", "depth", 2)), cv2.IMREAD_UNCHANGED), raw)
    assert "stopped by Ctrl-C after 3 frames" in capsys.readouterr().err


def test_ctrl_c_before_any_frame_writes_nothing(tmp_path):
    from spare_twin.capture.record import stream_to_recording
    from spare_twin.errors import SpareTwinError

    opts = types.SimpleNamespace(max_frames=None, stride=1, progress=False)
    with pytest.raises(SpareTwinError, match="no frames received"):
        stream_to_recording(_frames(0), _camera(), 30.0, 0.001, tmp_path / "live", {"kind": "sensor"}, opts, None)
    assert not (tmp_path / "live").exists() and not list(tmp_path.iterdir())


class _CutOff:
    """Depth that never arrives: Ctrl-C while the frame is being written (its colour is already on disk)."""

    def __array__(self, dtype=None, copy=None):
        raise KeyboardInterrupt


def test_stream_writer_drops_a_frame_cut_off_half_way(tmp_path):
    from spare_twin.recording import Camera, Recording, RecordingWriter

    K = np.loadtxt(APC / "intrinsics.K.txt")
    color = np.full((48, 64, 3), 200, np.uint8)
    depth = np.full((48, 64), 700, np.uint16)
    cam = Camera("cam0", 64, 48, K, None, "unknown")
    with RecordingWriter(tmp_path / "s", [cam], None, 30.0, {"kind": "sensor"}, depth_scale=0.001) as w:
        for t in (10.0, 10.5):
            w.append(color, depth, t)
        with pytest.raises(KeyboardInterrupt):
            w.append(color, _CutOff(), 11.0)
        assert w.frames_written == 2
    rec = Recording.open(tmp_path / "s")
    rec.validate()  # no colour picture without its depth
    assert rec.n_frames == 2 and np.allclose(rec.timestamps_s, [0.0, 0.5])
    assert np.array_equal(rec.depth_raw("cam0", 1), depth)


def test_stream_writer_takes_one_camera_without_per_frame_poses(tmp_path):
    from spare_twin.errors import SpareTwinError
    from spare_twin.recording import Camera, RecordingWriter

    K = np.eye(3)
    moving = Camera("cam0", 64, 48, K, None, "per_frame")
    with pytest.raises(SpareTwinError, match="stream of unknown length"):
        RecordingWriter(tmp_path / "s", [moving], None, 30.0, {"kind": "sensor"})
    fixed = Camera("cam0", 64, 48, K, np.eye(4), "fixed")
    with pytest.raises(SpareTwinError, match="append is for streams"):
        with RecordingWriter(tmp_path / "f", [fixed], 1, 30.0, {"kind": "sensor"}) as w:
            w.append(np.zeros((48, 64, 3), np.uint8), np.zeros((48, 64), np.uint16), 0.0)
    assert not (tmp_path / "f").exists() and not list(tmp_path.iterdir())
