"""A small analytic stand-in for the twin simulation: SPARE chains as capsules, ray-cast into an
8-camera depth/grey rig. It yields exactly the docs/design.md sample dict, so the networks, training,
evaluation and prediction can be developed and tested without pybullet or a stored dataset.

Geometry follows docs/design.md: world z up, table at z = 0, joints about +y, link k in its own layer
at y = k * 6.4 mm, link k's length along its own +z, physical size = paper length * print_scale.
Every sample is a pure function of (seed, split, index).

A synthetic data folder is just ``synthetic.json`` ({"format": "spare-twin-synthetic", ...}); the
samples are rendered on demand (and cached), so tests need no large files.
"""

from __future__ import annotations

import json
import math
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch.utils.data as _tud

from spare_twin.config import PartDims, sample_lengths
from spare_twin.dataset.streams import stream_indices
from spare_twin.errors import SpareTwinError
from spare_twin.io import read_json
from spare_twin.sim.rig import Rig

FORMAT = "spare-twin-synthetic"
RIG_NAME = "synthetic-ring8"
LAYER_PITCH_M = PartDims().layer_pitch_mm / 1000.0
LINK_RADIUS_M = PartDims().link_width_mm / 2000.0
KEEPOUT_M = (PartDims().foot_thickness_mm + PartDims().socket_height_mm) / 1000.0  # links stay above it
GREY_OF_COLOUR = [0.08, 0.95, 0.35, 0.6, 0.3, 0.45, 0.8, 0.2]  # luminance of the paper's 8 colours


@dataclass(frozen=True)
class SyntheticSpec:
    """What a synthetic data folder holds."""

    mode: str = "mv"
    """mv (8 views of one time step) or tmp (`frames` frames of one camera)."""
    input: str = "depth"
    frames: int = 100
    """tmp only: frames per sequence."""
    sizes: tuple[tuple[str, int], ...] = (("train", 256), ("val", 64), ("test", 64))
    seed: int = 0
    print_scale: float = 0.08
    n_range: tuple[int, int] = (1, 6)


def synthetic_rig() -> Rig:
    """The synthetic 8-camera ring: 0.36 m from the axis, 0.18 m high, aimed at (0, 0, 0.12), f = 125 px at
    96 x 128. Camera 0 stands at 22.5 deg so that no camera looks exactly along the chain's plane."""
    return Rig(
        name=RIG_NAME,
        radius_m=0.36,
        heights_m=(0.18,),
        look_at_m=(0.0, 0.0, 0.12),
        azimuth0_deg=22.5,
        fov_y_deg=math.degrees(2 * math.atan(48.0 / 125.0)),
    )


def rig() -> tuple[np.ndarray, np.ndarray]:
    """The synthetic ring as arrays: K (3, 3) at 96 x 128 and the camera-to-world poses (8, 4, 4)."""
    ring = synthetic_rig()
    return ring.K(), ring.poses()


def chain_segments(lengths_pu: np.ndarray, angles_rad: np.ndarray, print_scale: float) -> list[tuple]:
    """(start, end) world points per link: base upright at the origin, link k at y = k * pitch."""
    segs = [(np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, lengths_pu[0] * print_scale]))]
    p = segs[0][1].copy()
    theta = 0.0
    for k, q in enumerate(angles_rad, start=1):
        theta += q
        d = np.array([np.sin(theta), 0.0, np.cos(theta)])
        start = np.array([p[0], k * LAYER_PITCH_M, p[2]])
        end = start + lengths_pu[k] * print_scale * d
        segs.append((start, end))
        p = end
    return segs


def _valid_pose(segs) -> bool:
    return all(min(a[2], b[2]) > KEEPOUT_M + LINK_RADIUS_M for a, b in segs[1:])


def sample_angles(n: int, rng: np.random.Generator, lengths, print_scale, tries: int = 60) -> np.ndarray:
    for _ in range(tries):
        q = rng.uniform(-1.4, 1.4, size=n)
        if _valid_pose(chain_segments(lengths, q, print_scale)):
            return q
    return rng.uniform(-0.2, 0.2, size=n)


def render(segs, colours, K, T_world_camera, height=96, width=128, table_radius_m=0.35):
    """Ray-cast capsules and the table disc: (z-depth m, grey 0..1), each (H, W)."""
    v, u = np.mgrid[0:height, 0:width]
    d_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, float)], -1).reshape(-1, 3)
    norm = np.linalg.norm(d_cam, axis=1)
    rd = (d_cam / norm[:, None]) @ T_world_camera[:3, :3].T
    ro = T_world_camera[:3, 3]
    t_best = np.full(rd.shape[0], np.inf)
    grey = np.zeros(rd.shape[0])
    shade_n = np.zeros((rd.shape[0], 3))
    r = LINK_RADIUS_M
    for (a, b), col in zip(segs, colours):
        # Cull rays that miss the capsule's bounding sphere (most of the image), then intersect the rest
        # in closed form: cylinder body, then the end spheres.
        centre, rad = (a + b) / 2, np.linalg.norm(b - a) / 2 + r
        oc0 = ro - centre
        proj = rd @ oc0
        near = np.flatnonzero(proj * proj - (oc0 @ oc0 - rad * rad) > 0)
        if near.size == 0:
            continue
        rdn = rd[near]
        ba, oa = b - a, ro - a
        baba, baoa = ba @ ba, ba @ oa
        bard, rdoa, oaoa = rdn @ ba, rdn @ oa, oa @ oa
        A = baba - bard * bard
        Bq = baba * rdoa - baoa * bard
        C = baba * oaoa - baoa * baoa - r * r * baba
        h = Bq * Bq - A * C
        t = np.full(near.size, np.inf)
        ok = (h >= 0) & (A > 1e-12)
        tb = np.where(ok, (-Bq - np.sqrt(np.maximum(h, 0))) / np.where(A > 1e-12, A, 1), np.inf)
        y = baoa + tb * bard
        body = ok & (y > 0) & (y < baba) & (tb > 0)
        t[body] = tb[body]
        for cap in (a, b):
            oc = ro - cap
            bb = rdn @ oc
            hh = bb * bb - (oc @ oc - r * r)
            tc = np.where(hh > 0, -bb - np.sqrt(np.maximum(hh, 0)), np.inf)
            tc = np.where(tc > 0, tc, np.inf)
            t = np.minimum(t, tc)
        closer_local = t < t_best[near]
        closer = near[closer_local]
        t_best[closer] = t[closer_local]
        hit = ro + t[closer_local, None] * rd[closer]
        s = np.clip(((hit - a) @ ba) / baba, 0, 1)
        nrm = hit - (a + s[:, None] * ba)
        shade_n[closer] = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-9)
        grey[closer] = col
    # table disc at z = 0
    with np.errstate(divide="ignore", invalid="ignore"):
        tt = np.where(rd[:, 2] < 0, -ro[2] / rd[:, 2], np.inf)
    hit = ro + np.where(np.isfinite(tt), tt, 0)[:, None] * rd
    table = np.isfinite(tt) & (np.hypot(hit[:, 0], hit[:, 1]) < table_radius_m) & (tt < t_best)
    t_best[table] = tt[table]
    shade_n[table] = [0, 0, 1]
    grey[table] = 0.5
    seen = np.isfinite(t_best)
    lambert = np.abs(np.sum(shade_n * rd, axis=1))
    grey_img = np.where(seen, grey * (0.35 + 0.65 * lambert), 0.0)
    depth = np.where(seen, t_best / norm, 0.0)
    return depth.reshape(height, width).astype(np.float32), grey_img.reshape(height, width).astype(np.float32)


def _rng(seed: int, split: str, index: int) -> np.random.Generator:
    return np.random.default_rng([seed, zlib.crc32(split.encode()), index])


def make_sample(spec: SyntheticSpec, split: str, index: int) -> dict[str, np.ndarray]:
    """One docs/design.md sample (numpy), a pure function of (spec.seed, split, index)."""
    rng = _rng(spec.seed, split, index)
    n = int(rng.integers(spec.n_range[0], spec.n_range[1] + 1))
    lengths = np.asarray(sample_lengths(n, rng))
    colours = [GREY_OF_COLOUR[int(i)] for i in rng.integers(0, 8, size=n + 1)]
    K, poses = rig()
    label = np.zeros(7, np.float32)
    label[: n + 1] = lengths
    out = {"n_links": np.int64(n), "lengths_pu": label, "print_scale": np.float32(spec.print_scale)}
    if spec.mode == "mv":
        q = sample_angles(n, rng, lengths, spec.print_scale)
        segs = chain_segments(lengths, q, spec.print_scale)
        imgs = [render(segs, colours, K, T)[0 if spec.input == "depth" else 1] for T in poses]
        angles = np.zeros(6, np.float32)
        angles[:n] = q
        out.update(
            x=np.stack(imgs),
            K=np.repeat(K[None], len(poses), 0).astype(np.float32),
            T_world_camera=poses.astype(np.float32),
            joint_angles_rad=angles,
        )
    else:
        cam = int(rng.integers(0, len(poses)))
        q0 = sample_angles(n, rng, lengths, spec.print_scale)
        amp, freq, phase = rng.uniform(0.2, 0.6, n), rng.uniform(0.05, 0.2, n), rng.uniform(0, 2 * np.pi, n)
        imgs, angles = [], np.zeros((spec.frames, 6), np.float32)
        for f in range(spec.frames):
            q = q0 + amp * np.sin(2 * np.pi * freq * f / 10.0 + phase)  # 10 fps
            segs = chain_segments(lengths, q, spec.print_scale)
            if not _valid_pose(segs):  # hold the last valid pose rather than pass through the table
                q = angles[f - 1, :n] if f else q0
                segs = chain_segments(lengths, q, spec.print_scale)
            angles[f, :n] = q
            imgs.append(render(segs, colours, K, poses[cam])[0 if spec.input == "depth" else 1])
        out.update(
            x=np.stack(imgs),
            K=K[None].astype(np.float32),
            T_world_camera=poses[cam][None].astype(np.float32),
            joint_angles_rad=angles,
        )
    return out


def write_synthetic(root: str | Path, spec: SyntheticSpec = SyntheticSpec()) -> Path:
    """Create a synthetic data folder (only its description: samples render on demand)."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    d = asdict(spec)
    d["format"] = FORMAT
    d["rig"] = RIG_NAME
    (root / "synthetic.json").write_text(json.dumps(d, indent=2) + "\n")
    return root


def read_spec(root: str | Path) -> SyntheticSpec:
    d = read_json(Path(root) / "synthetic.json")
    d.pop("format", None)
    d.pop("rig", None)
    d["sizes"] = tuple((str(a), int(b)) for a, b in d["sizes"])
    d["n_range"] = tuple(d["n_range"])
    return SyntheticSpec(**d)


class SyntheticDataset:
    """torch-style map Dataset over one split of a synthetic folder; renders lazily, caches samples."""

    def __init__(self, spec: SyntheticSpec, split: str, cache: bool = True):
        sizes = dict(spec.sizes)
        if split not in sizes:
            raise SpareTwinError(f"synthetic data has no split {split!r} (has {', '.join(sizes)})")
        self.spec, self.split, self.n = spec, split, sizes[split]
        self._cache: dict[int, dict] | None = {} if cache else None

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> dict:
        import torch

        if i < 0 or i >= self.n:
            raise IndexError(i)
        if self._cache is not None and i in self._cache:
            s = self._cache[i]
        else:
            s = make_sample(self.spec, self.split, int(i))
            if self._cache is not None:
                self._cache[i] = s
        return {k: torch.as_tensor(v) for k, v in s.items()}

    @property
    def labels_n(self) -> np.ndarray:
        return np.array(
            [
                int(_rng(self.spec.seed, self.split, i).integers(self.spec.n_range[0], self.spec.n_range[1] + 1))
                for i in range(self.n)
            ]
        )


class SyntheticOnTheFly(_tud.IterableDataset):
    """Endless fresh synthetic samples (split "fresh"): a different stream per data-loader worker and per
    training process (`rank` of `world_size` under torchrun), as in dataset.torch_data.OnTheFlyDataset."""

    def __init__(self, spec: SyntheticSpec, seed: int, rank: int = 0, world_size: int = 1):
        super().__init__()
        self.spec = SyntheticSpec(**{**asdict(spec), "seed": seed})
        self.rank, self.world_size = rank, world_size

    def __iter__(self):
        import torch

        info = _tud.get_worker_info()
        wid, nw = (info.id, info.num_workers) if info else (0, 1)
        for i in stream_indices(self.rank, self.world_size, wid, nw, None):
            yield {k: torch.as_tensor(v) for k, v in make_sample(self.spec, "fresh", i).items()}
