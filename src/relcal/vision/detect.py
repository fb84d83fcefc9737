"""Board detection, camera pose with covariance, and batch measurement of image files.

Detection runs OpenCV's finders on a copy downscaled to at most ``max_side`` pixels (fast and
robust on large images), then refines every point on the full-resolution image: ``cornerSubPix``
for chessboard and ChArUco corners, a grey-level (area-coverage) centroid for dots. Point order is
made canonical: right-handed (the board is seen from its printed side), chessboards turned by the
colour of their squares, circle grids with an origin marker turned by the big dot.

The pose is solved with IPPE then refined by Levenberg-Marquardt (``solvePnPRefineLM``). For dots
the perspective shift between the centroid of a dot's image and the image of its centre is
predicted from the pose and removed (two passes). The covariance of the pose 6-vector follows from
the projection Jacobian and the pixel noise.

Every frame that cannot be trusted is returned as :class:`Rejected` with a reason; none is
silently dropped or used.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from relcal import geometry as tf
from relcal.vision.boards import Board, board_points, charuco_board
from relcal.vision.camera import Camera

# ----------------------------------------------------------------------------- results


@dataclass(frozen=True)
class Rejected:
    """A frame that was not used, and why (for a person)."""

    reason: str

    def __str__(self) -> str:
        return self.reason


@dataclass(frozen=True, eq=False)
class Detection:
    """Board points found in one image.

    Attributes
    ----------
    board : Board
    ids : ndarray of int, shape (N,)
        Point ids, rows of :func:`relcal.vision.boards.board_points`.
    image_points : ndarray, shape (N, 2)
        Pixel coordinates (pixel centres at integers, as in OpenCV).
    image_size : (int, int)
        ``(width, height)`` of the image, px.
    notes : tuple of str
        What was left out and why (points at the image edge), for the report.
    """

    board: Board
    ids: np.ndarray
    image_points: np.ndarray
    image_size: tuple[int, int]
    notes: tuple[str, ...] = ()

    @property
    def object_points(self) -> np.ndarray:
        """Board-frame points ``(N, 3)`` (m) matching :attr:`image_points`."""
        return board_points(self.board)[self.ids]


@dataclass(frozen=True, eq=False)
class PoseResult:
    """Camera pose from one detection.

    Attributes
    ----------
    T_board_camera : ndarray, shape (4, 4)
        Camera pose in the board frame (``C_k`` of the design notes), m.
    rms : float
        Reprojection RMS, px (root mean square of the 2-D residual lengths).
    covariance : ndarray, shape (6, 6)
        Covariance of ``relcal.geometry.to_vector(T_board_camera)`` (translation m, rotation
        vector rad).
    pixel_sigma : float
        Pixel noise per coordinate used for the covariance, px (given, or from the residuals).
    residuals : ndarray, shape (N, 2)
        Measured minus projected image points, px.
    ids : ndarray of int, shape (N,)
        Point ids of the residual rows.
    """

    T_board_camera: np.ndarray
    rms: float
    covariance: np.ndarray
    pixel_sigma: float
    residuals: np.ndarray
    ids: np.ndarray

    @property
    def std(self) -> np.ndarray:
        """Standard deviations ``(6,)`` of the pose 6-vector (m, rad)."""
        return np.sqrt(np.diag(self.covariance))

    @property
    def vector(self) -> np.ndarray:
        """The pose 6-vector ``(6,)`` (translation m, rotation vector rad)."""
        return tf.to_vector(self.T_board_camera)


# ----------------------------------------------------------------------------- detection


def to_gray(image: np.ndarray) -> np.ndarray:
    """8-bit single-channel copy of a grey, BGR or BGRA image. Other depths (12/16-bit integers,
    floats) are scaled so that their brightest pixel becomes 255."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        img = cv2.cvtColor(img, code)
    if img.dtype != np.uint8:
        values = img.astype(np.float64)
        top = float(np.max(values)) if values.size else 0.0
        img = np.clip(np.rint(values * (255.0 / top if top > 0 else 1.0)), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(img)


def detect(
    image: np.ndarray,
    board: Board,
    *,
    max_side: int = 1600,
    min_points: int = 6,
) -> Detection | Rejected:
    """Find the board in an image, with sub-pixel refinement at full resolution.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3)
        8-bit (or 16-bit) grey or BGR image.
    board : Board
    max_side : int
        OpenCV's finders run on a copy shrunk by an integer factor to at most this many pixels
        wide and high.
    min_points : int
        ChArUco views with fewer corners are rejected (other boards must be seen whole).

    Returns
    -------
    Detection or Rejected
    """
    gray = to_gray(image)
    height, width = gray.shape
    factor = int(np.ceil(max(height, width) / max_side))  # integer: fast, exact pixel mapping
    small = gray
    if factor > 1:
        size = (width // factor, height // factor)
        small = cv2.resize(
            gray[: size[1] * factor, : size[0] * factor], size, interpolation=cv2.INTER_AREA
        )
    scale = 1.0 / factor
    if board.type == "chessboard":
        found = _find_chessboard(small, board)
    elif board.type == "charuco":
        found = _find_charuco(small, board, min_points)
    else:
        found = _find_circles(small, board)
    if isinstance(found, Rejected):
        return found
    ids, coarse = found
    points = (coarse + 0.5) / scale - 0.5  # pixel-centre convention
    areas = None
    if board.type in ("chessboard", "charuco"):
        points, keep = _refine_corners(gray, points)
    else:
        points, keep, areas = _refine_dots(gray, points)
    order = np.arange(len(points))
    if board.type == "chessboard":
        order = _chessboard_order(gray, points.reshape(*board.grid_shape, 2)).ravel()
        mismatch = _outer_squares_mismatch(gray, points[order].reshape(*board.grid_shape, 2))
        if mismatch:
            return Rejected(mismatch + f" (the board file declares {board.describe()})")
    elif board.type == "circles":
        found_order = _circle_order(points.reshape(*board.grid_shape, 2), areas, board)
        if isinstance(found_order, Rejected):
            return found_order
        order = found_order.ravel()
    points, keep = points[order], keep[order]
    notes: tuple[str, ...] = ()
    if not keep.all():
        what = "dot" if board.type in ("circles", "acircles") else "corner"
        left_out = np.flatnonzero(~keep)
        if board.needs_whole_view and keep.sum() < 0.9 * len(keep):
            u, v = points[left_out[0]]
            return Rejected(
                f"partial board: {len(left_out)} of {len(keep)} {what}s (e.g. near ({u:.0f}, "
                f"{v:.0f}) px) are cut by the image edge or cannot be measured"
            )
        shown = ", ".join(str(int(i)) for i in ids[left_out][:8])
        more = ", ..." if len(left_out) > 8 else ""
        notes = (
            f"{len(left_out)} {what}(s) at the image edge or unmeasurable left out (ids {shown}"
            f"{more})",
        )
        ids, points = ids[keep], points[keep]
    if len(ids) < min_points:
        return Rejected(
            f"only {len(ids)} points usable away from the image edge (need {min_points})"
        )
    return Detection(board, np.asarray(ids, int), points.astype(float), (width, height), notes)


def _find_chessboard(gray: np.ndarray, board: Board) -> tuple[np.ndarray, np.ndarray] | Rejected:
    """OpenCV's classic finder with its fast check first (milliseconds, also to reject frames
    without a board), then the more robust sector-based finder (``findChessboardCornersSB``)."""
    rows, cols = board.grid_shape
    fast = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK  # adaptive: seconds if partial
    ok, corners = cv2.findChessboardCorners(gray, (cols, rows), flags=fast)
    if not ok:
        ok, corners = cv2.findChessboardCornersSB(
            gray, (cols, rows), flags=cv2.CALIB_CB_NORMALIZE_IMAGE
        )
    if not ok or corners is None:
        return Rejected(
            f"no {rows} x {cols} inner-corner chessboard found: the board is missing, partly "
            f"outside the image or hidden, or too blurred"
        )
    return np.arange(rows * cols), corners.reshape(-1, 2).astype(float)


@functools.lru_cache(maxsize=8)
def _charuco_detector(board: Board) -> cv2.aruco.CharucoDetector:
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE
    charuco_params = cv2.aruco.CharucoParameters()
    charuco_params.minMarkers = 1
    return cv2.aruco.CharucoDetector(charuco_board(board), charuco_params, params)


def _find_charuco(
    gray: np.ndarray, board: Board, min_points: int
) -> tuple[np.ndarray, np.ndarray] | Rejected:
    corners, ids, _, marker_ids = _charuco_detector(board).detectBoard(gray)
    n_markers = 0 if marker_ids is None else len(marker_ids)
    n = 0 if ids is None else len(ids)
    if n == 0:
        if n_markers == 0:
            return Rejected(f"no ChArUco board found: no {board.dictionary} markers in the image")
        return Rejected(f"no ChArUco corners found ({n_markers} markers seen)")
    if n < min_points:
        return Rejected(
            f"partial ChArUco board: only {n} corners found ({n_markers} markers), "
            f"need {min_points}"
        )
    ids = ids.ravel().astype(int)
    if charuco_board(board).checkCharucoCornersCollinear(ids.reshape(-1, 1).astype(np.int32)):
        return Rejected(f"the {n} ChArUco corners found lie on one line: the pose is undetermined")
    return ids, corners.reshape(-1, 2).astype(float)


def _blob_detector(shape: tuple[int, int], board: Board) -> cv2.SimpleBlobDetector:
    params = cv2.SimpleBlobDetector_Params()
    params.filterByColor = True
    params.blobColor = 0
    params.filterByArea = True
    params.minArea = 8.0
    params.maxArea = max(100.0, 0.5 * shape[0] * shape[1] / board.n_points)
    params.filterByCircularity = False
    params.filterByInertia = True
    params.minInertiaRatio = 0.05
    params.filterByConvexity = True
    params.minConvexity = 0.85
    params.minDistBetweenBlobs = 2.0
    return cv2.SimpleBlobDetector_create(params)


def _find_circles(gray: np.ndarray, board: Board) -> tuple[np.ndarray, np.ndarray] | Rejected:
    rows, cols = board.grid_shape
    grid = cv2.CALIB_CB_SYMMETRIC_GRID if board.type == "circles" else cv2.CALIB_CB_ASYMMETRIC_GRID
    detector = _blob_detector(gray.shape, board)
    for extra in (0, cv2.CALIB_CB_CLUSTERING):
        ok, centres = cv2.findCirclesGrid(gray, (cols, rows), None, grid | extra, detector)
        if ok and centres is not None:
            return np.arange(rows * cols), centres.reshape(-1, 2).astype(float)
    kind = "symmetric" if board.type == "circles" else "asymmetric"
    return Rejected(
        f"no {rows} x {cols} {kind} circle grid found: the board is missing, partly outside the "
        f"image or hidden, or too blurred"
    )


def _neighbour_distance(points: np.ndarray) -> np.ndarray:
    """Distance ``(N,)`` from each point to its nearest other point, px."""
    d = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    return d.min(axis=1)


def _refine_corners(gray: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``cornerSubPix`` at full resolution; also which points are far enough from the edges."""
    height, width = gray.shape
    nn = _neighbour_distance(points) if len(points) > 1 else np.array([20.0])
    win = int(np.clip(np.floor(0.22 * np.percentile(nn, 5)), 2, 12))
    margin = win + 2
    keep = (
        (points[:, 0] >= margin)
        & (points[:, 1] >= margin)
        & (points[:, 0] <= width - 1 - margin)
        & (points[:, 1] <= height - 1 - margin)
    )
    refined = points.copy()
    if keep.any():
        criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
        start = points[keep].astype(np.float32).reshape(-1, 1, 2)
        out = cv2.cornerSubPix(gray, start, (win, win), (-1, -1), criteria)
        refined[keep] = out.reshape(-1, 2)
        moved = np.linalg.norm(refined - points, axis=1)
        keep &= moved < max(2.0, win)  # a corner that ran off is not trusted
    return refined, keep


def _refine_dots(gray: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, ...]:
    """Area-weighted grey-level centroids (px) of the dots at full resolution, which dots could
    be measured, and their areas (px^2)."""
    nn = _neighbour_distance(points)
    refined = points.copy()
    keep = np.zeros(len(points), bool)
    areas = np.full(len(points), np.nan)
    for i, (p, d) in enumerate(zip(points, nn, strict=True)):
        result = _dot_centroid(gray, p, d)
        if result is not None:
            centre, areas[i], keep[i] = result
            if keep[i]:
                refined[i] = centre
    return refined, keep, areas


def _dot_centroid(
    gray: np.ndarray, p: np.ndarray, nn: float
) -> tuple[np.ndarray, float, bool] | None:
    """Centroid (px), area (px^2) of the dark dot nearest ``p`` (``nn``: distance to the next
    dot, px) and whether it is clean (False: it touches the image edge, the centroid is biased);
    None when the dot cannot be separated from its surroundings."""
    height, width = gray.shape
    half = int(np.ceil(0.8 * nn)) + 2
    cx0, cy0 = int(round(p[0])), int(round(p[1]))
    x0, y0 = max(cx0 - half, 0), max(cy0 - half, 0)
    x1, y1 = min(cx0 + half + 1, width), min(cy0 + half + 1, height)
    if x1 - x0 < 5 or y1 - y0 < 5:
        return None
    roi = gray[y0:y1, x0:x1]
    _, dark = cv2.threshold(roi, 0, 255, cv2.THRESH_BINARY_INV | cv2.THRESH_OTSU)
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(dark, connectivity=8)
    if n < 2:
        return None
    label = labels[cy0 - y0, cx0 - x0]
    if label == 0:
        dist = np.linalg.norm(centroids[1:] - [cx0 - x0, cy0 - y0], axis=1)
        label = int(np.argmin(dist)) + 1
    left, top, w, h = stats[label, :4]
    at_left, at_top = left == 0, top == 0
    at_right, at_bottom = left + w >= roi.shape[1], top + h >= roi.shape[0]
    if (
        (at_left and x0 > 0)
        or (at_top and y0 > 0)
        or (at_right and x1 < width)
        or (at_bottom and y1 < height)
    ):
        return None  # the blob runs into the window: not an isolated dot
    clean = not (at_left or at_top or at_right or at_bottom)
    blob = (labels == label).astype(np.uint8)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
    inner = cv2.erode(blob, kernel)
    grown = cv2.dilate(blob, kernel, iterations=3)
    ring = cv2.dilate(blob, kernel, iterations=6) & ~grown & (dark == 0)
    if not inner.any() or not ring.any():
        return None
    values = roi.astype(np.float64)
    black = float(np.median(values[inner > 0]))
    white = float(np.median(values[ring > 0]))
    if white - black < 5.0:
        return None
    mask = grown.astype(bool) & ~((dark > 0) & (labels != label))
    weight = np.where(mask, (white - values) / (white - black), 0.0)
    total = weight.sum()
    if total <= 0:
        return None
    ys, xs = np.mgrid[0 : roi.shape[0], 0 : roi.shape[1]]
    cx = (weight * xs).sum() / total + x0
    cy = (weight * ys).sum() / total + y0
    return np.array([cx, cy]), float(total), clean


# ----------------------------------------------------------------------------- point order


def _grid_symmetries(grid: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """Index arrays ``(R, C)`` that re-order a grid by each symmetry of its shape."""
    rows, cols = grid.shape[:2]
    idx = np.arange(rows * cols).reshape(rows, cols)
    out = [
        ("identity", idx),
        ("rot180", idx[::-1, ::-1]),
        ("flip_rows", idx[::-1, :]),
        ("flip_cols", idx[:, ::-1]),
    ]
    if rows == cols:
        out += [
            ("transpose", idx.T),
            ("rot90", np.rot90(idx, 1)),
            ("rot270", np.rot90(idx, 3)),
            ("anti_transpose", np.rot90(idx, 2).T),
        ]
    return out


def _right_handed(points: np.ndarray) -> bool:
    """True when x (along a row) turned to y (down a column) is clockwise in the image, as for a
    board seen from its printed side."""
    x = points[0, -1] - points[0, 0]
    y = points[-1, 0] - points[0, 0]
    return float(x[0] * y[1] - x[1] * y[0]) > 0.0


def _candidates(grid: np.ndarray) -> list[np.ndarray]:
    flat = grid.reshape(-1, 2)
    return [idx for _, idx in _grid_symmetries(grid) if _right_handed(flat[idx])]


def _sample(gray: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Mean grey level ``(N,)`` of the 3x3 pixels around each point ``(N, 2)``."""
    height, width = gray.shape
    u = np.clip(np.rint(xy[:, 0]).astype(int), 1, width - 2)
    v = np.clip(np.rint(xy[:, 1]).astype(int), 1, height - 2)
    total = np.zeros(len(xy))
    for dv in (-1, 0, 1):
        for du in (-1, 0, 1):
            total += gray[v + dv, u + du]
    return total / 9.0


def _chessboard_order(gray: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Re-ordering ``(R, C)`` of a detected corner grid that matches the square colours
    (square between corners ``(i, j)`` and ``(i+1, j+1)`` is black when ``i + j`` is even)."""
    flat = grid.reshape(-1, 2)
    best, best_score = None, -np.inf
    for idx in _candidates(grid):
        g = flat[idx]
        centres = 0.25 * (g[:-1, :-1] + g[1:, :-1] + g[:-1, 1:] + g[1:, 1:])
        levels = _sample(gray, centres.reshape(-1, 2)).reshape(centres.shape[:2])
        i, j = np.indices(levels.shape)
        sign = np.where((i + j) % 2 == 0, -1.0, 1.0)
        score = float((sign * (levels - levels.mean())).sum())
        if score > best_score + 1e-9:
            best, best_score = idx, score
    return best if best is not None else np.arange(flat.shape[0]).reshape(grid.shape[:2])


def _outer_squares_mismatch(gray: np.ndarray, grid: np.ndarray) -> str | None:
    """Check a detected corner grid ``(R, C, 2)`` against the declared board: the squares just
    outside the grid are the board's outer squares and must continue the colour alternation.
    A grid that takes the pattern's edge (where black squares meet the white margin) for a row
    of corners, as a finder may when the board has fewer rows or columns than declared, puts
    margin there instead. Returns why the grid does not fit, or None."""
    rows, cols = grid.shape[:2]
    i, j = np.mgrid[0:rows, 0:cols]
    src = np.stack([j.ravel(), i.ravel()], axis=1).astype(np.float32)
    hom, _ = cv2.findHomography(src, grid.reshape(-1, 2).astype(np.float32))
    if hom is None:
        return None
    ci, cj = np.mgrid[-1:rows, -1:cols]
    centres = np.stack([cj.ravel() + 0.5, ci.ravel() + 0.5], axis=1)
    img = cv2.perspectiveTransform(centres[None].astype(np.float64), hom)[0]
    height, width = gray.shape
    inside = (
        (img[:, 0] >= 1) & (img[:, 0] <= width - 2) & (img[:, 1] >= 1) & (img[:, 1] <= height - 2)
    )
    levels = _sample(gray, img)
    dark = ((ci.ravel() + cj.ravel()) % 2) == 0
    ring = (ci.ravel() < 0) | (ci.ravel() == rows - 1) | (cj.ravel() < 0) | (cj.ravel() == cols - 1)
    core = ~ring & inside
    if not (core & dark).any() or not (core & ~dark).any():
        return None
    threshold = 0.5 * (np.median(levels[core & dark]) + np.median(levels[core & ~dark]))
    wrong = (levels > threshold) == dark  # a dark square brighter than the threshold, or vice versa
    sides = {
        "before the first row": ci.ravel() < 0,
        "after the last row": ci.ravel() == rows - 1,
        "before the first column": cj.ravel() < 0,
        "after the last column": cj.ravel() == cols - 1,
    }
    for name, side in sides.items():
        seen = side & inside
        if seen.sum() >= 3 and wrong[seen].mean() > 0.3:
            return (
                f"the detected {rows} x {cols} corner grid does not match the printed pattern: "
                f"{int(wrong[seen].sum())} of {int(seen.sum())} squares {name} have the wrong "
                "colour, so the finder took the pattern's edge for a row of corners; the board "
                "has fewer rows or columns than declared?"
            )
    return None


def _circle_order(grid: np.ndarray, areas: np.ndarray, board: Board) -> np.ndarray | Rejected:
    """Right-handed re-ordering of a symmetric dot grid; with an origin marker, the big dot
    (largest ``areas``, px^2) becomes point 0."""
    candidates = _candidates(grid)
    if not board.origin_marker:
        return candidates[0]
    if np.isnan(areas).all():
        return Rejected("origin marker not found: no dot could be measured")
    big = int(np.nanargmax(areas))
    ratio = areas[big] / np.nanmedian(areas)
    if ratio < 2.0:
        return Rejected(
            f"origin marker not found: the largest dot is only {ratio:.1f}x the median area"
        )
    for idx in candidates:
        if idx[0, 0] == big:
            return idx
    return Rejected("origin marker (big dot) is not at a corner of the detected grid")


# ----------------------------------------------------------------------------- pose


def _rt_to_T(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """``T_board_camera`` from OpenCV's board-to-camera ``rvec, tvec``."""
    rot, _ = cv2.Rodrigues(np.asarray(rvec, float).reshape(3, 1))
    T_camera_board = tf.homogeneous(rot, np.asarray(tvec, float).ravel())
    return tf.invert(T_camera_board)


def _pose_vector_jacobian(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """d to_vector(T_board_camera) / d(tvec, rvec), ``(6, 6)``, for OpenCV's board-to-camera
    ``rvec, tvec``: the camera position is ``-R^T t`` and its rotation vector is ``-rvec``."""
    rot, drot = cv2.Rodrigues(np.asarray(rvec, float).reshape(3, 1))  # drot: (3, 9) dR/dr_k
    t = np.ravel(tvec)
    jac = np.zeros((6, 6))
    jac[:3, :3] = -rot.T
    for k in range(3):
        jac[:3, 3 + k] = -drot[k].reshape(3, 3).T @ t
    jac[3:, 3:] = -np.eye(3)
    return jac


def dot_bias(
    board: Board, camera: Camera, rvec: np.ndarray, tvec: np.ndarray, ids: np.ndarray, n: int = 48
) -> np.ndarray:
    """Perspective bias ``(N, 2)`` (px) of dot centroids: centroid of each dot's image (projected
    outline as a polygon) minus the image of its centre."""
    from relcal.vision.boards import dots

    centres, diameters = dots(board)
    angles = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    circle = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    outline = centres[ids, None, :] + 0.5 * diameters[ids, None, None] * circle
    pts = np.concatenate([outline.reshape(-1, 2), centres[ids]], axis=0)
    pts3 = np.concatenate([pts, np.zeros((len(pts), 1))], axis=1)
    uv, _ = cv2.projectPoints(pts3, rvec, tvec, camera.matrix, camera.dist)
    uv = uv.reshape(-1, 2)
    poly = uv[: len(ids) * n].reshape(len(ids), n, 2)
    x, y = poly[..., 0], poly[..., 1]
    xn, yn = np.roll(x, -1, axis=1), np.roll(y, -1, axis=1)
    cross = x * yn - xn * y
    area = 0.5 * cross.sum(axis=1)
    cx = ((x + xn) * cross).sum(axis=1) / (6 * area)
    cy = ((y + yn) * cross).sum(axis=1) / (6 * area)
    return np.stack([cx, cy], axis=1) - uv[len(ids) * n :]


def estimate_pose(
    detection: Detection,
    camera: Camera,
    *,
    pixel_sigma: float | None = None,
    max_rms: float = 1.0,
    min_points: int = 6,
    dot_bias_correction: bool = True,
) -> PoseResult | Rejected:
    """Camera pose in the board frame from one detection.

    Parameters
    ----------
    detection : Detection
    camera : Camera
    pixel_sigma : float or None
        Image noise per coordinate, px; ``None`` estimates it from the residuals
        (``sqrt(sum r^2 / (2N - 6))``).
    max_rms : float
        Frames whose reprojection RMS is above this (px) are rejected.
    min_points : int
        Fewer points are rejected.
    dot_bias_correction : bool
        For circle grids, remove the predicted perspective shift of dot centroids.

    Returns
    -------
    PoseResult or Rejected
    """
    obj = detection.object_points
    img = detection.image_points.astype(float)
    n = len(obj)
    if n < max(min_points, 4):
        return Rejected(f"only {n} points, the pose needs at least {max(min_points, 4)}")
    k, dist = camera.matrix, camera.dist
    ok, rvecs, tvecs, errs = cv2.solvePnPGeneric(obj, img, k, dist, flags=cv2.SOLVEPNP_IPPE)
    if not ok or not rvecs:
        return Rejected("PnP failed: the points do not determine a pose")
    best = int(np.argmin(np.ravel(errs))) if errs is not None else 0
    rvec, tvec = rvecs[best].reshape(3, 1), tvecs[best].reshape(3, 1)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    target = img
    is_dots = detection.board.type in ("circles", "acircles") and dot_bias_correction
    for _ in range(3 if is_dots else 1):
        rvec, tvec = cv2.solvePnPRefineLM(obj, target, k, dist, rvec, tvec, criteria=criteria)
        if is_dots:
            target = img - dot_bias(detection.board, camera, rvec, tvec, detection.ids)
    if float(tvec[2, 0]) <= 0:
        return Rejected("PnP put the board behind the camera")
    proj, jac = cv2.projectPoints(obj, rvec, tvec, k, dist)
    residuals = target - proj.reshape(-1, 2)
    rms = float(np.sqrt(np.mean(np.sum(residuals**2, axis=1))))
    if not np.isfinite(rms):
        return Rejected("PnP gave a non-finite pose")
    if rms > max_rms:
        return Rejected(f"reprojection RMS {rms:.3f} px is above the {max_rms:.3f} px limit")
    dof = 2 * n - 6
    sigma = (
        float(pixel_sigma)
        if pixel_sigma is not None
        else float(np.sqrt(np.sum(residuals**2) / max(dof, 1)))
    )
    j = jac[:, [3, 4, 5, 0, 1, 2]]  # columns (tvec, rvec)
    normal = j.T @ j
    if np.linalg.cond(normal) > 1e14:
        return Rejected("the points do not constrain the pose (degenerate geometry)")
    cov_cb = sigma**2 * np.linalg.inv(normal)
    g = _pose_vector_jacobian(rvec, tvec)
    cov = g @ cov_cb @ g.T
    return PoseResult(
        T_board_camera=_rt_to_T(rvec, tvec),
        rms=rms,
        covariance=0.5 * (cov + cov.T),
        pixel_sigma=sigma,
        residuals=residuals,
        ids=detection.ids.copy(),
    )


# ----------------------------------------------------------------------------- many images


@dataclass(frozen=True, eq=False)
class ImageResult:
    """What became of one image file: a detection, a pose (when a camera was given), or the
    reason it was rejected."""

    path: str
    detection: Detection | None = None
    pose: PoseResult | None = None
    reason: str | None = None

    @property
    def ok(self) -> bool:
        return self.reason is None


def measure_image(
    path: str | Path,
    board: Board,
    camera: Camera | None = None,
    *,
    max_side: int = 1600,
    min_points: int = 6,
    max_rms: float = 1.0,
    pixel_sigma: float | None = None,
) -> ImageResult:
    """Read one image file, detect the board and (with a camera) estimate the pose."""
    path = str(path)
    image = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
    if image is None:
        reason = "file not found" if not os.path.exists(path) else "not a readable image"
        return ImageResult(path, reason=f"{path}: {reason}")
    if camera is not None and camera.width is not None and camera.height is not None:
        if (image.shape[1], image.shape[0]) != (camera.width, camera.height):
            return ImageResult(
                path,
                reason=f"{path}: image is {image.shape[1]}x{image.shape[0]} px, the camera "
                f"{camera.width}x{camera.height}",
            )
    found = detect(image, board, max_side=max_side, min_points=min_points)
    if isinstance(found, Rejected):
        return ImageResult(path, reason=f"{path}: {found.reason}")
    if camera is None:
        return ImageResult(path, detection=found)
    pose = estimate_pose(
        found, camera, pixel_sigma=pixel_sigma, max_rms=max_rms, min_points=min_points
    )
    if isinstance(pose, Rejected):
        return ImageResult(path, detection=found, reason=f"{path}: {pose.reason}")
    return ImageResult(path, detection=found, pose=pose)


def _measure_star(args: tuple) -> ImageResult:
    path, board, camera, kwargs = args
    return measure_image(path, board, camera, **kwargs)


def measure_images(
    paths: Sequence[str | Path],
    board: Board,
    camera: Camera | None = None,
    *,
    workers: int = 2,
    progress: bool = True,
    max_side: int = 1600,
    min_points: int = 6,
    max_rms: float = 1.0,
    pixel_sigma: float | None = None,
) -> list[ImageResult]:
    """Detect the board (and estimate the pose, given a camera) in many image files.

    Runs on ``workers`` threads (``workers <= 1``: this thread only). Decoding, detection and
    refinement happen in OpenCV, which releases the GIL, so threads use the cores without the
    start-up of worker processes (each would import NumPy, SciPy and OpenCV again: slower than
    one thread on a hundred small images). A tqdm progress bar is shown unless ``progress`` is
    False.

    Returns
    -------
    list of ImageResult
        In the order of ``paths``.
    """
    from tqdm import tqdm

    kwargs = {
        "max_side": max_side,
        "min_points": min_points,
        "max_rms": max_rms,
        "pixel_sigma": pixel_sigma,
    }
    jobs = [(str(p), board, camera, kwargs) for p in paths]
    bar = functools.partial(
        tqdm, total=len(jobs), disable=not progress, unit="image", desc="measuring"
    )
    workers = min(int(workers), len(jobs))
    if workers <= 1:
        return [_measure_star(job) for job in bar(jobs)]
    with ThreadPoolExecutor(workers) as pool:
        return list(bar(pool.map(_measure_star, jobs)))
