"""Board geometry, YAML descriptions and their errors, drawing and printable sheets."""

import re

import cv2
import numpy as np
import pytest
from conftest import DATA

from relcal.errors import RelcalError
from relcal.vision.boards import (
    Board,
    board_extent,
    board_image,
    board_points,
    board_to_spec,
    charuco_board,
    load_board,
    reflectance,
    write_printable,
)

CHESS = Board("chessboard", 7, 10, 0.025)
CHARUCO = Board("charuco", 7, 5, 0.036195, 0.018256, "DICT_6X6_250")
CIRCLES = Board("circles", 4, 6, 0.02, diameter=0.01, origin_marker=True)
ACIRCLES = Board("acircles", 11, 4, 0.015)


def test_points_are_row_major_grids_with_the_origin_at_point_zero():
    pts = board_points(CHESS)
    assert pts.shape == (6 * 9, 3) and np.all(pts[:, 2] == 0)
    assert np.allclose(pts[0], 0) and np.allclose(pts[1], [0.025, 0, 0])
    assert np.allclose(pts[9], [0, 0.025, 0]) and np.allclose(pts[-1], [8 * 0.025, 5 * 0.025, 0])
    assert board_points(CIRCLES).shape == (24, 3)
    assert np.allclose(board_points(CIRCLES)[7], [0.02, 0.02, 0])


def test_asymmetric_grid_follows_opencv_layout():
    # OpenCV: point (row i, column j) at ((2 j + i % 2) s, i s)
    pts = board_points(ACIRCLES)
    assert pts.shape == (44, 3)
    i, j = np.divmod(np.arange(44), 4)
    assert np.allclose(pts[:, 0], (2 * j + i % 2) * 0.015)
    assert np.allclose(pts[:, 1], i * 0.015)


def test_charuco_points_are_opencv_corners_shifted_by_one_square():
    ours = board_points(CHARUCO)
    theirs = np.asarray(charuco_board(CHARUCO).getChessboardCorners(), float)
    assert ours.shape == theirs.shape == (24, 3)
    assert np.allclose(ours + [CHARUCO.spacing, CHARUCO.spacing, 0], theirs, atol=1e-7)


def test_charuco_drawing_matches_opencv():
    """Same layout, colours and marker bits as OpenCV's own generator (edges may differ by
    anti-aliasing only)."""
    ppm = 80 / CHARUCO.spacing  # 80 px per square
    flush = Board("charuco", 7, 5, CHARUCO.spacing, CHARUCO.marker_size, "DICT_6X6_250", margin=0)
    ours = board_image(flush, ppm)[:560, :400].astype(float)
    theirs = charuco_board(CHARUCO).generateImage((400, 560), marginSize=0).astype(float)
    assert np.mean(np.abs(ours - theirs)) < 2.0
    assert np.mean(np.abs(ours - theirs) > 128) < 0.002


@pytest.mark.parametrize("board", [CHESS, CHARUCO, CIRCLES, ACIRCLES])
def test_drawing_conserves_ink_area(board):
    """Anti-aliasing by exact area coverage: ink area in the image equals the printed area."""
    ppm = 3001.7  # deliberately not aligned with any edge
    image, _ = reflectance(board, ppm)
    ink = float(np.sum(1.0 - image)) / ppm**2
    if board.type == "chessboard":
        expected = (board.rows * board.columns + 1) // 2 * board.spacing**2
    elif board.type in ("circles", "acircles"):
        d = np.full(board.n_points, board.dot_diameter)
        d[0] *= 2 if board.origin_marker else 1
        expected = float(np.sum(np.pi * d**2 / 4))
    else:
        squares = (board.rows * board.columns + 1) // 2 * board.spacing**2
        dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
        cell = board.marker_size / 8
        black_cells = sum(
            int(np.sum(dictionary.generateImageMarker(i, 8) < 128)) for i in range(17)
        )
        expected = squares + black_cells * cell**2
    assert ink == pytest.approx(expected, rel=2e-3)


def test_board_frame_convention_top_left_square_is_black():
    image = board_image(CHESS, 2000)
    x0, y0, _, _ = board_extent(CHESS)
    # centre of the square left of and above point 0, then its right neighbour
    u = int((-0.0125 - x0) * 2000)
    v = int((-0.0125 - y0) * 2000)
    assert image[v, u] == 0 and image[v, u + 50] == 255


def write(tmp_path, text):
    path = tmp_path / "board.yaml"
    path.write_text(text)
    return path


def test_yaml_round_trip(tmp_path):
    import yaml

    for board in (CHESS, CHARUCO, CIRCLES, ACIRCLES):
        path = write(tmp_path, yaml.safe_dump(board_to_spec(board)))
        assert load_board(path) == board


def test_yaml_accepts_short_dictionary_names(tmp_path):
    path = write(
        tmp_path,
        "type: charuco\nrows: 7\ncolumns: 5\nsquare: 0.04\nmarker: 0.03\ndictionary: 5x5_100\n",
    )
    assert load_board(path).dictionary == "DICT_5X5_100"


@pytest.mark.parametrize(
    "text, field, line, words",
    [
        ("type: chessboard\nrows: 7\ncolumns: 10\nsquare: -0.02\n", "square", 4, "greater than 0"),
        ("type: chessboard\nrows: 2\ncolumns: 10\nsquare: 0.02\n", "rows", 2, "3"),
        ("type: hexagons\nrows: 7\ncolumns: 10\nsquare: 0.02\n", "type", 1, "chessboard"),
        ("type: circles\nrows: 7\ncolumns: 10\nsquare: 0.02\n", "", 1, "'spacing'"),
        ("type: chessboard\nrows: 7\ncolumns: 10\n", "", 1, "'square' (m) is required"),
        (
            "type: charuco\nrows: 7\ncolumns: 5\nsquare: 0.02\nmarker: 0.03\n"
            "dictionary: DICT_4X4_50\n",
            "",
            1,
            "smaller than the square",
        ),
        (
            "type: charuco\nrows: 7\ncolumns: 5\nsquare: 0.04\nmarker: 0.03\n"
            "dictionary: DICT_9X9\n",
            "",
            1,
            "not an OpenCV ArUco dictionary",
        ),
        (
            "type: charuco\nrows: 20\ncolumns: 20\nsquare: 0.04\nmarker: 0.03\n"
            "dictionary: DICT_4X4_50\n",
            "",
            1,
            "needs 200 markers",
        ),
        ("type: circles\nrows: 5\ncolumns: 5\nspacing: 0.02\ndiameter: 0.03\n", "", 1, "smaller"),
        (
            "type: chessboard\nrows: 7\ncolumns: 10\nsquare: 0.02\nsquares: 3\n",
            "squares",
            5,
            "Extra",
        ),
    ],
)
def test_yaml_errors_name_file_line_and_field(tmp_path, text, field, line, words):
    path = write(tmp_path, text)
    with pytest.raises(RelcalError) as err:
        load_board(path)
    msg = str(err.value)
    assert msg.startswith(f"{path} line {line}: "), msg
    assert field in msg and words in msg, msg


def test_direct_construction_is_validated():
    with pytest.raises(ValueError, match="positive length"):
        Board("chessboard", 7, 10, 0.0)
    with pytest.raises(ValueError, match="ChArUco boards only"):
        Board("chessboard", 7, 10, 0.02, marker_size=0.01)
    with pytest.raises(ValueError, match="dictionary is required"):
        Board("charuco", 7, 10, 0.02, marker_size=0.01)


def test_robot_cal_tools_targets_load():
    circles = load_board(DATA / "rct_circle_grid_eye_in_hand" / "target.yaml")
    assert circles == Board("circles", 10, 10, 0.0254, origin_marker=True)
    charuco = load_board(DATA / "rct_charuco_eye_to_hand" / "target.yaml")
    assert charuco == Board("charuco", 7, 5, 0.036195, 0.018256, "DICT_6X6_250")


def test_printable_png_is_true_scale_with_its_geometry(tmp_path):
    from PIL import Image

    path = write_printable(CIRCLES, tmp_path / "circles.png", dpi=200)
    x0, y0, x1, y1 = board_extent(CIRCLES)
    with Image.open(path) as img:
        width, height = img.size
        dpi = img.info["dpi"]
        gray = np.asarray(img.convert("L"))
    assert dpi[0] == pytest.approx(200, abs=0.1)
    assert width == pytest.approx((x1 - x0) / 0.0254 * 200, abs=1)  # within 0.13 mm
    assert height == pytest.approx((y1 - y0 + 0.022) / 0.0254 * 200, abs=1)
    # dot 0 is the big one: measure its diameter on the image (dark run through its centre)
    ppm = 200 / 0.0254
    row = gray[int((0 - y0) * ppm)]
    u0 = int((0 - x0) * ppm)
    dark = row < 128
    assert dark[u0]
    left = u0 - np.argmin(dark[u0::-1])
    right = u0 + np.argmin(dark[u0:])
    assert (right - left) / ppm == pytest.approx(0.02, abs=2 / ppm)
    caption = gray[int((y1 - y0) * ppm) + 5 :]
    assert np.sum(caption < 128) > 500  # the geometry line and the 50 mm scale bar are printed


def test_printable_pdf_page_is_true_scale(tmp_path):
    path = write_printable(CHARUCO, tmp_path / "charuco.pdf")
    raw = path.read_bytes()
    assert raw.startswith(b"%PDF")
    box = re.search(rb"/MediaBox \[\s*0 0 ([\d.]+) ([\d.]+)\s*\]", raw)
    assert box is not None
    x0, y0, x1, y1 = board_extent(CHARUCO)
    assert float(box.group(1)) == pytest.approx((x1 - x0) / 0.0254 * 72, abs=0.5)
    assert float(box.group(2)) == pytest.approx((y1 - y0 + 0.022) / 0.0254 * 72, abs=0.5)
    assert CHARUCO.describe() == (
        "ChArUco 7 x 5 squares, square 36.195 mm, marker 18.256 mm, DICT_6X6_250"
    )


def test_printable_refuses_other_formats(tmp_path):
    with pytest.raises(RelcalError, match="pdf or .png"):
        write_printable(CHESS, tmp_path / "board.svg")
