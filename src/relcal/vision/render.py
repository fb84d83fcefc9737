"""Synthetic camera images of a board at a known pose, for tests and simulation.

Each output pixel is the average of ``supersample x supersample`` rays. The rays of all pixel
centres are undistorted once per camera with OpenCV (iterated to 1e-12 px) and interpolated
linearly to the sub-pixel points (the distortion field is smooth); each ray is intersected with the
board plane, and the board's anti-aliased reflectance texture (exact area
coverage, see :func:`boards.reflectance`) is sampled there with ``cv2.remap``. Blur, an
uneven lighting gradient and Gaussian noise are then applied, so tests know the true pose while
the image looks like a camera's.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from relcal.vision.boards import Board, board_extent, reflectance
from relcal.vision.camera import Camera

#: Grey levels (0..1 of full scale) of the ink, the paper and the scene around the board.
INK_LEVEL = 0.08
PAPER_LEVEL = 0.85
BACKGROUND_LEVEL = 0.35

_MAX_TEXTURE_PIXELS = 24_000_000
_STRIP_ROWS = 64


@functools.lru_cache(maxsize=2)
def _texture(board: Board, px_per_m: float) -> tuple[np.ndarray, tuple[float, float]]:
    image, origin = reflectance(board, px_per_m)
    levels = INK_LEVEL + (PAPER_LEVEL - INK_LEVEL) * image
    levels.setflags(write=False)
    return levels, origin


def texture_density(
    board: Board, camera: Camera, T_board_camera: np.ndarray, supersample: int
) -> float:
    """Texture density (px/m) fine enough for the nearest part of the board, quantised to
    quarter octaves (so nearby poses share a cached texture) and capped in size."""
    x0, y0, x1, y1 = board_extent(board)
    corners = np.array([[x0, y0, 0, 1], [x1, y0, 0, 1], [x1, y1, 0, 1], [x0, y1, 0, 1.0]])
    T_camera_board = np.linalg.inv(T_board_camera)
    depth = (corners @ T_camera_board.T)[:, 2]
    if not np.any(depth > 0):
        return 1024.0  # the board is behind the camera: nothing will be sampled
    nearest = max(float(depth[depth > 0].min()), 1e-3)
    wanted = supersample * max(camera.fx, camera.fy) / nearest
    area = (x1 - x0) * (y1 - y0)
    wanted = min(wanted, np.sqrt(_MAX_TEXTURE_PIXELS / area))
    return float(2.0 ** (np.ceil(4.0 * np.log2(wanted)) / 4.0))


@functools.lru_cache(maxsize=1)
def _ray_grid(camera: Camera) -> np.ndarray:
    """Normalised rays ``(H + 2, W + 2, 2)`` of the pixel centres ``v, u = -1 .. H, -1 .. W``."""
    width, height = camera.size
    u = np.arange(-1, width + 1, dtype=float)
    v = np.arange(-1, height + 1, dtype=float)
    return _rays(camera, u, v)


def _rays(camera: Camera, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Normalised ray directions ``(len(v), len(u), 2)`` (x/z, y/z) for the pixel grid ``v x u``."""
    uu, vv = np.meshgrid(u, v)
    if not any(camera.distortion):
        xn = (uu - camera.cx) / camera.fx
        yn = (vv - camera.cy) / camera.fy
        return np.stack([xn, yn], axis=-1)
    return camera.undistort(np.stack([uu, vv], axis=-1).reshape(-1, 2)).reshape(*uu.shape, 2)


def _interpolate(grid: np.ndarray, first: int, count: int, s: int, axis: int) -> np.ndarray:
    """Linear interpolation of ``grid`` (pixel-centre samples offset by one) at ``s`` sub-pixel
    positions inside each of the pixels ``first .. first + count - 1`` along ``axis``."""
    offsets = (np.arange(s) + 0.5) / s - 0.5
    low = np.floor(offsets).astype(int)
    frac = offsets - low
    idx = (np.arange(first, first + count)[:, None] + 1 + low).ravel()
    w = np.tile(frac, count)
    shape = [1] * grid.ndim
    shape[axis] = len(w)
    w = w.reshape(shape)
    return (1.0 - w) * np.take(grid, idx, axis=axis) + w * np.take(grid, idx + 1, axis=axis)


def subsample_rays(camera: Camera, first_row: int, rows: int, s: int) -> np.ndarray:
    """Normalised rays ``(rows * s, W * s, 2)`` through ``s x s`` sub-pixel points of image rows
    ``first_row .. first_row + rows - 1`` (pixel centres at integer coordinates)."""
    grid = _ray_grid(camera)
    width = camera.size[0]
    strip = _interpolate(grid, first_row, rows, s, axis=0)
    return _interpolate(strip, 0, width, s, axis=1)


def plane_homography(T_board_camera: np.ndarray) -> np.ndarray:
    """Homography ``(3, 3)`` from normalised camera rays ``(x/z, y/z, 1)`` to board-plane points
    ``(X, Y, 1)`` (m), and its last row is the ray's direction along the board normal."""
    rot, t = T_board_camera[:3, :3], T_board_camera[:3, 3]
    return np.stack([t[0] * rot[2] - t[2] * rot[0], t[1] * rot[2] - t[2] * rot[1], rot[2]])


def board_hits(rays: np.ndarray, T_board_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Board-plane points hit by camera rays.

    Parameters
    ----------
    rays : ndarray, shape (..., 2)
        Normalised ray directions (x/z, y/z) in the camera frame.
    T_board_camera : ndarray, shape (4, 4)

    Returns
    -------
    xy : ndarray, shape (..., 2)
        Board coordinates (m) of each ray's intersection with the plane z = 0.
    valid : ndarray of bool, shape (...)
        False where the ray misses the plane (parallel to it, or the plane is behind).
    """
    h = plane_homography(np.asarray(T_board_camera, float))
    x, y = rays[..., 0], rays[..., 1]
    den = h[2, 0] * x + h[2, 1] * y + h[2, 2]
    valid = den * -T_board_camera[2, 3] > 0
    den = np.where(valid, den, 1.0)
    xy = np.stack(
        [(h[0, 0] * x + h[0, 1] * y + h[0, 2]) / den, (h[1, 0] * x + h[1, 1] * y + h[1, 2]) / den],
        axis=-1,
    )
    return xy, valid


def render_board(
    board: Board,
    camera: Camera,
    T_board_camera: np.ndarray,
    blur_sigma: float = 0.0,
    noise_sigma: float = 0.0,
    lighting_gradient: float = 0.0,
    seed: int | None = 0,
    *,
    supersample: int = 3,
    background: float = BACKGROUND_LEVEL,
) -> np.ndarray:
    """Image of ``board`` seen by ``camera`` at pose ``T_board_camera``:
    :func:`render_levels` followed by :func:`finish_image`.

    Parameters
    ----------
    board : Board
    camera : Camera
        Intrinsics, distortion and image size (``width``, ``height`` required).
    T_board_camera : ndarray, shape (4, 4)
        Camera pose in the board frame (m); the camera looks along its +z axis.
    blur_sigma : float
        Gaussian blur (defocus), px.
    noise_sigma : float
        Gaussian noise, grey levels (0..255 scale).
    lighting_gradient : float
        Relative brightness change across the image diagonal (0.3: -15 % top-left to +15 %
        bottom-right).
    seed : int or None
        Seed of the noise.
    supersample : int
        Rays per pixel along each axis (anti-aliasing).
    background : float
        Grey level of the scene around the board (0..1).

    Returns
    -------
    ndarray, uint8, shape (height, width)
    """
    levels = render_levels(
        board, camera, T_board_camera, supersample=supersample, background=background
    )
    return finish_image(levels, blur_sigma, noise_sigma, lighting_gradient, seed)


def render_levels(
    board: Board,
    camera: Camera,
    T_board_camera: np.ndarray,
    *,
    supersample: int = 3,
    background: float = BACKGROUND_LEVEL,
) -> np.ndarray:
    """Ideal (noise-free, unblurred, evenly lit) image of the board, grey levels 0..1,
    float32 ``(height, width)``; arguments as for :func:`render_board`."""
    width, height = camera.size
    T_board_camera = np.asarray(T_board_camera, float)
    s = int(supersample)
    if s < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    ppm = texture_density(board, camera, T_board_camera, s)
    texture, (x0, y0) = _texture(board, ppm)
    # rays -> texture pixel coordinates (pixel centres at integers)
    to_texture = np.array([[ppm, 0.0, -x0 * ppm - 0.5], [0.0, ppm, -y0 * ppm - 0.5], [0, 0, 1]])
    h = to_texture @ plane_homography(T_board_camera)
    out = np.empty((height, width), np.float32)
    for r0 in range(0, height, _STRIP_ROWS):
        r1 = min(r0 + _STRIP_ROWS, height)
        rays = subsample_rays(camera, r0, r1 - r0, s)
        x, y = rays[..., 0], rays[..., 1]
        den = h[2, 0] * x + h[2, 1] * y + h[2, 2]
        behind = den * -T_board_camera[2, 3] <= 0
        den[behind] = np.inf
        map_u = ((h[0, 0] * x + h[0, 1] * y + h[0, 2]) / den).astype(np.float32)
        map_v = ((h[1, 0] * x + h[1, 1] * y + h[1, 2]) / den).astype(np.float32)
        map_u[behind] = -1e6
        samples = cv2.remap(
            texture,
            map_u,
            map_v,
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=float(background),
        )
        out[r0:r1] = samples.reshape(r1 - r0, s, width, s).mean(axis=(1, 3))
    return out


def finish_image(
    levels: np.ndarray,
    blur_sigma: float = 0.0,
    noise_sigma: float = 0.0,
    lighting_gradient: float = 0.0,
    seed: int | None = 0,
) -> np.ndarray:
    """Lighting, blur and noise on an ideal image of grey levels ``(H, W)`` in 0..1; uint8 out."""
    height, width = levels.shape
    img = levels.astype(np.float32)
    if lighting_gradient:
        ramp = 0.5 * (np.arange(width)[None, :] / max(width - 1, 1)) + 0.5 * (
            np.arange(height)[:, None] / max(height - 1, 1)
        )
        img = img * (1.0 + lighting_gradient * (ramp - 0.5)).astype(np.float32)
    if blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma, borderType=cv2.BORDER_REFLECT)
    img = img * 255.0
    if noise_sigma > 0:
        rng = np.random.default_rng(seed)
        img = img + rng.normal(0.0, noise_sigma, img.shape).astype(np.float32)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """Camera pose ``T_board_camera`` ``(4, 4)`` at ``eye`` looking at ``target`` (board frame, m).

    The camera's y axis (image down) is aligned with ``up`` (default board +y) as far as possible.
    """
    eye = np.asarray(eye, float)
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    up = np.array([0.0, 1.0, 0.0]) if up is None else np.asarray(up, float)
    x = np.cross(up, z)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross([1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    out = np.eye(4)
    out[:3, :3] = np.stack([x, y, z], axis=1)
    out[:3, 3] = eye
    return out
