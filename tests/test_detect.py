"""Detection and pose on rendered images with known truth; rejections; covariance; batch runs;
camera files and intrinsic calibration.

Measured on these renders (1280 x 1024, f = 2400 px, k1 = -0.12, blur 0.8 px, noise 2 DN, 30 %
lighting gradient, board ~0.5 m away and ~10 deg off axis, 9 board/roll cases): position error
0.007 - 0.13 mm, rotation error 0.0008 - 0.015 deg, reprojection RMS 0.006 px (dots) to 0.027 px
(corners); predicted position std 0.013 - 0.068 mm. Corners: 0.023 px RMS (max 0.039 px) from
the truth, the same whether the search ran at full size or downscaled to 640 px. Tolerances below:
0.4 mm and 0.04 deg. A ChArUco board half out of view: 30 of 48 corners, 0.59 mm, 0.067 deg.
"""

import cv2
import numpy as np
import pytest
from conftest import DATA
from scipy.spatial.transform import Rotation

from relcal import geometry as tf
from relcal.errors import RelcalError
from relcal.vision.boards import Board, board_points
from relcal.vision.camera import Camera, calibrate_intrinsics, load_camera, save_camera
from relcal.vision.detect import (
    Detection,
    PoseResult,
    Rejected,
    detect,
    estimate_pose,
    measure_images,
)
from relcal.vision.render import finish_image, look_at, render_board, render_levels

CAMERA = Camera(2400.0, 2402.0, 641.3, 509.2, (-0.12, 0.08, 4e-4, -3e-4, 0.0), 1280, 1024)
SMALL = Camera(1200.0, 1201.0, 322.4, 254.1, (-0.12, 0.08, 4e-4, -3e-4, 0.0), 640, 512)

BOARDS = {
    "chessboard": Board("chessboard", 8, 11, 0.015),
    "charuco": Board("charuco", 7, 9, 0.02, 0.015, "DICT_5X5_100"),
    "circles": Board("circles", 7, 9, 0.018),
    "circles_origin": Board("circles", 8, 8, 0.016, origin_marker=True),
    "acircles": Board("acircles", 9, 5, 0.015),
}
MAX_POSITION_ERROR = 0.4e-3  # m
MAX_ROTATION_ERROR = np.radians(0.04)


def view(board, roll_deg=0.0, distance=0.5, offset=(0.06, -0.05), aim=(0.0, 0.0)):
    """A camera pose ``distance`` (m) in front of the board centre, off to the side by ``offset``
    (m), looking at the centre shifted by ``aim`` (m), rolled about its axis (deg)."""
    centre = board_points(board).mean(axis=0)
    eye = centre + [offset[0], offset[1], -distance]
    T = look_at(eye, centre + [aim[0], aim[1], 0.0])
    T[:3, :3] = T[:3, :3] @ Rotation.from_euler("z", roll_deg, degrees=True).as_matrix()
    return T


def realistic(board, T, camera=CAMERA, seed=0, supersample=2):
    return render_board(board, camera, T, 0.8, 2.0, 0.3, seed=seed, supersample=supersample)


def pose_error(T_true, T_est):
    """Position (m) and rotation (rad) error between two poses."""
    e = tf.to_vector(tf.invert(T_true) @ T_est)
    return np.linalg.norm(e[:3]), np.linalg.norm(e[3:])


CASES = [
    ("chessboard", 15),
    ("chessboard", 195),  # upside down: corner order follows the square colours
    ("charuco", -30),
    ("charuco", 160),
    ("circles", 20),
    ("circles_origin", 10),
    ("circles_origin", 200),  # the big dot fixes the orientation
    ("acircles", 0),
    ("acircles", 170),
]


@pytest.mark.parametrize("name, roll", CASES)
def test_pose_from_rendered_image_matches_truth(name, roll):
    board = BOARDS[name]
    T = view(board, roll)
    found = detect(realistic(board, T, seed=abs(roll)), board)
    assert isinstance(found, Detection), found
    assert len(found.ids) == board.n_points
    pose = estimate_pose(found, CAMERA)
    assert isinstance(pose, PoseResult), pose
    dp, dr = pose_error(T, pose.T_board_camera)
    assert dp < MAX_POSITION_ERROR, dp
    assert dr < MAX_ROTATION_ERROR, np.degrees(dr)
    assert pose.rms < 0.1
    assert pose.covariance.shape == (6, 6) and np.all(np.linalg.eigvalsh(pose.covariance) > 0)
    assert np.allclose(pose.vector, tf.to_vector(pose.T_board_camera))


def test_detection_points_are_sub_pixel_accurate():
    """Corners found on a downscaled copy and refined at full resolution land within a few
    hundredths of a pixel of the projected truth (measured RMS 0.023 px, max 0.039 px)."""
    board = BOARDS["chessboard"]
    T = view(board, 15)
    image = realistic(board, T)
    T_cb = tf.invert(T)
    rvec, _ = cv2.Rodrigues(T_cb[:3, :3])
    truth, _ = cv2.projectPoints(board_points(board), rvec, T_cb[:3, 3], CAMERA.matrix, CAMERA.dist)
    truth = truth.reshape(-1, 2)
    for max_side in (1600, 640):  # full resolution, and a 2x downscaled search
        found = detect(image, board, max_side=max_side)
        err = np.linalg.norm(found.image_points - truth[found.ids], axis=1)
        assert np.sqrt(np.mean(err**2)) < 0.06 and err.max() < 0.15, (max_side, err.max())


def test_colour_and_deep_images_are_accepted():
    board = BOARDS["chessboard"]
    image = realistic(board, view(board, 15))
    reference = detect(image, board).image_points
    bgr = np.repeat(image[:, :, None], 3, axis=2)
    twelve_bit = image.astype(np.uint16) * 16  # a 12-bit camera's range in 16-bit pixels
    for variant in (bgr, twelve_bit, image / 255.0):
        assert np.allclose(detect(variant, board).image_points, reference, atol=0.02)


def test_covariance_matches_the_scatter_over_noise():
    """Same view, 12 noise draws: the spread of the estimated poses agrees with the predicted
    standard deviations (ratio measured 0.72 - 1.14 over the 6 components)."""
    board = BOARDS["chessboard"]
    T = view(board, 15)
    levels = render_levels(board, CAMERA, T, supersample=2)
    vectors, stds = [], []
    for seed in range(12):
        image = finish_image(levels, blur_sigma=0.8, noise_sigma=8.0, seed=seed)
        pose = estimate_pose(detect(image, board), CAMERA)
        vectors.append(pose.vector)
        stds.append(pose.std)
    spread = np.std(np.array(vectors), axis=0, ddof=1)
    predicted = np.sqrt(np.mean(np.square(stds), axis=0))
    ratio = spread / predicted
    # 12 samples: a sample std is within a factor ~[0.6, 1.45] of the truth at 95 %
    assert np.all((ratio > 0.5) & (ratio < 1.7)), ratio


def test_given_pixel_noise_scales_the_covariance():
    board = BOARDS["chessboard"]
    found = detect(realistic(board, view(board, 15)), board)
    a = estimate_pose(found, CAMERA, pixel_sigma=0.1)
    b = estimate_pose(found, CAMERA, pixel_sigma=0.2)
    assert a.pixel_sigma == 0.1 and np.allclose(b.covariance, 4 * a.covariance)


def test_image_without_board_is_rejected_with_reason():
    rng = np.random.default_rng(0)
    clutter = cv2.GaussianBlur(rng.uniform(0, 255, (1024, 1280)).astype(np.uint8), (0, 0), 3)
    for name in ("chessboard", "charuco", "circles", "acircles"):
        result = detect(clutter, BOARDS[name])
        assert isinstance(result, Rejected)
    assert "no 7 x 10 inner-corner chessboard found" in detect(clutter, BOARDS["chessboard"]).reason
    assert "DICT_5X5_100" in detect(clutter, BOARDS["charuco"]).reason
    assert "circle grid" in detect(clutter, BOARDS["circles"]).reason


def test_partial_board_is_rejected_when_it_must_be_whole():
    for name in ("chessboard", "circles"):
        board = BOARDS[name]
        T = view(board, 5, aim=(0.11, 0.0))  # the board's left part leaves the image
        result = detect(realistic(board, T), board)
        assert isinstance(result, Rejected), name
        assert "board" in result.reason


def test_partial_charuco_board_is_used_with_the_corners_seen():
    board = BOARDS["charuco"]
    T = view(board, 0, aim=(0.11, 0.0))
    found = detect(realistic(board, T), board)
    assert isinstance(found, Detection)
    assert 10 <= len(found.ids) < board.n_points
    pose = estimate_pose(found, CAMERA)
    dp, dr = pose_error(T, pose.T_board_camera)
    assert dp < 2 * MAX_POSITION_ERROR and dr < 2 * MAX_ROTATION_ERROR


def test_bad_fit_and_too_few_points_are_rejected():
    board = BOARDS["chessboard"]
    found = detect(realistic(board, view(board, 15)), board)
    points = found.image_points.copy()
    points[::7] += 3.0  # ten corners off by 4 px: a mismatched detection
    bad = Detection(board, found.ids, points, found.image_size)
    result = estimate_pose(bad, CAMERA)
    assert isinstance(result, Rejected) and "reprojection RMS" in result.reason
    assert isinstance(estimate_pose(bad, CAMERA, max_rms=5.0), PoseResult)
    few = Detection(board, found.ids[:4], found.image_points[:4], found.image_size)
    assert "only 4 points" in estimate_pose(few, CAMERA).reason


def test_measure_images_in_parallel_keeps_order_and_reasons(tmp_path):
    board = BOARDS["chessboard"]
    truths, paths = [], []
    for k, roll in enumerate((0, 40, 190)):
        T = view(board, roll, distance=0.6)
        path = tmp_path / f"{k}.png"
        cv2.imwrite(str(path), realistic(board, T, camera=SMALL, seed=k))
        truths.append(T)
        paths.append(path)
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((512, 640), 128, np.uint8))
    garbage = tmp_path / "garbage.png"
    garbage.write_text("not an image")
    all_paths = [paths[0], blank, paths[1], tmp_path / "missing.png", garbage, paths[2]]

    results = measure_images(all_paths, board, SMALL, workers=2, progress=False)
    assert [r.path for r in results] == [str(p) for p in all_paths]
    assert [r.ok for r in results] == [True, False, True, False, False, True]
    assert "chessboard" in results[1].reason and str(blank) in results[1].reason
    assert "file not found" in results[3].reason
    assert "not a readable image" in results[4].reason
    for result, T in zip([results[0], results[2], results[5]], truths, strict=True):
        dp, dr = pose_error(T, result.pose.T_board_camera)
        assert dp < 3 * MAX_POSITION_ERROR and dr < 3 * MAX_ROTATION_ERROR

    inline = measure_images(all_paths, board, SMALL, workers=1, progress=False)
    assert np.allclose(inline[2].pose.T_board_camera, results[2].pose.T_board_camera)
    detections_only = measure_images(paths[:1], board, workers=1, progress=False)
    assert detections_only[0].ok and detections_only[0].pose is None


def test_intrinsics_from_fifteen_rendered_views():
    """15 views of a chessboard (640 x 512, f = 1200 px) 1.0 - 1.4 m away: measured errors fx
    0.11 px, fy 0.02 px, cx 0.53 px, cy 0.11 px (OpenCV's standard deviations 0.48, 0.45, 0.74,
    0.53 px), k1 1e-4, RMS 0.04 px. A mismatched frame is dropped with its reason."""
    board = Board("chessboard", 8, 11, 0.03)
    rng = np.random.default_rng(7)
    detections, truth_poses = [], []
    for k in range(15):
        centre = board_points(board).mean(axis=0)
        tilt = rng.uniform(-35, 35, 2)
        direction = Rotation.from_euler("xy", tilt, degrees=True).apply([0, 0, -1.0])
        T = look_at(
            centre + direction * rng.uniform(1.0, 1.4), centre + [*rng.normal(0, 0.03, 2), 0]
        )
        T[:3, :3] = (
            T[:3, :3] @ Rotation.from_euler("z", rng.uniform(-20, 20), degrees=True).as_matrix()
        )
        found = detect(realistic(board, T, camera=SMALL, seed=k), board)
        assert isinstance(found, Detection), (k, found)
        detections.append(found)
        truth_poses.append(T)
    bad = detections[3]
    shuffled = bad.image_points.copy()
    shuffled[:10] = shuffled[:10][::-1]  # ten corners matched to the wrong ids
    detections.append(Detection(board, bad.ids, shuffled, bad.image_size))

    result = calibrate_intrinsics(detections)
    cam = result.camera
    assert list(result.rejected) == [15] and "median" in result.rejected[15]
    assert len(result.used) == 15 and result.rms < 0.1
    for name in ("fx", "fy", "cx", "cy"):
        error = abs(getattr(cam, name) - getattr(SMALL, name))
        assert error < 1.5 and error < 3 * result.std[name], (name, error, result.std[name])
    assert cam.distortion[0] == pytest.approx(SMALL.distortion[0], abs=0.005)
    assert np.all(np.isfinite(result.per_image_rms))
    assert set(result.std) == {"fx", "fy", "cx", "cy"}


def test_intrinsics_needs_enough_views():
    board = Board("chessboard", 8, 11, 0.03)
    found = detect(realistic(board, view(board, 0, distance=1.2), camera=SMALL), board)
    with pytest.raises(RelcalError, match="at least 4 usable views"):
        calibrate_intrinsics([found, found])


# ----------------------------------------------------------------------------- camera files


def test_camera_yaml_round_trip(tmp_path):
    path = tmp_path / "camera.yaml"
    save_camera(CAMERA, path)
    assert load_camera(path) == CAMERA


def test_camera_from_robot_cal_tools_and_ros_files(tmp_path):
    rct = load_camera(DATA / "rct_circle_grid_eye_in_hand" / "camera_intr_calibrated.yaml")
    assert (rct.fx, rct.fy, rct.cx, rct.cy) == (542.324, 543.515, 320.474, 226.039)
    assert rct.distortion == () and rct.width is None
    sized = load_camera(DATA / "rct_charuco_eye_to_hand" / "camera_intr.yaml", 1600, 1200)
    assert sized.size == (1600, 1200) and sized.fx == 1400.0

    ros = tmp_path / "ost.yaml"
    ros.write_text(
        "image_width: 640\nimage_height: 480\ncamera_name: cam\n"
        "camera_matrix:\n  rows: 3\n  cols: 3\n"
        "  data: [500.0, 0.0, 320.5, 0.0, 501.0, 240.5, 0, 0, 1]\n"
        "distortion_model: plumb_bob\n"
        "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [-0.1, 0.01, 0.0, 0.0, 0.0]\n"
    )
    cam = load_camera(ros)
    assert cam == Camera(500.0, 501.0, 320.5, 240.5, (-0.1, 0.01, 0.0, 0.0, 0.0), 640, 480)


@pytest.mark.parametrize(
    "text, where",
    [
        ("fx: -5.0\nfy: 500.0\ncx: 320.0\ncy: 240.0\n", "line 1: fx"),
        (
            "fx: 500.0\nfy: 500.0\ncx: 320.0\ncy: 240.0\ndistortion: [0.1, 0.2, 0.3]\n",
            "line 5: distortion",
        ),
        ("fx: 500.0\nfy: 500.0\ncx: 320.0\ncy: 240.0\nwidth: 640\n", "width and height"),
        ("intrinsics:\n  fx: 500.0\n  fy: 500.0\n  cx: 320.0\n", "line 2: intrinsics.cy"),
    ],
)
def test_camera_yaml_errors_name_the_file_and_field(tmp_path, text, where):
    path = tmp_path / "camera.yaml"
    path.write_text(text)
    with pytest.raises(RelcalError) as err:
        load_camera(path)
    assert str(err.value).startswith(str(path)) and where in str(err.value), str(err.value)
