"""A depth-sensor noise model (depth-dependent noise, quantisation, holes at edges, dropouts) and its
fit to real frames.

Model, applied to a clean z-depth image d (metres, 0 = no reading):
1. holes at depth edges: where a pixel's 4-neighbour is nearer by more than `edge_jump_rel * d`
   (the far side of an occluding edge, where structured light and stereo lose the pattern), the pixel
   starts a hole with probability `edge_hole_prob`; holes are `edge_band_px` pixels wide at the
   sensor's `ref_width_px` (scaled to the image width). The edges are the scene's: where the sensor's
   other readings (mixed pixels) already changed the image, its depth before them says where they are;
2. Gaussian noise with std sigma(d) = `sigma0_m` + `sigma2_per_m` * d^2 (disparity noise grows
   with the square of depth);
3. quantisation to steps of max(`unit_m`, `quant_per_m` * d^2) (disparity quantisation);
4. independent dropouts with probability `dropout_prob`; readings outside
   [`min_range_m`, `max_range_m`] are lost.

Fit (`fit_depth_noise`): on real depth frames, along image rows,
- sigma(d): in smooth runs (three valid pixels whose outer two differ by < 1 % of d), the residual
  r = d[x] - (d[x-1] + d[x+1]) / 2 has std sqrt(1.5) sigma; robust std (1.4826 MAD) per 10 cm depth
  bin, then least squares for sigma0 + sigma2 d^2;
- quantisation: the smallest non-zero difference between neighbouring readings per depth bin, fitted
  as quant_per_m d^2; `unit_m` is the file's depth unit;
- edges: every pair of valid readings separated only by invalid pixels (gap g <= 10) whose depths
  differ by more than edge_jump_rel is an edge; edge_hole_prob is the fraction of edges with g >= 1
  and edge_band_px the mean gap of those;
- dropout_prob: isolated invalid pixels between two valid, smoothly continuing neighbours, per
  such configuration.
`fit_noise_models` (`spare-twin noise fit`) fits and writes them (capture/rigs/noise_*.json).
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spare_twin.errors import SpareTwinError
from spare_twin.io import read_json, read_png, write_bytes_atomic
from spare_twin.output import OutputKind, check_output, writing
from spare_twin.sim.rig import RIGS_DIR

NOISE_FILE_PREFIX = "noise_"


@dataclass(frozen=True)
class DepthNoise:
    """Parameters of the depth-sensor noise model (see the module docstring)."""

    sigma0_m: float = 0.0005
    sigma2_per_m: float = 0.0015
    """sigma(d) = sigma0_m + sigma2_per_m * d^2 (d in metres)."""
    unit_m: float = 0.001
    quant_per_m: float = 0.0
    """Quantisation step = max(unit_m, quant_per_m * d^2)."""
    edge_jump_rel: float = 0.05
    edge_hole_prob: float = 0.3
    edge_band_px: float = 2.0
    ref_width_px: int = 640
    """Image width the pixel sizes (edge_band_px) were measured at."""
    dropout_prob: float = 0.01
    min_range_m: float = 0.1
    max_range_m: float = 4.0
    sensor: str = "generic"

    def apply(
        self, depth_m: np.ndarray, rng: np.random.Generator, scene_depth_m: np.ndarray | None = None
    ) -> np.ndarray:
        """A noisy copy of (..., H, W) float depth images. `scene_depth_m`: the scene's own depth (the
        clean render) where `depth_m` already holds other readings of the sensor (mixed pixels along
        edges, `sim.active_sensor.flying_pixels`): holes start at its edges, not at theirs. The fit
        counted holes per edge of the scene (module doc), mixed readings included among the valid
        ones; a mixed reading on a link, deeper than the link beside it, is no edge of the scene, and
        holes grown from each of them ate a thin link from both rims (one link of bench seed 31685's
        Kinect capture read 95 pixels in every fourth frame of its first camera, 449 with the scene's
        edges)."""
        d = np.array(depth_m, dtype=np.float32, copy=True)
        valid = d > 0
        scene = d if scene_depth_m is None else np.asarray(scene_depth_m, np.float32)
        # 1. holes on the far side of the scene's depth edges
        jump = np.zeros(d.shape, bool)
        big = np.where(scene > 0, scene, np.inf)
        for axis in (-1, -2):
            for shift in (1, -1):
                nb = np.roll(big, shift, axis=axis)
                jump |= valid & (scene - nb > self.edge_jump_rel * scene)
        holes = jump & (rng.random(d.shape) < self.edge_hole_prob)
        r = int(round(self.edge_band_px * d.shape[-1] / self.ref_width_px)) - 1
        for _ in range(max(r, 0)):
            grown = holes.copy()
            for axis in (-1, -2):
                grown |= np.roll(holes, 1, axis=axis) | np.roll(holes, -1, axis=axis)
            holes = grown & valid
        # 2. depth-dependent noise, 3. quantisation
        sigma = self.sigma0_m + self.sigma2_per_m * d * d
        d = d + rng.standard_normal(d.shape).astype(np.float32) * sigma
        step = np.maximum(self.unit_m, self.quant_per_m * d * d)
        d = np.round(d / step) * step
        # 4. dropouts and range
        lost = holes | (rng.random(d.shape) < self.dropout_prob) | (d < self.min_range_m) | (d > self.max_range_m)
        d[lost | ~valid] = 0.0
        return d.astype(np.float32)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_json_file(cls, path: str | Path) -> DepthNoise:
        d = read_json(path)
        if not isinstance(d, dict):
            raise SpareTwinError(f"{path}: expected a JSON object")
        d.pop("fit", None)
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(str(k) for k in set(d) - known)
        problems = [f"unknown key(s) {', '.join(unknown)}"] if unknown else []
        for k, v in d.items():  # a wrong value would only show later, as a numpy error in the middle of a render
            if k == "sensor":
                ok = isinstance(v, str)
            elif k in known:
                ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0
                ok = ok and (v <= 1 if k.endswith("_prob") else v > 0 if k in ("unit_m", "ref_width_px") else True)
            else:
                continue
            if not ok:
                problems.append(f"{k}: {json.dumps(v)[:40]} is not a valid value")
        if problems:
            raise SpareTwinError(f"{path}: {'; '.join(problems)}")
        return cls(**d)


def load_noise(name: str, param: str = "noise", flag: str | None = None) -> DepthNoise | None:
    """The DepthNoise of capture/rigs/noise_<name>.json (or a JSON path); None for 'none'.

    Errors start with `param`, the caller's name for `name` (`flag` is its older spelling)."""
    param = flag or param
    if name == "none":
        return None
    p = Path(name) if name.endswith(".json") else RIGS_DIR / f"{NOISE_FILE_PREFIX}{name}.json"
    if not p.is_file():
        have = sorted(q.stem[len(NOISE_FILE_PREFIX) :] for q in RIGS_DIR.glob(f"{NOISE_FILE_PREFIX}*.json"))
        raise SpareTwinError(f"{param} {name!r}: no such noise model ({p}; have: {', '.join(have) or 'none'})")
    return DepthNoise.from_json_file(p)


def _rows_stats(depths: list[np.ndarray], jump_rel: float, max_gap: int = 10):
    res_z, res_r, diffs_z, diffs = [], [], [], []
    edges_gap, iso, iso_den = [], 0, 0
    for d in depths:
        v = d > 0
        a, b, c = d[:, :-2], d[:, 1:-1], d[:, 2:]
        va, vb, vc = v[:, :-2], v[:, 1:-1], v[:, 2:]
        smooth = va & vc & (np.abs(c - a) < 0.01 * b)
        ok = smooth & vb
        res_z.append(b[ok])
        res_r.append(b[ok] - (a[ok] + c[ok]) / 2)
        nd = np.abs(c - b)[vb & vc & (np.abs(c - b) < 0.01 * b)]
        diffs.append(nd)
        diffs_z.append(b[vb & vc & (np.abs(c - b) < 0.01 * b)])
        iso += int((smooth & ~vb).sum())
        iso_den += int(smooth.sum())
        for row, vr in zip(d, v):
            idx = np.flatnonzero(vr)
            if len(idx) < 2:
                continue
            gaps = np.diff(idx) - 1
            da, db = row[idx[:-1]], row[idx[1:]]
            is_edge = (gaps <= max_gap) & (np.abs(da - db) > jump_rel * np.minimum(da, db))
            edges_gap.append(gaps[is_edge])
    return (
        np.concatenate(res_z),
        np.concatenate(res_r),
        np.concatenate(diffs_z),
        np.concatenate(diffs),
        np.concatenate(edges_gap),
        iso,
        iso_den,
    )


def fit_depth_noise(
    depths: list[np.ndarray], unit_m: float, sensor: str, jump_rel: float = 0.05
) -> tuple[DepthNoise, dict]:
    """Fit the model to real depth frames (metres, 0 = none); returns the model and a fit report."""
    if not depths:
        raise SpareTwinError("fit_depth_noise: no depth frames")
    z, r, dz, dd, gaps, iso, iso_den = _rows_stats(depths, jump_rel)
    bins = np.arange(0.1, 6.0, 0.1)
    zs, sig, steps = [], [], []
    for lo in bins:
        m = (z >= lo) & (z < lo + 0.1)
        if m.sum() < 200:
            continue
        mad = np.median(np.abs(r[m] - np.median(r[m])))
        zs.append(lo + 0.05)
        sig.append(1.4826 * mad / np.sqrt(1.5))
        q = dd[(dz >= lo) & (dz < lo + 0.1)]
        q = q[q > unit_m * 0.5]
        steps.append(float(np.percentile(q, 5)) if len(q) else unit_m)
    zs, sig, steps = np.array(zs), np.array(sig), np.array(steps)
    if len(zs) == 0:
        raise SpareTwinError("fit_depth_noise: too few smooth valid pixels to fit")
    A = np.stack([np.ones_like(zs), zs**2], 1)
    (s0, s2), *_ = np.linalg.lstsq(A, sig, rcond=None)
    s0, s2 = max(float(s0), 0.0), max(float(s2), 0.0)
    quant = float(np.median(steps / zs**2)) if (steps > unit_m * 1.5).any() else 0.0
    holes = gaps[gaps >= 1]
    model = DepthNoise(
        sigma0_m=round(s0, 6),
        sigma2_per_m=round(s2, 6),
        unit_m=unit_m,
        quant_per_m=round(quant, 6),
        edge_jump_rel=jump_rel,
        edge_hole_prob=round(float(len(holes) / max(len(gaps), 1)), 4),
        edge_band_px=round(float(holes.mean()) if len(holes) else 1.0, 3),
        ref_width_px=int(depths[0].shape[1]),
        dropout_prob=round(iso / max(iso_den, 1), 5),
        min_range_m=round(float(np.percentile(z, 0.5)), 3),
        max_range_m=round(float(np.percentile(z, 99.5)), 3),
        sensor=sensor,
    )
    report = {
        "frames": len(depths),
        "valid_fraction": float(np.mean([np.mean(d > 0) for d in depths])),
        "depth_bins_m": zs.round(3).tolist(),
        "sigma_m": np.round(sig, 6).tolist(),
        "quant_step_m": np.round(steps, 6).tolist(),
        "edges": int(len(gaps)),
    }
    return model, report


def load_real_depths(folder: str | Path) -> tuple[list[np.ndarray], float, str]:
    """Depth frames (metres), depth unit and sensor of a real sample: 7-Scenes (mm, a RealSense SR300)
    or TUM (1/5000 m, a Kinect v1)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise SpareTwinError(f"{folder}: no such folder")
    seven = sorted(folder.glob("frame-*.depth.png"))
    if seven:
        return [read_png(p).astype(np.float32) * 0.001 for p in seven], 0.001, "realsense_sr300"
    tum = sorted(folder.glob("*_depth.png")) or sorted((folder / "depth").glob("*.png"))
    if tum:
        return [read_png(p).astype(np.float32) / 5000.0 for p in tum], 1 / 5000.0, "kinect_v1"
    raise SpareTwinError(f"{folder}: no 7-Scenes (frame-*.depth.png) or TUM (*_depth.png, depth/*.png) frames")


#: The real frames inside the repository (tests/data): the default source of `fit_noise_models`.
#: The shipped models in capture/rigs/ were fitted to longer recordings of the same two sensors.
SAMPLE_SOURCES = tuple(
    Path(__file__).resolve().parents[2] / "tests" / "data" / name for name in ("apc_shelf_realsense", "tum_desk_pair")
)


@dataclass(frozen=True)
class NoiseFit:
    """One noise model fitted by `fit_noise_models`, and the file it went to."""

    path: Path
    source: Path
    model: DepthNoise
    report: dict

    def to_json(self) -> dict:
        return {"path": str(self.path), "source": str(self.source), "model": self.model.to_dict()}


#: What `fit_noise_models` writes: a folder of noise_<sensor>.json files (the output rule's kind).
NOISE_FIT = OutputKind("noise fit")


def fit_noise_models(
    out_dir: str | Path, sources: Sequence[str | Path] = SAMPLE_SOURCES, force: bool = False
) -> tuple[NoiseFit, ...]:
    """Fit one noise model per source folder of real depth frames and write them into the folder
    `out_dir` as noise_<sensor>.json (the files capture/rigs/ ships). `out_dir` follows the output
    rule (`spare_twin.output`): absent, empty or an earlier noise fit, else only with `force`; it is
    replaced once every fit has succeeded."""
    if not sources:
        raise SpareTwinError("sources: no folder of real depth frames given")
    sources = [Path(s) for s in sources]
    loaded: dict[str, tuple[Path, list[np.ndarray], float]] = {}
    for src in sources:  # the inputs are read and checked first, then the output path, then the fitting
        depths, unit, sensor = load_real_depths(src)
        if sensor in loaded:
            raise SpareTwinError(f"{src}: a second {sensor} source (one noise model per sensor; {loaded[sensor][0]})")
        loaded[sensor] = (src, depths, unit)
    check_output(out_dir, NOISE_FIT, sources, force)
    fits = {sensor: (src, *fit_depth_noise(depths, unit, sensor)) for sensor, (src, depths, unit) in loaded.items()}
    out = Path(out_dir)
    written = []
    with writing(out, NOISE_FIT, sources, force) as tmp:
        for sensor, (src, model, report) in fits.items():
            d = model.to_dict()
            d["fit"] = {"source": f"{src.resolve().parent.name}/{src.resolve().name}", **report}
            name = f"{NOISE_FILE_PREFIX}{sensor}.json"
            write_bytes_atomic(tmp / name, (json.dumps(d, indent=2) + "\n").encode())
            written.append(NoiseFit(out / name, src, model, report))
    return tuple(written)
