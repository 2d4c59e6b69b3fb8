"""Rig calibration with a ChArUco board: the board at true print size, detection, camera poses.

Board frame (OpenCV's): origin at the board's top-left corner, x along the squares' rows, y down the
board, z into the board. Lying on the table, the board defines the world: x along the board, y the
other way across it, z up, table z = 0, i.e. T_world_board = diag(1, -1, -1) (a half turn about x).

Each camera's pose comes from solvePnP on the detected ChArUco corners (IPPE for a plane, then
Levenberg-Marquardt), and is then refined with depth: the board plane fitted to the depth pixels
inside the board replaces the PnP plane (tilt and distance), keeping the in-plane position from the
image, because structured-light / stereo depth measures a flat sheet's distance better than a corner
fit does at a few pixels per square.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from spare_twin.capture.checks import is_number, whole
from spare_twin.errors import SpareTwinError
from spare_twin.io import read_json, write_bytes_atomic
from spare_twin.output import check_output, writing

T_WORLD_BOARD = np.diag([1.0, -1.0, -1.0, 1.0])
#: Print resolutions a board page may have (an A4 page at 1200 dpi is 14000 x 9900 pixels).
MIN_DPI, MAX_DPI = 72, 1200
#: The command whose output a board folder is (its output marker).
BOARD = "capture board"
MM_PER_INCH = 25.4
A4_LANDSCAPE_MM = (297.0, 210.0)


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board. Defaults: 7 x 5 squares of 35 mm (245 x 175 mm) fit an A4 sheet with margins."""

    squares_x: int = 7
    squares_y: int = 5
    square_m: float = 0.035
    marker_m: float = 0.026
    dictionary: str = "DICT_5X5_100"
    dpi: int = 300
    """print resolution of the PNG/PDF; the page is A4 landscape at this resolution."""

    def __post_init__(self):
        import cv2

        for name in ("squares_x", "squares_y"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 3:
                raise SpareTwinError(f"{name} {value!r}: a board needs at least 3 x 3 squares")
        whole("dpi", self.dpi, MIN_DPI)
        if self.dpi > MAX_DPI:  # an A4 page at more would need gigabytes
            raise SpareTwinError(f"dpi {self.dpi}: must be at most {MAX_DPI}")
        if not is_number(self.square_m) or self.square_m <= 0:
            raise SpareTwinError(f"square_m: {_mm(self.square_m)} must be positive")
        if not is_number(self.marker_m) or not 0 < self.marker_m < self.square_m:
            raise SpareTwinError(
                f"marker_m: {_mm(self.marker_m)} must be positive and smaller than a square ({_mm(self.square_m)})"
            )
        if not isinstance(self.dictionary, str) or not self.dictionary.startswith("DICT_"):
            raise SpareTwinError(f"dictionary {self.dictionary!r}: unknown ArUco dictionary (e.g. DICT_5X5_100)")
        if not hasattr(cv2.aruco, self.dictionary):
            raise SpareTwinError(f"dictionary {self.dictionary!r}: unknown ArUco dictionary (e.g. DICT_5X5_100)")
        w_mm, h_mm = self.size_m[0] * 1000, self.size_m[1] * 1000
        if w_mm > A4_LANDSCAPE_MM[0] - 20 or h_mm > A4_LANDSCAPE_MM[1] - 25:
            raise SpareTwinError(f"board: {w_mm:.0f} x {h_mm:.0f} mm does not fit an A4 page with margins")

    @property
    def size_m(self) -> tuple[float, float]:
        return self.squares_x * self.square_m, self.squares_y * self.square_m

    def cv_board(self):
        import cv2

        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_m, self.marker_m, d)

    def board_image(self, px_per_m: float) -> np.ndarray:
        """uint8 grey image of the board alone, exactly its size at `px_per_m` (no margin)."""
        w, h = (int(round(s * px_per_m)) for s in self.size_m)
        return self.cv_board().generateImage((w, h), marginSize=0, borderBits=1)

    @classmethod
    def load(cls, path: str | Path) -> BoardSpec:
        d = read_json(path)
        if not isinstance(d, dict):
            raise SpareTwinError(f"{path}: bad board description (expected a JSON object)")
        try:
            return cls(**{k: d[k] for k in ("squares_x", "squares_y", "square_m", "marker_m", "dictionary") if k in d})
        except TypeError as exc:
            raise SpareTwinError(f"{path}: bad board description ({exc})") from None
        except SpareTwinError as exc:
            raise SpareTwinError(f"{path}: {exc}") from None


def board_page(spec: BoardSpec) -> np.ndarray:
    """An A4 landscape page (uint8 grey, `spec.dpi`) with the board centred, a 100 mm scale bar and a caption."""
    import cv2

    px_per_mm = spec.dpi / MM_PER_INCH
    W, H = (int(round(v * px_per_mm)) for v in A4_LANDSCAPE_MM)
    page = np.full((H, W), 255, np.uint8)
    board = spec.board_image(px_per_mm * 1000)
    bh, bw = board.shape
    y0, x0 = (H - bh) // 2 - int(4 * px_per_mm), (W - bw) // 2
    page[y0 : y0 + bh, x0 : x0 + bw] = board
    # 100 mm scale bar under the board: measure it to check the print was not scaled
    yb = y0 + bh + int(6 * px_per_mm)
    xb = x0
    page[yb : yb + int(1.5 * px_per_mm), xb : xb + int(round(100 * px_per_mm))] = 0
    caption = (
        f"ChArUco {spec.squares_x}x{spec.squares_y}  squares {spec.square_m * 1000:g} mm  markers "
        f"{spec.marker_m * 1000:g} mm  {spec.dictionary}  -  print at 100 %: the bar is 100 mm"
    )
    cv2.putText(
        page,
        caption,
        (xb, yb + int(7 * px_per_mm)),
        cv2.FONT_HERSHEY_SIMPLEX,
        0.09 * px_per_mm,
        0,
        max(1, int(0.25 * px_per_mm)),
        cv2.LINE_AA,
    )
    return page


def _mm(length_m) -> str:
    return f"{length_m * 1000:g} mm" if is_number(length_m) else repr(length_m)


def write_board(spec: BoardSpec, out_dir: str | Path, force: bool = False) -> dict[str, Path]:
    """board.png and board.pdf (A4 landscape, true size at spec.dpi) and board.json; returns the paths.

    `out_dir` follows the output rule (`spare_twin.output`); `force` replaces what it would refuse.
    """
    import io

    from PIL import Image

    out_dir = Path(out_dir)
    check_output(out_dir, BOARD, force=force)  # before the page is drawn
    page = Image.fromarray(board_page(spec))
    files = {}
    for ext, kw in (("png", {"dpi": (spec.dpi, spec.dpi)}), ("pdf", {"resolution": float(spec.dpi)})):
        buf = io.BytesIO()
        page.save(buf, format=ext.upper(), **kw)
        files[ext] = buf.getvalue()
    desc = asdict(spec) | {
        "size_m": list(spec.size_m),
        "page": "A4 landscape",
        "frame": "origin top-left corner, x along rows, y down, z into the board; "
        "world = board on the table: T_world_board = diag(1, -1, -1)",
    }
    files["json"] = (json.dumps(desc, indent=2) + "\n").encode()
    with writing(out_dir, BOARD, force=force) as tmp:
        for ext, data in files.items():
            write_bytes_atomic(tmp / f"board.{ext}", data)
    return {ext: out_dir / f"board.{ext}" for ext in files}


@dataclass
class BoardPose:
    T_camera_board: np.ndarray
    corners: int
    reprojection_px: float
    depth: dict | None = None
    """depth refinement: points used, plane residual (mm), shift (mm), tilt change (deg)."""

    @property
    def T_world_camera(self) -> np.ndarray:
        return T_WORLD_BOARD @ np.linalg.inv(self.T_camera_board)


def detect_board(image: np.ndarray, spec: BoardSpec) -> tuple[np.ndarray, np.ndarray]:
    """ChArUco corners (N, 2) pixels and their ids (N,) in an RGB or grey uint8 image (N may be 0)."""
    import cv2

    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    detector = cv2.aruco.CharucoDetector(spec.cv_board())
    corners, ids, _mc, _mi = detector.detectBoard(gray)
    if corners is None or ids is None:
        return np.zeros((0, 2), np.float32), np.zeros((0,), np.int32)
    return corners.reshape(-1, 2), ids.reshape(-1)


def board_pose(
    image: np.ndarray,
    K: np.ndarray,
    spec: BoardSpec,
    source: str = "image",
    dist: np.ndarray | None = None,
    min_corners: int = 6,
) -> BoardPose:
    """Board pose in the camera from one colour image (one-line error naming `source` if not found)."""
    import cv2

    corners, ids = detect_board(image, spec)
    if len(ids) < min_corners:
        raise SpareTwinError(f"{source}: ChArUco board not found ({len(ids)} corners, need {min_corners})")
    board = spec.cv_board()
    obj, img = board.matchImagePoints(corners.reshape(-1, 1, 2), ids.reshape(-1, 1))
    obj, img = obj.reshape(-1, 3).astype(np.float64), img.reshape(-1, 2).astype(np.float64)
    dist = np.zeros(5) if dist is None else dist
    ok, rvec, tvec = cv2.solvePnP(obj, img, K, dist, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise SpareTwinError(f"{source}: ChArUco board pose could not be solved")
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, dist, rvec, tvec)
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K, dist)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, axis=1))))
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec.ravel()
    return BoardPose(T, len(ids), rms)


def refine_with_depth(
    pose: BoardPose, depth_m: np.ndarray, K: np.ndarray, spec: BoardSpec, inset_m: float = 0.005, min_points: int = 200
) -> BoardPose:
    """Replace the board plane's tilt and distance by the plane fitted to the depth inside the board.

    Pixels within the board outline (shrunk by `inset_m`) are back-projected; a least-squares plane
    with two rounds of 3-sigma outlier rejection is fitted; the pose is then rotated about the board
    centre so its normal matches, and moved along the normal onto the depth plane. With too few
    depth readings the pose is returned unchanged (depth=None).
    """
    import cv2

    T = pose.T_camera_board
    w, h = spec.size_m
    outline = np.array(
        [[inset_m, inset_m, 0], [w - inset_m, inset_m, 0], [w - inset_m, h - inset_m, 0], [inset_m, h - inset_m, 0]]
    )
    cam = (T[:3, :3] @ outline.T).T + T[:3, 3]
    uv = (K @ cam.T).T
    uv = uv[:, :2] / uv[:, 2:3]
    mask = np.zeros(depth_m.shape, np.uint8)
    cv2.fillConvexPoly(mask, np.round(uv).astype(np.int32), 1)
    v, u = np.nonzero((mask > 0) & (depth_m > 0))
    if len(u) < min_points:
        return BoardPose(T, pose.corners, pose.reprojection_px, None)
    z = depth_m[v, u].astype(np.float64)
    P = np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], axis=1)
    keep = np.ones(len(P), bool)
    for _ in range(3):
        c = P[keep].mean(axis=0)
        n = np.linalg.svd(P[keep] - c, full_matrices=False)[2][2]  # only V: U would be N x N
        r = (P - c) @ n
        keep = np.abs(r) < max(3 * np.std(r[keep]), 1e-4)
    n_pnp = T[:3, 2]  # board z axis in the camera
    if n @ n_pnp < 0:
        n = -n
    centre_b = np.array([w / 2, h / 2, 0.0])
    centre = T[:3, :3] @ centre_b + T[:3, 3]
    axis = np.cross(n_pnp, n)
    angle = float(np.arctan2(np.linalg.norm(axis), n_pnp @ n))
    Rc = cv2.Rodrigues(axis / np.linalg.norm(axis) * angle)[0] if angle > 1e-9 else np.eye(3)
    shift = float((c - centre) @ n)  # distance from the PnP board centre to the depth plane, along n
    new_centre = centre + shift * n
    Tn = np.eye(4)
    Tn[:3, :3] = Rc @ T[:3, :3]
    Tn[:3, 3] = new_centre - Tn[:3, :3] @ centre_b
    info = {
        "points": int(keep.sum()),
        "plane_residual_mm": round(1000 * float(np.std(r[keep])), 3),
        "shift_mm": round(1000 * shift, 3),
        "tilt_change_deg": round(float(np.degrees(angle)), 4),
    }
    return BoardPose(Tn, pose.corners, pose.reprojection_px, info)


def render_board_view(
    spec: BoardSpec, K: np.ndarray, T_camera_board: np.ndarray, width: int, height: int, background: int = 110
) -> tuple[np.ndarray, np.ndarray]:
    """A synthetic camera view of the board (grey uint8) and its z-depth (float32 m), for tests.

    The board plane maps to the image by the homography K [r1 r2 t] (board metres to pixels),
    applied to the board picture with a white margin, as printed.
    """
    import cv2

    px_per_m = 4000.0  # 0.25 mm per board pixel: finer than any camera pixel at table-top range
    margin_m = 0.01
    board = spec.board_image(px_per_m)
    m = int(round(margin_m * px_per_m))
    sheet = cv2.copyMakeBorder(board, m, m, m, m, cv2.BORDER_CONSTANT, value=255)
    S = np.array([[1 / px_per_m, 0, -margin_m], [0, 1 / px_per_m, -margin_m], [0, 0, 1]])  # sheet pixel -> board m
    H = K @ np.column_stack([T_camera_board[:3, 0], T_camera_board[:3, 1], T_camera_board[:3, 3]]) @ S
    img = cv2.warpPerspective(
        sheet, H, (width, height), flags=cv2.INTER_AREA, borderMode=cv2.BORDER_CONSTANT, borderValue=background
    )
    # z-depth of the board plane (n . X = n . t) along each pixel ray, inside the sheet only
    inside = cv2.warpPerspective(np.ones_like(sheet), H, (width, height), flags=cv2.INTER_NEAREST) > 0
    u, v = np.meshgrid(np.arange(width), np.arange(height))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, float)], axis=-1)
    n = T_camera_board[:3, 2]
    z = (n @ T_camera_board[:3, 3]) / (rays @ n)
    depth = np.where(inside & (z > 0), z, 0).astype(np.float32)
    return img, depth
