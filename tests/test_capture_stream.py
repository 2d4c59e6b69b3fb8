"""The live / .bag stream writer without hardware: frames as they come, Ctrl-C keeps them all."""

import types

import cv2
import numpy as np
import pytest
from capture_helpers import APC, APC_FRAMES


def _frames(n_before_interrupt):
    import open3d as o3d

    for k in range(n_before_interrupt):
        n = APC_FRAMES[k % len(APC_FRAMES)]
        color = cv2.cvtColor(cv2.imread(str(APC / f"frame-{n:06d}.color.png")), cv2.COLOR_BGR2RGB)
        depth = cv2.imread(str(APC / f"frame-{n:06d}.depth.png"), cv2.IMREAD_UNCHANGED)
        yield o3d.t.geometry.RGBDImage(
            o3d.t.geometry.Image(o3d.core.Tensor(color)), o3d.t.geometry.Image(o3d.core.Tensor(depth[..., None]))
        )
    raise KeyboardInterrupt  # the user presses Ctrl-C


def _metadata():
    K = np.loadtxt(APC / "intrinsics.K.txt")
    return types.SimpleNamespace(
        intrinsics=types.SimpleNamespace(intrinsic_matrix=K),
        width=640,
        height=480,
        depth_scale=1000.0,
        fps=30.0,
        device_name="fake",
    )


def test_ctrl_c_finalises_with_every_frame(tmp_path, capsys):
    from spare_twin.capture.record import stream_to_recording
    from spare_twin.recording import Recording

    clock = iter(np.arange(100) / 30.0 + 5.0)
    opts = types.SimpleNamespace(max_frames=None, stride=1, progress=False)
    rec = stream_to_recording(
        _frames(3),
        _metadata(),
        tmp_path / "live",
        {"kind": "sensor", "layout": "live"},
        opts,
        None,
        lambda: next(clock),
    )
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
        stream_to_recording(_frames(0), _metadata(), tmp_path / "live", {"kind": "sensor"}, opts, None, lambda: 0.0)
    assert not (tmp_path / "live").exists() and not list(tmp_path.iterdir())
