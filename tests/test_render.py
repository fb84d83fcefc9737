"""The renderer against OpenCV's forward projection: geometry with distortion, anti-aliasing,
noise, blur and lighting."""

import cv2
import numpy as np
import pytest

from relcal.geometry import invert
from relcal.vision.boards import Board, board_points, dots
from relcal.vision.camera import Camera
from relcal.vision.render import (
    BACKGROUND_LEVEL,
    INK_LEVEL,
    PAPER_LEVEL,
    finish_image,
    look_at,
    render_board,
    render_levels,
)

# 8 mm lens on a 1280 x 1024 sensor with 4.8 um pixels... scaled down: 640 x 512, f = 1200 px
CAMERA = Camera(1200.0, 1201.0, 322.4, 254.1, (-0.15, 0.09, 4e-4, -3e-4, 0.0), 640, 512)
DOTS = Board("circles", 5, 7, 0.02, diameter=0.01)


def project(camera, T_board_camera, points):
    """OpenCV projection of board-frame points ``(N, 3)``."""
    T = invert(T_board_camera)
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    uv, _ = cv2.projectPoints(points.astype(float), rvec, T[:3, 3], camera.matrix, camera.dist)
    return uv.reshape(-1, 2)


def ellipse_centroids(camera, T_board_camera, board):
    """Area centroids of the projected dot outlines (polygons of 256 points), px."""
    centres, diameters = dots(board)
    a = np.linspace(0, 2 * np.pi, 256, endpoint=False)
    out = []
    for c, d in zip(centres, diameters, strict=True):
        ring = np.stack([c[0] + d / 2 * np.cos(a), c[1] + d / 2 * np.sin(a), 0 * a], axis=1)
        p = project(camera, T_board_camera, ring)
        x, y = p[:, 0], p[:, 1]
        xn, yn = np.roll(x, -1), np.roll(y, -1)
        cross = x * yn - xn * y
        area = cross.sum() / 2
        out.append([((x + xn) * cross).sum() / (6 * area), ((y + yn) * cross).sum() / (6 * area)])
    return np.array(out)


def image_centroids(levels, guesses, half):
    """Ink-weighted centroids of a noise-free level image around each guess (px)."""
    out = []
    for u, v in guesses:
        u0, v0 = int(round(u)) - half, int(round(v)) - half
        win = levels[v0 : v0 + 2 * half + 1, u0 : u0 + 2 * half + 1].astype(float)
        w = (PAPER_LEVEL - win) / (PAPER_LEVEL - INK_LEVEL)
        ys, xs = np.mgrid[0 : win.shape[0], 0 : win.shape[1]]
        out.append([(w * xs).sum() / w.sum() + u0, (w * ys).sum() / w.sum() + v0])
    return np.array(out)


def oblique_pose(board, distance=0.45):
    centre = board_points(board).mean(axis=0)
    return look_at(centre + [0.12, -0.08, -distance], centre, up=[0.2, 1.0, 0.0])


def test_dot_images_sit_where_opencv_projects_them_with_distortion():
    """Rendered dot centroids match OpenCV's projection of the dot outlines (with lens
    distortion) to a few thousandths of a pixel (measured max 0.0037 px)."""
    T = oblique_pose(DOTS)
    levels = render_levels(DOTS, CAMERA, T, supersample=3)
    truth = ellipse_centroids(CAMERA, T, DOTS)
    found = image_centroids(levels, truth, half=15)
    err = np.linalg.norm(found - truth, axis=1)
    assert err.max() < 0.006, err.max()

    # the distortion matters here: ignoring it would move the dots by pixels
    pinhole = Camera(CAMERA.fx, CAMERA.fy, CAMERA.cx, CAMERA.cy, (), 640, 512)
    assert np.linalg.norm(ellipse_centroids(pinhole, T, DOTS) - truth, axis=1).max() > 0.3


def test_ink_area_is_conserved_by_antialiasing():
    """Fronto-parallel chessboard, no distortion: total ink in the image equals the black area
    times the squared magnification (area averaging, not point sampling)."""
    board = Board("chessboard", 5, 6, 0.013, margin=0.01)
    camera = Camera(1000.0, 1000.0, 319.5, 255.5, (), 640, 512)
    z = 0.5
    T = look_at([0.03, 0.02, -z], [0.03, 0.02, 0.0])
    levels = render_levels(board, camera, T, supersample=2, background=PAPER_LEVEL)
    ink_px = float(np.sum(PAPER_LEVEL - levels.astype(float))) / (PAPER_LEVEL - INK_LEVEL)
    expected = 15 * (board.spacing * camera.fx / z) ** 2
    assert ink_px == pytest.approx(expected, rel=3e-3)


def test_supersampling_converges():
    """Dot centroid error (px) shrinks with the rays per pixel: measured max 0.026 (1x1),
    0.0063 (2x2), 0.0037 (3x3), 0.0012 (6x6)."""
    T = oblique_pose(DOTS)
    truth = ellipse_centroids(CAMERA, T, DOTS)
    worst = {}
    for s in (1, 2, 6):
        levels = render_levels(DOTS, CAMERA, T, supersample=s)
        worst[s] = np.linalg.norm(image_centroids(levels, truth, 15) - truth, axis=1).max()
    assert worst[6] < worst[2] < worst[1]
    assert worst[1] > 3 * worst[6] and worst[6] < 0.002


def test_noise_blur_and_lighting():
    flat = np.full((200, 300), 0.5, np.float32)
    noisy = finish_image(flat, noise_sigma=4.0, seed=3).astype(float)
    assert noisy.std() == pytest.approx(4.0, rel=0.05) and noisy.mean() == pytest.approx(127.5, 0.5)
    assert np.array_equal(noisy, finish_image(flat, noise_sigma=4.0, seed=3))
    assert not np.array_equal(noisy, finish_image(flat, noise_sigma=4.0, seed=4))

    lit = finish_image(flat, lighting_gradient=0.4).astype(float)
    assert lit[0, 0] == pytest.approx(0.5 * 0.8 * 255, abs=1)  # -20 % at the top left
    assert lit[-1, -1] == pytest.approx(0.5 * 1.2 * 255, abs=1)  # +20 % at the bottom right

    edge = np.zeros((50, 50), np.float32)
    edge[:, 25:] = 1.0
    blurred = finish_image(edge, blur_sigma=2.0).astype(float)
    profile = blurred[25, 15:35] / 255
    # a Gaussian-blurred step: 16 % and 84 % one sigma either side of the edge at 24.5
    assert np.interp(22.5, np.arange(15, 35), profile) == pytest.approx(0.16, abs=0.03)
    assert np.interp(26.5, np.arange(15, 35), profile) == pytest.approx(0.84, abs=0.03)


def test_board_behind_the_camera_is_not_drawn():
    T = look_at([0.05, 0.05, -0.5], [0.05, 0.05, 0.0])
    behind = T.copy()
    behind[:3, 2] *= -1  # look away from the board (keep a right-handed frame)
    behind[:3, 0] *= -1
    image = render_board(DOTS, CAMERA, behind)
    assert np.all(image == round(BACKGROUND_LEVEL * 255))
    assert np.any(render_board(DOTS, CAMERA, T) < 50)


def test_render_board_output_type_and_size():
    image = render_board(DOTS, CAMERA, oblique_pose(DOTS), 0.7, 2.0, 0.2, seed=1, supersample=2)
    assert image.dtype == np.uint8 and image.shape == (512, 640)
    with pytest.raises(Exception, match="image size"):
        render_board(DOTS, Camera(1000.0, 1000.0, 320, 240), oblique_pose(DOTS))
