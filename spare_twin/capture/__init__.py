"""Real capture: sensors and importers, rig calibration, registration, fusion, the object, Rerun view.

Modules (each imports open3d / opencv / rerun only where used):

- `checks`       range checks of settings (one-line errors naming the field).
- `frames`       RGB-D frame helpers: depth sanity checks, intrinsics, resizing, back-projection.
- `layouts`      listing the frames of a 7-Scenes / tsdf-fusion, TUM RGB-D or Open3D-recorder folder.
- `bag`          RealSense `.bag` files, read from the file (rosbags): colour and depth paired by time.
- `align`        depth resampled into another camera's grid (a RealSense's depth into its colour).
- `importers`    those folders and `.bag` files into a recording (`spare_twin.recording`), every frame
                 checked before anything is written, keeping the sensor's depth scale.
- `record`       live capture from an Intel RealSense through open3d, and the stream writer it shares
                 with the .bag import.
- `board`        ChArUco board: generation at true print size, detection, camera pose, depth refinement.
- `calibrate`    `calibrate_recording`: each camera's fixed pose from the board, written atomically.
- `registration` camera poses from RGB-D frames: FPFH + RANSAC, ICP, pose-graph optimisation.
- `fusion`       TSDF fusion of a registered recording into one coloured point cloud (and mesh).
- `segment`      table plane, object cluster, the object frame (z up, table z = 0).
- `pipeline`     `register_recording` (poses + fusion + object, written atomically into the recording;
                 returns a `RegisterResult`) and `fuse_recording(rec) -> (points, colors, T_world_object)`.
- `export`       one camera of a recording as a 7-Scenes folder.
- `simulated`    the twin captured by a simulated hand-held sensor and brought in as a real capture is.
- `view`         Rerun logging of a recording (cameras, colour, depth, fused cloud).
- `bench`        `bench_registration`: accuracy and speed on the APC shelf frames.

Reading and writing recordings goes through `spare_twin.recording` only (`Recording`,
`RecordingWriter`, `update_recording`, the typed `Registration`).
"""
