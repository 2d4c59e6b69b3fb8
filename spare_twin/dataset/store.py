"""The sharded HDF5 store: one file per sequence (`sequences/seq-NNNNNN.h5`), written under a
temporary name and renamed into place, so a file that exists is complete.

Schema (readable with plain h5py; V cameras, T frames, H x W pixels, n moving links):

    depth              uint16 (V, T, H, W)  z-depth, metres = value * attrs["depth_scale"], 0 = no reading
    grey               uint8  (V, T, H, W)  BT.601 luma of the rendered colour image
    segmentation       uint8  (V, T, H, W)  optional: 0 background / table / clutter, k = link k - 1
    K                  float64 (V, 3, 3)    pinhole intrinsics at H x W (pixels, OpenCV)
    T_world_camera     float64 (V, 4, 4)    camera-to-world, metres, OpenCV axes (x right, y down, z forward)
    joint_angles_rad   float64 (T, n)       joint k = column k - 1
    T_world_link       float64 (T, n + 1, 4, 4)  link frames (link 0 = base), world z up, table z = 0
    link_lengths_pu    float64 (n + 1,)     paper units, base first (physical = * attrs["print_scale"])
    lengths_label_pu   float32 (7,)         the paper's 7-slot label in paper units, zeros past the last link

Attributes: format ("spare-twin-sequence/1"), index, dataset_seed, n_links, split, print_scale,
depth_scale, fps, chain (the object.json ChainSpec as JSON), scene (lighting / colours / clutter as
JSON). Images are chunked one image per chunk (1, 1, H, W), gzip (deflate) level 1 with the shuffle
filter: any single image is read by decompressing ~10 KB, and both the multi-view (8 cameras at
one t) and temporal (100 frames of one camera) reads touch only the images they return.

Files are byte-for-byte deterministic: no timestamps (track_times=False), fixed attribute order and
the same library versions give the same bytes. Files from before 0.6.0 name the label
`lengths_label_m` (paper units all the same); `lengths_label_pu` reads either.
"""

from __future__ import annotations

import json
import os
import socket
from pathlib import Path

import numpy as np

SEQUENCE_FORMAT = "spare-twin-sequence/1"
IMAGE_KEYS = ("depth", "grey", "segmentation")


def sequence_filename(index: int) -> str:
    return f"seq-{index:06d}.h5"


def write_sequence(path: str | Path, seq, fps: float, compression_level: int = 1) -> None:
    """Write a generate.Sequence to `path` atomically (temporary name in the same folder, rename)."""
    import h5py

    path = Path(path)
    # host and pid: writers on several nodes of a cluster may share the folder
    tmp = path.with_name(f".{path.name}.tmp-{socket.gethostname()}-{os.getpid()}")
    try:
        with h5py.File(tmp, "w", libver=("earliest", "v110"), track_order=False) as f:
            V, T, H, W = seq.depth.shape
            for key in IMAGE_KEYS:
                arr = getattr(seq, key)
                if arr is None:
                    continue
                f.create_dataset(
                    key,
                    data=arr,
                    chunks=(1, 1, H, W),
                    compression="gzip",
                    compression_opts=compression_level,
                    shuffle=arr.dtype.itemsize > 1,
                    track_times=False,
                )
            small = {
                "K": np.asarray(seq.K, np.float64),
                "T_world_camera": np.asarray(seq.T_world_camera, np.float64),
                "joint_angles_rad": np.asarray(seq.joint_angles_rad, np.float64),
                "T_world_link": np.asarray(seq.T_world_link, np.float64),
                "link_lengths_pu": np.asarray(seq.spec.link_lengths_pu, np.float64),
                LABEL_KEY: seq.spec.label_lengths().astype(np.float32),
            }
            for key, arr in small.items():
                f.create_dataset(key, data=arr, track_times=False)
            attrs = {
                "format": SEQUENCE_FORMAT,
                "index": int(seq.index),
                "dataset_seed": int(seq.seed),
                "n_links": int(seq.spec.n_links),
                "split": seq.split,
                "print_scale": float(seq.spec.print_scale),
                "depth_scale": float(seq.depth_scale),
                "fps": float(fps),
                "chain": seq.spec.to_json(),
                "scene": json.dumps(seq.scene, sort_keys=True),
            }
            for k, v in attrs.items():
                f.attrs[k] = v
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


#: The label's key, and its name in files from before 0.6.0 (a misnomer: the values were paper units).
LABEL_KEY, OLD_LABEL_KEY = "lengths_label_pu", "lengths_label_m"


def lengths_label_pu(f) -> np.ndarray:
    """float32 (7,) the paper's length label of an open sequence file, in paper units, whichever
    release wrote it."""
    return f[LABEL_KEY if LABEL_KEY in f else OLD_LABEL_KEY][()]


#: The small arrays of a sequence file and their leading dimensions (V cameras, T frames).
_SMALL = {"K": "V", "T_world_camera": "V", "joint_angles_rad": "T", "T_world_link": "T"}


def shard_problem(
    path: str | Path, index: int, cameras: int, frames: int, height: int, width: int, segmentation: bool = True
) -> str | None:
    """Why sequence file `path` does not read back as sequence `index` of this size, or None when it does.

    Cheap (a few milliseconds): it opens the file, checks its format, index and array shapes, and
    decompresses the last image of each image array, the bytes a truncated file loses first."""
    import h5py

    want = (cameras, frames, height, width)
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != SEQUENCE_FORMAT:
                return f"not a {SEQUENCE_FORMAT} file"
            if int(f.attrs.get("index", -1)) != index:
                return f"holds sequence {f.attrs.get('index')}, not {index}"
            for key in IMAGE_KEYS:
                if key not in f:
                    if key == "segmentation" and not segmentation:
                        continue
                    return f"no {key} images"
                if f[key].shape != want:
                    return f"{key} has shape {f[key].shape}, expected {want}"
                f[key][-1, -1]  # noqa: B018  (read: a truncated or garbled file fails here)
            for key, dim in _SMALL.items():
                if key not in f:
                    return f"no {key}"
                if f[key].shape[0] != (cameras if dim == "V" else frames):
                    return f"{key} has shape {f[key].shape}"
                f[key][()]  # noqa: B018
    except (OSError, KeyError, ValueError, RuntimeError, TypeError) as exc:
        return f"unreadable: {' '.join(str(exc).split())[:120]}"
    return None
