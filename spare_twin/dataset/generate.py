"""One dataset sequence as a pure function of (dataset seed, index): the sampled chain, its scene
and motion, rendered by the rig at the network resolution.

Balance and splits are functions of the index alone, so a dataset extended to more sequences keeps
every existing sequence, its split and its bytes:
- n_links = index % 6 + 1 (every 6 consecutive indices hold each count once);
- split: block b = index // 6 takes slot b % 27 of a fixed interleaved pattern of 16 train, 3 val
  and 8 test slots (the paper's 153,600 / 28,800 / 76,800 images = 16 : 3 : 8), so every split
  is balanced over n and small datasets already have all three splits.

Speed: the renderer is called for every (frame, camera) with precomputed matrices and its raw
buffers are stacked; linearising depth, grey conversion and segmentation labels run once per
sequence on whole arrays, so per-image Python work is one pybullet call and three copies.
"""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spare_twin.config import MAX_MOVING_LINKS, ChainSpec, sample_chain
from spare_twin.object.folder import SIM_CIRCLE_SEGMENTS, ObjectFolder, build_sim_twin
from spare_twin.object.parts import CIRCLE_SEGMENTS
from spare_twin.recording import SIM_DEPTH_SCALE
from spare_twin.sim.effects import ALL_EFFECTS
from spare_twin.sim.motion import MotionConfig, object_motion
from spare_twin.sim.print_physics import draw_perturbation, perturbed_object
from spare_twin.sim.rig import Rig
from spare_twin.sim.scene import DomainRandomization, sample_scene
from spare_twin.sim.twin import Twin, projection_matrix, view_matrix

SPLITS = ("train", "val", "test")
SPLIT_COUNTS = (16, 3, 8)  # per 27 blocks of 6 sequences: 192 / 36 / 96 of the paper's 324


def _split_pattern() -> tuple[str, ...]:
    slots = []
    for name, count in zip(SPLITS, SPLIT_COUNTS):
        slots += [((j + 0.5) / count, SPLITS.index(name), name) for j in range(count)]
    return tuple(name for _, _, name in sorted(slots))


SPLIT_PATTERN = _split_pattern()


def n_links_of(index: int) -> int:
    return index % MAX_MOVING_LINKS + 1


def split_of(index: int) -> str:
    return SPLIT_PATTERN[(index // MAX_MOVING_LINKS) % len(SPLIT_PATTERN)]


def _seeds(seed: int, index: int) -> dict[str, int]:
    """Independent 63-bit seeds for each random part of sequence `index`."""
    words = np.random.SeedSequence([int(seed), int(index)]).generate_state(4, dtype=np.uint64)
    return {k: int(w >> np.uint64(1)) for k, w in zip(("chain", "motion", "scene", "spare"), words)}


def sequence_spec(seed: int, index: int, print_scale: float | None = None) -> ChainSpec:
    kw = {} if print_scale is None else {"print_scale": print_scale}
    return sample_chain(n_links_of(index), _seeds(seed, index)["chain"], name=f"seq{index:06d}", **kw)


@dataclass(frozen=True)
class GenConfig:
    """Everything besides (seed, index) that a sequence depends on; stored in the dataset."""

    rig: Rig = field(default_factory=Rig)
    frames: int = 100
    fps: float = 10.0
    geometry: str = "sim"
    """The printed parts as meshes: "sim" tessellates circles with 16 segments (fast to render),
    "print" with the 64 of the STL files that get printed."""
    segmentation: bool = True
    depth_scale: float = SIM_DEPTH_SCALE
    """Metres per stored depth unit (uint16)."""
    randomization: DomainRandomization = field(default_factory=DomainRandomization)
    print_physics: bool = False
    """Each sequence's object as a print is, not as its CAD: joint play and print error drawn from the
    sequence's own seed with the sim-to-real bench's ranges (`sim.print_physics`; the labels stay
    nominal, as a recording's ground truth does)."""

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["rig"] = self.rig.to_dict()
        if not self.print_physics:  # datasets made before the option keep their settings, and resume
            del d["print_physics"]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> GenConfig:
        d = dict(d)
        d["rig"] = Rig.from_dict(d["rig"])
        d["randomization"] = DomainRandomization(**d.get("randomization", {}))
        return cls(**d)

    def motion(self) -> MotionConfig:
        return MotionConfig(n_frames=self.frames, fps=self.fps)


@dataclass
class Sequence:
    """One rendered sequence (V cameras, T frames) with its labels."""

    index: int
    seed: int
    spec: ChainSpec
    split: str
    depth: np.ndarray
    """uint16 (V, T, H, W); depth_m = depth * depth_scale, 0 = no reading."""
    grey: np.ndarray
    """uint8 (V, T, H, W)."""
    segmentation: np.ndarray | None
    """uint8 (V, T, H, W): 0 background, k = link k - 1."""
    K: np.ndarray
    T_world_camera: np.ndarray
    joint_angles_rad: np.ndarray
    """(T, n)."""
    T_world_link: np.ndarray
    """(T, n + 1, 4, 4)."""
    scene: dict
    depth_scale: float


#: What `GenConfig.print_physics` switches on.
PRINT_EFFECTS = ("joint_play", "print_error")

GEOMETRY_SEGMENTS = {"sim": SIM_CIRCLE_SEGMENTS, "print": CIRCLE_SEGMENTS}


def load_twin_object(cfg: GenConfig, spec: ChainSpec, workdir: Path) -> ObjectFolder:
    """Write the sequence's object (its printed parts and URDF) into a fresh folder: pybullet caches
    URDFs by path."""
    folder = Path(tempfile.mkdtemp(dir=workdir, prefix=f"{spec.name}-"))
    return build_sim_twin(spec, folder, GEOMETRY_SEGMENTS[cfg.geometry])


class _DepthEncoder:
    """pybullet depth buffer -> uint16 z-depth units in a few float32 passes (no float64 temporaries).

    depth_m = far * near / (far - (far - near) * z); units = round(depth_m / depth_scale); the far
    plane (z = 1: nothing hit) becomes 0, no reading."""

    def __init__(self, near_m: float, far_m: float, depth_scale: float):
        self.num = np.float32(far_m * near_m / depth_scale)
        self.far = np.float32(far_m)
        self.span = np.float32(far_m - near_m)
        self.max_units = np.float32(min(65535.0, far_m / depth_scale))

    def __call__(self, zbuf: np.ndarray, out: np.ndarray) -> None:
        q = zbuf * -self.span
        q += self.far
        np.divide(self.num, q, out=q)
        q += np.float32(0.5)
        q[zbuf >= np.float32(1.0 - 1e-7)] = 0.0
        np.minimum(q, self.max_units, out=q)
        out[...] = q  # truncation of x + 0.5: round half up


def render_sequence(cfg: GenConfig, seed: int, index: int, twin: Twin, workdir: Path) -> Sequence:
    """Render sequence `index` of the dataset with `seed` (a pure function of both and `cfg`)."""
    import cv2

    seeds = _seeds(seed, index)
    spec = sequence_spec(seed, index)
    scene = sample_scene(cfg.rig, spec, cfg.randomization, np.random.default_rng(seeds["scene"]))
    obj = load_twin_object(cfg, spec, workdir)
    printed = None
    try:
        if cfg.print_physics:
            printed = draw_perturbation(spec.n_links, ALL_EFFECTS.only(PRINT_EFFECTS), seeds["spare"])
            twin.load(perturbed_object(obj, printed, obj.root / "printed"))
        else:
            twin.load(obj)
    finally:
        shutil.rmtree(obj.root, ignore_errors=True)  # pybullet has read the URDF and meshes
    if scene.link_rgb is not None:
        for k, rgb in enumerate(scene.link_rgb):
            twin.set_link_color(k, rgb)
    twin.set_table_color(scene.table_rgba)
    twin.clear_extras()
    for box in scene.clutter:
        twin.add_box(box["half_extents_m"], box["position_m"], box["rgba"], box["yaw_rad"])

    angles = object_motion(
        obj,
        np.random.default_rng(seeds["motion"]),
        cfg.motion(),
    )
    rig = cfg.rig
    V, T, H, W = rig.n_cameras, cfg.frames, rig.height, rig.width
    views = [view_matrix(Tc) for Tc in scene.T_world_camera]
    projs = [projection_matrix(k, W, H, rig.near_m, rig.far_m) for k in scene.K]
    depth = np.empty((V, T, H, W), np.uint16)
    grey = np.empty((V, T, H, W), np.uint8)
    labels = np.empty((V, T, H, W), np.uint8) if cfg.segmentation else None
    # Per-frame buffers (8 images, a few hundred KB) keep the conversions inside the CPU cache.
    rgba = np.empty((V, H, W, 4), np.uint8)
    zbuf = np.empty((V, H, W), np.float32)
    seg = np.empty((V, H, W), np.int32)
    to_depth = _DepthEncoder(rig.near_m, rig.far_m, cfg.depth_scale)
    link_poses = np.empty((T, spec.n_links + 1, 4, 4))
    for t in range(T):
        twin.set_joints(angles[t])
        link_poses[t] = twin.link_poses()
        for v in range(V):
            c, z, sg = twin.render_raw(views[v], projs[v], W, H, scene.lighting, cfg.segmentation)
            rgba[v] = c
            zbuf[v] = z
            if labels is not None:
                seg[v] = sg
        to_depth(zbuf, depth[:, t])
        # BT.601 luma in OpenCV's fixed-point arithmetic (deterministic, exact for grey pixels).
        grey[:, t] = cv2.cvtColor(rgba.reshape(V * H, W, 4), cv2.COLOR_RGBA2GRAY).reshape(V, H, W)
        if labels is not None:
            labels[:, t] = twin.labels(seg)
    return Sequence(
        index=index,
        seed=seed,
        spec=spec,
        split=split_of(index),
        depth=depth,
        grey=grey,
        segmentation=labels,
        K=scene.K,
        T_world_camera=scene.T_world_camera,
        joint_angles_rad=angles,
        T_world_link=link_poses,
        scene=scene.describe() if printed is None else {**scene.describe(), "print": printed.to_dict()},
        depth_scale=cfg.depth_scale,
    )
