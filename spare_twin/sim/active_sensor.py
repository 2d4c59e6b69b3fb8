"""What an active depth sensor does to a clean z-depth image, besides its noise (`spare_twin.sim.noise`).

- Shadows (`shadow_mask`): structured light and active stereo triangulate between the depth imager
  and a second viewpoint (the projector, or the second imager) a baseline b to the side. A surface
  point the second viewpoint cannot see reads no depth. In the depth image that is a band on the far
  (background) side of every depth edge, on the side away from the second viewpoint, about
  f b (1/z_near - 1/z_far) pixels wide. Computed exactly per image row: a pixel is shadowed when a
  pixel on the second viewpoint's side projects, in that viewpoint, at or beyond it (a running minimum
  of u - f b / z along the row).
- Flying pixels (`flying_pixels`): at a depth edge a pixel's footprint (and the sensor's matching
  window) covers both the foreground and the background, and the reading is a mix: a depth between
  the two, i.e. a point on the pixel's ray between the surfaces. A thin link's silhouette is strung
  out along the rays behind it.
- Dark plastic (`dark_dropout`): black and indigo filament absorbs the near-infrared pattern; those
  links return only a fraction of their pixels.

Every function takes and returns float32 (H, W) depth in metres, 0 = no reading, and draws from the
generator it is given, so a capture is a pure function of its seed.
"""

from __future__ import annotations

import numpy as np

#: Baseline between the depth imager and the second viewpoint, metres, per noise model's sensor name
#: (docs/sensor_effects.md: Kinect v1 7.5 cm, D435 5 cm; no published figure found for the SR300,
#: whose projector sits a few centimetres from its imager: 5 cm assumed, as for a clean render).
SENSOR_BASELINE_M = {"kinect_v1": 0.075, "realsense_d435": 0.050, "realsense_sr300": 0.050}
DEFAULT_BASELINE_M = 0.050


def shadow_mask(depth_m: np.ndarray, fx_px: float, baseline_m: float, tol_px: float = 0.5) -> np.ndarray:
    """(H, W) bool: pixels the second viewpoint, `baseline_m` along the image's +x (negative: -x),
    cannot see. A horizontal baseline, as every listed sensor has (camera roll turns it with the image)."""
    d = np.asarray(depth_m, dtype=np.float64)
    if baseline_m == 0:
        return np.zeros(d.shape, bool)
    flip = baseline_m < 0  # mirror the rows so the second viewpoint is always to the right
    if flip:
        d = d[:, ::-1]
    valid = d > 0
    u = np.arange(d.shape[1], dtype=np.float64)[None, :]
    # column of each surface point in the second viewpoint's image (same intrinsics, rectified)
    ue = np.where(valid, u - fx_px * abs(baseline_m) / np.where(valid, d, 1.0), np.inf)
    # least such column over the pixels to the right of each pixel (nearer the second viewpoint)
    right_min = np.minimum.accumulate(ue[:, ::-1], axis=1)[:, ::-1]
    right_min = np.concatenate([right_min[:, 1:], np.full((d.shape[0], 1), np.inf)], axis=1)
    mask = valid & (right_min < ue - tol_px)
    return mask[:, ::-1] if flip else mask


def edge_neighbour(depth_m: np.ndarray, jump_rel: float) -> tuple[np.ndarray, np.ndarray]:
    """For each pixel, the 4-neighbour depth differing most from its own (valid pixels only) and whether
    that difference is a depth edge (more than `jump_rel` of the nearer depth)."""
    d = np.asarray(depth_m, dtype=np.float32)
    best = np.zeros_like(d)
    best_diff = np.zeros_like(d)
    padded = np.pad(d, 1)
    H, W = d.shape
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        nb = padded[1 + dy : 1 + dy + H, 1 + dx : 1 + dx + W]
        diff = np.where((d > 0) & (nb > 0), np.abs(nb - d), 0.0)
        take = diff > best_diff
        best = np.where(take, nb, best)
        best_diff = np.where(take, diff, best_diff)
    edge = best_diff > jump_rel * np.minimum(d, np.where(best > 0, best, d))
    return best, edge & (d > 0)


def flying_pixels(
    depth_m: np.ndarray, rng: np.random.Generator, prob: float, band_px: int = 1, jump_rel: float = 0.05
) -> np.ndarray:
    """Mixed readings along depth edges: each pixel within `band_px` of an edge (on either side) reads,
    with probability `prob`, z + a (z_other - z) with a ~ U(0, 1) and z_other the depth across the edge.
    The pixel keeps its ray, so the point lies between the surfaces along it."""
    d = np.array(depth_m, dtype=np.float32, copy=True)
    other, edge = edge_neighbour(d, jump_rel)
    # grow the band inwards from the edge: pixels up to band_px from it take the depth across the edge
    for _ in range(max(int(band_px), 1) - 1):
        grown_other, grown = other.copy(), edge.copy()
        for axis in (0, 1):
            for shift in (1, -1):
                nb_edge = np.roll(edge, shift, axis=axis)
                nb_other = np.roll(other, shift, axis=axis)
                new = nb_edge & ~grown & (d > 0) & (np.abs(nb_other - d) > jump_rel * np.minimum(d, nb_other))
                grown_other = np.where(new, nb_other, grown_other)
                grown |= new
        other, edge = grown_other, grown
    draw = rng.random(d.shape)
    alpha = rng.random(d.shape).astype(np.float32)
    mixed = edge & (draw < prob)
    d[mixed] = d[mixed] + alpha[mixed] * (other[mixed] - d[mixed])
    return d


def dark_dropout(
    depth_m: np.ndarray, labels: np.ndarray, dark_labels: np.ndarray, return_frac: float, rng: np.random.Generator
) -> np.ndarray:
    """Depth with each pixel of a dark link (label in `dark_labels`) lost with probability 1 - return_frac."""
    d = np.array(depth_m, dtype=np.float32, copy=True)
    dark = np.isin(labels, dark_labels) & (d > 0)
    d[dark & (rng.random(d.shape) >= return_frac)] = 0.0
    return d
