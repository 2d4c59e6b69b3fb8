"""Analytic profile samples: a printed chain drawn straight into the profile frame as points on its
plates, with a real print's and a hand-held sensor's effects, for training the profile network.

A hand-held capture costs about 20 s of a core to draw and observe (`dataset --handheld`); one of
these costs about 90 ms (4 ms to draw, the rest the layers' readings that level its image as
`predict` levels a capture's), so tens of thousands of them train the network on what a real
capture shows: each link leaning out of the chain's plane by its joint play, so that a long link's
plate runs across layers. Sample i of seed S:

1. the chain: n = i % 6 + 1 moving links, `config.sample_chain` with chain seed
   `ANALYTIC_SEED_BASE + S * SEED_STRIDE + i` (never a bench or hand-held seed), held in one pose of the
   simulator's random motion (`sim.motion.random_motion`, as a hand-held capture holds it);
2. the print (`sim.effects.CaptureEffects`' ranges, as `sim.print_physics` draws them): each link tilted
   out of the plane about its own x axis, each joint centre shifted within the pin's clearance, the
   whole object scaled by its shrink and standing off level;
3. what a sweep sees of it (`AnalyticProfileConfig`): the plates' faces on the camera's side, a share
   of those on the far side and of their rims; where a nearer plate covers a farther one, most of the
   farther one's points hidden; dark links returning a fraction of their points; depth noise across
   the plane (a few in 100 points three times as far off), noise in it, views slightly out of
   register (a small offset and turn each), holes, stray points strung out across the plane (flying
   pixels the cleaning missed), and the profile frame found a little off (base axis, plane direction);
4. the image: `observe.profile.draw_profile` of the points levelled by their layers' comb
   (`measure.level`), as `predict` draws a capture's points for the network.

Labels as `dataset --handheld`'s: the count, the nominal 7-slot lengths (paper units) and the held
joint angles. The appearance ranges of step 3 were set so that the samples' statistics match those of
600 hand-held captures (cells occupied per image, t extent per cell; docs/nets.md); none of the
bench's captures was looked at for them.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from spare_twin.config import ChainSpec, sample_chain
from spare_twin.dataset.backends import start_pool
from spare_twin.io import write_bytes_atomic, write_json_atomic
from spare_twin.measure.layers import LayersConfig, read_layers
from spare_twin.nets.profile_analytic_config import (
    ANALYTIC_SEED_BASE,
    CHUNK,
    SEED_STRIDE,
    AnalyticProfileConfig,
    check_analytic,
    split_of,
)
from spare_twin.nets.sample_folders import ANALYTIC_KIND, HANDHELD_FORMAT, SPLIT_CODES
from spare_twin.object.kinematics import joint_limits_rad, keepout_height_m, printed_lengths_m, rot_y
from spare_twin.observe.profile import ProfileConfig, draw_profile
from spare_twin.output import writing
from spare_twin.recording import npz_bytes
from spare_twin.sim.motion import MotionConfig, random_motion
from spare_twin.sim.rig import axis_angle


def _turned(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """4x4 rotation about the unit vector `axis` through the origin."""
    T = np.eye(4)
    T[:3, :3] = axis_angle(axis, angle_rad)
    return T


def _plate(rng: np.random.Generator, z0: float, z1: float, m: int, half_w: float) -> tuple[np.ndarray, np.ndarray]:
    """m points uniform on a stadium: the segment z0..z1 on x = 0 thickened by `half_w`."""
    rect, disc = 2 * half_w * (z1 - z0), math.pi * half_w**2
    k = int(round(m * rect / (rect + disc)))
    r, a = half_w * np.sqrt(rng.random(m - k)), rng.uniform(0, 2 * math.pi, m - k)
    dz = r * np.sin(a)
    x = np.concatenate([rng.uniform(-half_w, half_w, k), r * np.cos(a)])
    z = np.concatenate([rng.uniform(z0, z1, k), np.where(dz >= 0, dz + z1, dz + z0)])
    return x, z


def _rim(rng: np.random.Generator, z0: float, z1: float, m: int, half_w: float) -> tuple[np.ndarray, np.ndarray]:
    """m points on the stadium's outline."""
    length = z1 - z0
    u = rng.uniform(0, 2 * length + 2 * math.pi * half_w, m)
    side = u < 2 * length
    a = (u - 2 * length) / half_w
    x = np.where(side, np.where(u < length, half_w, -half_w), half_w * np.cos(a))
    arc_z = np.where(np.sin(a) >= 0, z1, z0) + half_w * np.sin(a)
    z = np.where(side, z0 + np.mod(u, max(length, 1e-9)), arc_z)
    return x, z


def _link_frames(rng, spec, angles_rad, c: AnalyticProfileConfig) -> list[np.ndarray]:
    """Links 0..n's frames in the object frame, with joint play and the base standing off level."""
    n = spec.n_links
    lengths = printed_lengths_m(spec)
    tilt = np.radians(np.where(rng.random(n) < 0.5, -1.0, 1.0) * rng.uniform(*c.joint_tilt_deg, size=n))
    shift = c.joint_shift_mm / 1000.0 * np.sqrt(rng.random(n))
    shift_dir = rng.uniform(0, 2 * math.pi, n)
    az = rng.uniform(0, 2 * math.pi)
    frames = [_turned(np.array([math.cos(az), math.sin(az), 0.0]), math.radians(rng.uniform(*c.level_error_deg)))]
    for k in range(1, n + 1):
        T = np.eye(4)
        T[:3, 3] = (
            shift[k - 1] * math.cos(shift_dir[k - 1]),
            spec.layer_pitch_mm / 1000.0,
            lengths[k - 1] + shift[k - 1] * math.sin(shift_dir[k - 1]),
        )
        frames.append(frames[-1] @ T @ rot_y(angles_rad[k - 1]) @ _turned(np.array([1.0, 0.0, 0.0]), tilt[k - 1]))
    return frames


def _seen_points(rng, spec, frames, c: AnalyticProfileConfig) -> tuple[np.ndarray, np.ndarray, float]:
    """(N, 3) points of the plates a sweep sees (object frame, metres), (N,) the link of each and the
    camera's side of the plane (+1: larger t)."""
    n = spec.n_links
    lengths = printed_lengths_m(spec)
    half_w, half_t = spec.parts.link_width_mm / 2000.0, spec.parts.link_thickness_mm / 2000.0
    side = 1.0 if rng.random() < 0.5 else -1.0  # the camera's side of the plane
    far = c.far_face_share[0] + (c.far_face_share[1] - c.far_face_share[0]) * rng.random() ** 2
    rim = rng.uniform(*c.rim_share)
    density = rng.uniform(*c.points_per_m2)
    points, links = [], []
    for k in range(n + 1):
        z0 = spec.parts.foot_thickness_mm / 1000.0 if k == 0 else 0.0
        z1 = lengths[k] if k < n else max(lengths[k] - half_w, 0.0)
        area = 2 * half_w * (z1 - z0) + math.pi * half_w**2
        keep = rng.uniform(*c.dark_return) if rng.random() < c.dark_link_prob else 1.0
        for t, share in ((side * half_t, 1.0), (-side * half_t, far), (None, rim)):
            m = int(rng.poisson(density * area * share * keep))
            x, z = (_rim if t is None else _plate)(rng, z0, z1, m, half_w)
            y = rng.uniform(-half_t, half_t, m) if t is None else np.full(m, t)
            local = np.stack([x, y, z, np.ones(m)], 1)
            points.append((frames[k] @ local.T).T[:, :3])
            links.append(np.full(m, k))
    m = int(rng.poisson(density * 0.0008))  # the foot's socket boss round the base post, 5-17 mm up
    boss = np.stack([rng.uniform(-0.009, 0.009, m), rng.uniform(-0.006, 0.006, m), rng.uniform(0.005, 0.017, m)], 1)
    points.append(boss @ frames[0][:3, :3].T)
    links.append(np.zeros(m, np.int64))
    return np.concatenate(points), np.concatenate(links), side


def _hide_covered(rng, p: np.ndarray, link: np.ndarray, side: float, share: float) -> np.ndarray:
    """Points left once those behind a nearer link's plate (3 mm cells of the plane) are mostly hidden."""
    cell = np.floor(p[:, [0, 2]] / 0.003).astype(np.int64)
    _, cell_id = np.unique(cell, axis=0, return_inverse=True)
    nearness = link * side
    nearest = np.full(cell_id.max() + 1, -np.inf)
    np.maximum.at(nearest, cell_id.reshape(-1), nearness)
    hidden = (nearness < nearest[cell_id.reshape(-1)]) & (rng.random(len(p)) < share)
    return p[~hidden]


def _as_captured(rng, p: np.ndarray, c: AnalyticProfileConfig) -> np.ndarray:
    """The points as a sweep's fused, cleaned cloud holds them: out of register, noisy, holed, strayed,
    in a profile frame found a little off (x = s, y = t, z up)."""
    views = int(rng.integers(c.views[0], c.views[1] + 1))
    v = rng.integers(0, views, len(p))
    offset = rng.normal(0, rng.uniform(*c.view_offset_m), (views, 3))
    turn = rng.normal(0, math.radians(rng.uniform(*c.view_turn_deg)), views)
    p = p + offset[v]
    cos, sin = np.cos(turn[v]), np.sin(turn[v])
    p[:, 0], p[:, 1] = cos * p[:, 0] - sin * p[:, 1], sin * p[:, 0] + cos * p[:, 1]
    outlier = 1.0 + 2.0 * (rng.random(len(p)) < 0.05)
    p[:, 1] += rng.normal(0, rng.uniform(*c.noise_across_m), len(p)) * outlier
    p[:, [0, 2]] += rng.normal(0, rng.uniform(*c.noise_in_plane_m), (len(p), 2))
    for _ in range(int(rng.integers(0, c.holes + 1))):
        centre = p[rng.integers(len(p)), [0, 2]]
        p = p[np.linalg.norm(p[:, [0, 2]] - centre, axis=1) > rng.uniform(0.003, 0.012)]
    m = int(len(p) * rng.uniform(*c.stray_share))
    stray = p[rng.integers(0, len(p), m)].copy()
    stray[:, 1] += rng.normal(0, c.stray_across_m, m)
    stray[:, [0, 2]] += rng.normal(0, 0.003, (m, 2))
    p = np.concatenate([p, stray])
    p[:, :2] += rng.normal(0, c.base_axis_error_m)
    e = math.radians(rng.normal(0, c.plane_error_deg))
    p[:, 0], p[:, 1] = math.cos(e) * p[:, 0] - math.sin(e) * p[:, 1], math.sin(e) * p[:, 0] + math.cos(e) * p[:, 1]
    return p


def _levelled_t_m(points: np.ndarray, spec: ChainSpec) -> np.ndarray:
    """The points' t less their layers' comb's zero, as `predict` levels a capture's profile
    (`measure.level`); with no cameras' directions, each plate centre is read over both faces."""
    cfg = LayersConfig.for_parts(spec.parts)
    links = points[points[:, 2] > cfg.min_height_m]
    if len(links) > cfg.max_points:  # as many as the measurement reads (`measure_layers`)
        links = links[np.linspace(0, len(links) - 1, cfg.max_points).astype(np.int64)]
    _, zero = read_layers(links, None, cfg)
    return points[:, 1] if zero is None else zero.levelled_t_m(points[:, 0], points[:, 1], points[:, 2])


def analytic_sample(
    c: AnalyticProfileConfig, index: int, profile: ProfileConfig = ProfileConfig(), levelled: bool = True
) -> dict:
    """Sample `index` of `c` (module doc): {"x": float16 (3, H, W), "n", "lengths" (7,), "angles" (6,)};
    `levelled` False: the image of the points as captured, before their layers' comb levels them."""
    chain_seed = ANALYTIC_SEED_BASE + c.seed * SEED_STRIDE + index
    rng = np.random.default_rng(chain_seed)
    n = index % 6 + 1
    spec = sample_chain(n, seed=chain_seed)
    motion = MotionConfig(n_frames=int(rng.integers(15, 61)))
    held = random_motion(joint_limits_rad(spec), printed_lengths_m(spec), keepout_height_m(spec),
                         spec.parts.link_width_mm / 2000.0, rng, motion)  # fmt: skip
    angles = held[len(held) // 2]
    frames = _link_frames(rng, spec, angles, c)
    points, links, side = _seen_points(rng, spec, frames, c)
    points = _hide_covered(rng, points, links, side, c.hidden_share)
    points = _as_captured(rng, points * (1.0 + rng.uniform(*c.scale_error)), c)
    points = points[points[:, 2] > 0.004]  # the table cut
    pitch_m = spec.layer_pitch_mm / 1000.0
    s_pu, z_pu = points[:, 0] / spec.print_scale, points[:, 2] / spec.print_scale
    t_m = _levelled_t_m(points, spec) if levelled else points[:, 1]
    image = draw_profile(s_pu, z_pu, t_m / pitch_m, profile)
    padded = np.zeros(6, np.float32)
    padded[:n] = angles
    return {"x": image.astype(np.float16), "n": n, "lengths": spec.label_lengths(), "angles": padded}


def _chunk_job(args: tuple) -> int:
    """Write chunk `k` of `c` into `root/chunks` (runs in a worker process); returns its sample count."""
    root, c, k = args
    indices = range(k * CHUNK, min((k + 1) * CHUNK, c.samples))
    samples = [analytic_sample(c, i) for i in indices]
    arrays = {key: np.stack([np.asarray(s[key]) for s in samples]) for key in ("x", "n", "lengths", "angles")}
    arrays["split"] = np.array([SPLIT_CODES[split_of(i)] for i in indices], np.uint8)
    arrays["settings"] = _chunk_key(c, k)
    write_bytes_atomic(root / "chunks" / f"chunk{k:05d}.npz", npz_bytes(arrays))
    return len(indices)


def _chunk_key(c: AnalyticProfileConfig, k: int) -> np.ndarray:
    """What chunk k's samples depend on: the settings but the count, and how many of them it holds (so
    a larger --instances keeps every full chunk of a smaller one)."""
    settings = {**c.to_json(), "samples": min(CHUNK, c.samples - k * CHUNK)}
    return np.frombuffer(repr(settings).encode(), np.uint8)


def _chunk_done(path: Path, c: AnalyticProfileConfig, k: int) -> bool:
    """Whether `path` holds chunk k as `c` draws it (an earlier run's)."""
    try:
        with np.load(path) as z:
            return bytes(z["settings"]) == _chunk_key(c, k).tobytes()
    except (OSError, ValueError, KeyError):
        return False


def analytic_profiles(out: str | Path, c: AnalyticProfileConfig, workers: int = 1, progress: bool = True,
                      force: bool = False) -> dict:  # fmt: skip
    """Draw (or resume, or extend) the folder `out` of `c.samples` analytic samples (module doc):
    `samples.npz` and `manifest.json` in the format of `dataset --handheld`'s folders, which `train`
    reads beside the rig's datasets. Chunks of `CHUNK` samples (`chunks/`) are written whole as they are
    drawn and kept: an interrupted run goes on where it stopped, and a larger `samples` draws only the
    new ones. Returns the manifest."""
    check_analytic(out, c, workers, force)
    with writing(out, ANALYTIC_KIND, (), force, resumable=True) as tmp:
        (tmp / "chunks").mkdir(exist_ok=True)
        chunks = -(-c.samples // CHUNK)
        todo = [(tmp, c, k) for k in range(chunks) if not _chunk_done(tmp / "chunks" / f"chunk{k:05d}.npz", c, k)]
        done = c.samples - sum(min(CHUNK, c.samples - k * CHUNK) for _, _, k in todo)
        with tqdm(total=c.samples, initial=done, desc="analytic profiles", unit="sample", disable=not progress,
                  file=sys.stderr) as bar:  # fmt: skip
            if workers > 1 and len(todo) > 1:
                with start_pool(min(workers, len(todo))) as pool:
                    for count in pool.imap_unordered(_chunk_job, todo):
                        bar.update(count)
            else:
                for job in todo:
                    bar.update(_chunk_job(job))
        parts = []
        for k in range(chunks):
            with np.load(tmp / "chunks" / f"chunk{k:05d}.npz") as z:
                parts.append({key: z[key] for key in ("x", "n", "lengths", "angles", "split")})
        stacked = {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}
        write_bytes_atomic(tmp / "samples.npz", npz_bytes(stacked))
        for extra in sorted((tmp / "chunks").glob("chunk*.npz"))[chunks:]:  # a larger earlier run's
            extra.unlink()
        manifest = {
            "format": HANDHELD_FORMAT,
            "kind": ANALYTIC_KIND,
            "seed": c.seed,
            "objects": c.samples,
            "first_chain_seed": ANALYTIC_SEED_BASE + c.seed * SEED_STRIDE,
            "settings": c.to_json(),
            "samples": {s: int((stacked["split"] == code).sum()) for s, code in SPLIT_CODES.items()},
            "file": "samples.npz",
        }
        write_json_atomic(tmp / "manifest.json", manifest)
    return manifest
