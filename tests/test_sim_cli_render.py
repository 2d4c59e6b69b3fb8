"""`spare-twin render`: a complete recording that the recording reader returns."""

import json

import numpy as np
import pytest

from spare_twin.cli import main
from spare_twin.object import folder as objects
from spare_twin.recording import Recording


def test_render_writes_a_complete_recording(tmp_path, capsys):
    from spare_twin.config import sample_chain

    obj = objects.build_object(sample_chain(2, 5), tmp_path / "obj", preview=False)
    rc = main(["render", str(obj.root), "--out", str(tmp_path / "rec"), "--frames", "3", "--resolution", "network"])
    assert rc == 0
    assert "wrote" in capsys.readouterr().out
    rec = Recording.open(tmp_path / "rec")
    rec.validate()
    assert rec.n_frames == 3 and len(rec.cameras) == 8 and rec.fps == 10.0
    assert rec.source["kind"] == "sim" and rec.rig == "spare8"
    assert rec.object_config["n_links"] == 2
    cam = rec.cameras[0]
    assert (cam.height, cam.width) == (96, 128) and cam.T_world_camera.shape == (4, 4)
    d = rec.depth_m("cam0", 2)
    seg = rec.segmentation("cam0", 2)
    assert d.dtype == np.float32 and 0.2 < d[d > 0].min() < 0.6 and set(np.unique(seg)) <= {0, 1, 2, 3}
    assert (seg > 0).any() and (d[seg > 0] > 0).all()
    gt = rec.ground_truth()
    assert gt["joint_angles_rad"].shape == (3, 2) and gt["T_world_link"].shape == (3, 3, 4, 4)
    assert np.allclose(gt["link_lengths_m"], obj.spec.link_lengths_pu)
    meta = json.loads((tmp_path / "rec" / "recording.json").read_text())
    assert meta["format"] == "spare-twin-recording"


def test_render_bad_object_dir_is_one_line_error(tmp_path, capsys):
    assert main(["render", str(tmp_path / "nope"), "--out", str(tmp_path / "rec")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope" in err[0]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--frames", "0"], "--frames 0: must be a whole number, at least 1"),
        (["--fps", "-1"], "--fps -1.0: must be a positive number"),
        (["--fps", "inf"], "--fps inf: must be a positive number"),
        (["--seed", "-1"], "--seed -1: must be a non-negative integer"),
        (["--resolution", "8x8"], "--resolution '8x8': width and height must be within 16..4096"),
        (["--rig", "nope"], "--rig 'nope': no such rig"),
        (["--noise", "nope"], "--noise 'nope': no such noise model"),
        (["--hide-poses"], "--hide-poses: only for a hand-held path"),
    ],
)
def test_bad_options_are_one_line_errors_naming_the_flag(tmp_path, capsys, argv, message):
    from spare_twin.config import sample_chain

    obj = objects.build_sim_twin(sample_chain(1, 0), tmp_path / "obj")
    assert main(["render", str(obj.root), "--out", str(tmp_path / "rec"), *argv]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "rec").exists()
