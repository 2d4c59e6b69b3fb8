"""Write one camera of a recording as a 7-Scenes / tsdf-fusion folder, the layout many RGB-D tools read
(and `spare-twin capture import --layout 7scenes` reads back):

    frame-NNNNNN.color.png    8-bit colour
    frame-NNNNNN.depth.png    uint16 millimetres, 0 = no reading
    frame-NNNNNN.pose.txt     4x4 camera-to-world (only when the recording knows the poses)
    camera-intrinsics.txt     3x3 K
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from spare_twin.io import encode_png, write_bytes_atomic
from spare_twin.output import writing
from spare_twin.recording import Recording, depth_to_uint16


def export_7scenes(rec_dir, out_dir, camera: str | None = None, poses: bool = True, force: bool = False) -> Path:
    """`out_dir` follows the output rule (`spare_twin.output`); `force` replaces what it would refuse."""
    import cv2

    rec = Recording.open(rec_dir)
    cam = rec.camera(camera or rec.cameras[0].name)
    with writing(out_dir, "capture export", inputs=[rec_dir], force=force) as tmp:
        np.savetxt(tmp / "camera-intrinsics.txt", cam.K, fmt="%.9f")
        for f in range(rec.n_frames):
            stem = tmp / f"frame-{f:06d}"
            write_bytes_atomic(
                stem.with_suffix(".color.png"), encode_png(cv2.cvtColor(rec.color(cam.name, f), cv2.COLOR_RGB2BGR))
            )
            write_bytes_atomic(
                stem.with_suffix(".depth.png"), encode_png(depth_to_uint16(rec.depth_m(cam.name, f), 0.001))
            )
            T = rec.T_world_camera(cam.name, f) if poses else None
            if T is not None:
                np.savetxt(stem.with_suffix(".pose.txt"), T, fmt="%.9f")
    return Path(out_dir)
