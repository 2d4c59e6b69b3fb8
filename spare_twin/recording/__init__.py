"""The recording format: one folder layout that the twin simulation and the capture tools both write,
and that `predict`, `compare` and the Rerun logger read.

Layout (all paths relative to the recording folder)::

    recording.json                      metadata, below
    cameras/<cam>/color/000000.png      8-bit RGB
    cameras/<cam>/depth/000000.png      uint16, depth_m = value * depth_scale, 0 = no reading (z-depth)
    cameras/<cam>/segmentation/000000.png   uint8, 0 = background, k = link k-1 (sim only, optional)
    cameras/<cam>/T_world_camera.npy    float64 (frames, 4, 4), only for cameras that move
    ground_truth.npz                    sim only, optional: joint_angles_rad (frames, n),
                                        T_world_link (frames, n + 1, 4, 4), link_lengths_pu (n + 1,) in paper units,
                                        n_links, print_scale; T_world_camera when poses are hidden

recording.json keys: ``format`` ("spare-twin-recording"), ``version`` (1), ``frames`` (int),
``fps`` (float), ``depth_scale`` (metres per depth unit), ``timestamps_s`` (one per frame),
``source`` ({"kind": "sim" | "sensor", "sensor_model": str, ...}), ``object`` (the object.json
configuration, or null), ``rig`` (name of the training rig the cameras are, or null) and
``cameras``: a list of {``name``, ``width``, ``height``, ``K`` (3x3, pixels), ``T_world_camera``
(4x4 camera-to-world, OpenCV axes: x right, y down, z forward; null when per-frame or unknown),
``poses`` ("fixed" | "per_frame" | "unknown")}.

``registration`` (written by `capture register`, see `Registration`) and ``calibration`` (by
`capture calibrate`) are added by in-place updates. A registration keeps the poses a camera had
before as ``cameras/<cam>/T_world_camera.reference.npy``.

Every camera has a picture for every frame. Writers go through the output rule
(`spare_twin.output.writing`): the folder is built under a temporary name and swapped into place, so an
existing recording is never half-overwritten, and a new one never replaces what is not an earlier output
of the same command (unless forced). `Recording.open` checks every key's type and range, one-line errors.

This package is the only code that knows the layout: `format` (constants, `Camera`, `Registration`,
byte encodings), `reader` (`Recording`), `writer` (`RecordingWriter`, `update_recording`).
"""

from spare_twin.recording.format import (
    FORMAT,
    POSES,
    REFERENCE_POSES,
    SIM_DEPTH_SCALE,
    VERSION,
    Camera,
    Registration,
    depth_to_uint16,
    frame_file_name,
    npy_bytes,
    npz_bytes,
)
from spare_twin.recording.reader import Recording
from spare_twin.recording.writer import RecordingWriter, update_recording

__all__ = [
    "FORMAT",
    "POSES",
    "REFERENCE_POSES",
    "SIM_DEPTH_SCALE",
    "VERSION",
    "Camera",
    "Recording",
    "RecordingWriter",
    "Registration",
    "depth_to_uint16",
    "frame_file_name",
    "npy_bytes",
    "npz_bytes",
    "update_recording",
]
