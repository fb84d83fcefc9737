"""Calibration boards: geometry, YAML description, drawing and printable sheets.

Four kinds of board are supported, all flat and printed dark on white:

- ``chessboard``: ``rows x columns`` squares; the points are the ``(rows-1) x (columns-1)`` inner
  corners. The top-left square is black.
- ``charuco``: a chessboard whose white squares carry ArUco markers (OpenCV layout, OpenCV >= 4.6
  unless ``legacy_pattern``); points are the inner corners, identified even when partly hidden.
- ``circles``: a symmetric ``rows x columns`` grid of dots ``spacing`` apart. With
  ``origin_marker`` the dot at point 0 is twice as large (as on ROS-Industrial "modified circle
  grid" targets) and fixes the board's orientation.
- ``acircles``: OpenCV's asymmetric grid, ``rows`` rows of ``columns`` dots. Dots in a row are
  ``2 * spacing`` apart; consecutive rows are ``spacing`` apart and shifted by ``spacing``.

Board frame: origin at point 0, x along a row (towards point 1), y down the columns, z = x cross y
into the board (away from a camera that sees its printed face), as in OpenCV. Points have
ids ``0..M-1`` in row-major order; a detection reports which ids it saw.
"""

from __future__ import annotations

import functools
import io
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
import pydantic

from relcal.errors import RelcalError
from relcal.io import load_yaml, validate

BoardType = Literal["chessboard", "charuco", "circles", "acircles"]
BOARD_TYPES: tuple[str, ...] = ("chessboard", "charuco", "circles", "acircles")

#: Reflectance of the ink and the paper used when drawing a board (0 black .. 1 white).
INK = 0.0
PAPER = 1.0


@dataclass(frozen=True)
class Board:
    """A flat calibration board.

    Parameters
    ----------
    type : {"chessboard", "charuco", "circles", "acircles"}
    rows, columns : int
        Squares (chessboard, ChArUco) or dots (circle grids) along y and x.
    spacing : float
        Square side (chessboard, ChArUco) or dot pitch (circle grids), m.
    marker_size : float or None
        ChArUco marker side, m.
    dictionary : str or None
        ChArUco dictionary name, e.g. ``"DICT_6X6_250"``.
    diameter : float or None
        Dot diameter of circle grids, m (default ``spacing / 2``).
    origin_marker : bool
        Symmetric circle grid whose dot 0 is twice the diameter of the others.
    legacy_pattern : bool
        ChArUco boards with an even number of rows printed by OpenCV < 4.6.
    margin : float or None
        White border around the pattern, m (default one ``spacing``).
    """

    type: BoardType
    rows: int
    columns: int
    spacing: float
    marker_size: float | None = None
    dictionary: str | None = None
    diameter: float | None = None
    origin_marker: bool = False
    legacy_pattern: bool = False
    margin: float | None = None

    def __post_init__(self) -> None:
        problems = board_problems(self)
        if problems:
            raise ValueError("; ".join(problems))

    @property
    def grid_shape(self) -> tuple[int, int]:
        """Points per column and per row ``(rows, columns)`` of the point grid."""
        if self.type in ("chessboard", "charuco"):
            return self.rows - 1, self.columns - 1
        return self.rows, self.columns

    @property
    def n_points(self) -> int:
        """Number of points ``M`` (inner corners or dots)."""
        r, c = self.grid_shape
        return r * c

    @property
    def needs_whole_view(self) -> bool:
        """True when the detector needs every point visible (all but ChArUco)."""
        return self.type != "charuco"

    @property
    def dot_diameter(self) -> float:
        """Diameter of the ordinary dots of a circle grid, m."""
        return self.diameter if self.diameter is not None else 0.5 * self.spacing

    @property
    def border(self) -> float:
        """White margin around the pattern, m."""
        return self.margin if self.margin is not None else self.spacing

    def describe(self) -> str:
        """One line with the board's geometry, for people (mm)."""
        mm = 1000.0
        if self.type == "chessboard":
            r, c = self.grid_shape
            return (
                f"chessboard {self.rows} x {self.columns} squares ({r} x {c} inner corners), "
                f"square {self.spacing * mm:.3f} mm"
            )
        if self.type == "charuco":
            legacy = ", legacy (pre-4.6) layout" if self.legacy_pattern else ""
            return (
                f"ChArUco {self.rows} x {self.columns} squares, square {self.spacing * mm:.3f} mm, "
                f"marker {self.marker_size * mm:.3f} mm, {self.dictionary}{legacy}"
            )
        kind = "symmetric" if self.type == "circles" else "asymmetric"
        origin = ", big dot at the origin" if self.origin_marker else ""
        return (
            f"{kind} circle grid {self.rows} x {self.columns} dots, spacing "
            f"{self.spacing * mm:.3f} mm, dot diameter {self.dot_diameter * mm:.3f} mm{origin}"
        )


def board_problems(board: Board) -> list[str]:
    """What is wrong with a board description (empty when it is usable)."""
    out: list[str] = []
    if board.type not in BOARD_TYPES:
        return [f"type '{board.type}' is not one of {', '.join(BOARD_TYPES)}"]
    minimum = 3
    if board.rows < minimum or board.columns < minimum:
        out.append(
            f"rows and columns must be at least {minimum}, got {board.rows} x {board.columns}"
        )
    if not np.isfinite(board.spacing) or board.spacing <= 0:
        what = "square" if board.type in ("chessboard", "charuco") else "spacing"
        out.append(f"{what} must be a positive length in metres, got {board.spacing}")
        return out
    if board.margin is not None and (not np.isfinite(board.margin) or board.margin < 0):
        out.append(f"margin must be >= 0 m, got {board.margin}")
    if board.type == "charuco":
        if board.marker_size is None or not board.marker_size > 0:
            out.append(f"marker must be a positive length in metres, got {board.marker_size}")
        elif board.marker_size >= board.spacing:
            out.append(
                f"marker ({board.marker_size} m) must be smaller than the square "
                f"({board.spacing} m)"
            )
        if board.dictionary is None:
            out.append("dictionary is required for a ChArUco board, e.g. DICT_6X6_250")
        else:
            try:
                size = _dictionary_size(board.dictionary)
            except KeyError:
                out.append(f"dictionary '{board.dictionary}' is not an OpenCV ArUco dictionary")
            else:
                needed = board.rows * board.columns // 2
                if needed > size:
                    out.append(
                        f"a {board.rows} x {board.columns} ChArUco board needs {needed} markers "
                        f"but {board.dictionary} has only {size}"
                    )
    elif board.marker_size is not None or board.dictionary is not None:
        out.append(f"marker and dictionary apply to ChArUco boards only, not {board.type}")
    if board.type in ("circles", "acircles"):
        d = board.dot_diameter
        gap = board.spacing if board.type == "circles" else board.spacing * np.sqrt(2.0)
        if not np.isfinite(d) or d <= 0:
            out.append(f"diameter must be a positive length in metres, got {d}")
        elif d >= gap:
            out.append(
                f"dot diameter {d} m must be smaller than the {gap:.6g} m between dot centres"
            )
        elif board.origin_marker and 1.5 * d >= board.spacing:
            out.append(
                f"with origin_marker the big dot ({2 * d} m) needs dot diameter < spacing / 1.5"
            )
    elif board.diameter is not None:
        out.append(f"diameter applies to circle grids only, not {board.type}")
    if board.origin_marker and board.type != "circles":
        out.append("origin_marker applies to symmetric circle grids (type circles) only")
    if board.legacy_pattern and board.type != "charuco":
        out.append("legacy_pattern applies to ChArUco boards only")
    return out


# ----------------------------------------------------------------------------- YAML


class BoardSpec(pydantic.BaseModel):
    """A board as written in YAML (lengths in metres)::

    type: charuco          # chessboard | charuco | circles | acircles
    rows: 7                # squares (chessboard, charuco) or dots (circle grids)
    columns: 5
    square: 0.036195       # chessboard, charuco ("spacing" for circle grids)
    marker: 0.018256       # charuco
    dictionary: DICT_6X6_250
    """

    model_config = pydantic.ConfigDict(extra="forbid")

    type: BoardType
    rows: int = pydantic.Field(ge=3)
    columns: int = pydantic.Field(ge=3)
    square: pydantic.PositiveFloat | None = None
    spacing: pydantic.PositiveFloat | None = None
    marker: pydantic.PositiveFloat | None = None
    dictionary: str | None = None
    diameter: pydantic.PositiveFloat | None = None
    origin_marker: bool = False
    legacy_pattern: bool = False
    margin: pydantic.NonNegativeFloat | None = None

    @pydantic.model_validator(mode="after")
    def _check(self) -> BoardSpec:
        squares = self.type in ("chessboard", "charuco")
        name, other = ("square", "spacing") if squares else ("spacing", "square")
        if getattr(self, other) is not None:
            raise ValueError(f"a {self.type} board gives its pitch as '{name}', not '{other}'")
        if getattr(self, name) is None:
            raise ValueError(f"'{name}' (m) is required for a {self.type} board")
        problems = board_problems(self._raw())
        if problems:
            raise ValueError("; ".join(problems))
        return self

    def _raw(self) -> Board:
        board = object.__new__(Board)
        values = {
            "type": self.type,
            "rows": self.rows,
            "columns": self.columns,
            "spacing": float(self.square if self.square is not None else self.spacing),
            "marker_size": self.marker,
            "dictionary": _canonical_dictionary(self.dictionary),
            "diameter": self.diameter,
            "origin_marker": self.origin_marker,
            "legacy_pattern": self.legacy_pattern,
            "margin": self.margin,
        }
        for key, value in values.items():
            object.__setattr__(board, key, value)
        return board

    def to_board(self) -> Board:
        """The validated :class:`Board`."""
        raw = self._raw()
        return Board(**{k: getattr(raw, k) for k in raw.__dataclass_fields__})


class _RctTarget(pydantic.BaseModel):
    """ROS-Industrial robot_cal_tools ``target_finder`` block."""

    type: str
    rows: int = pydantic.Field(ge=3)
    cols: int = pydantic.Field(ge=3)
    spacing: pydantic.PositiveFloat | None = None
    chessboard_dim: pydantic.PositiveFloat | None = None
    aruco_marker_dim: pydantic.PositiveFloat | None = None
    dictionary: int | str | None = None


class _RctTargetFile(pydantic.BaseModel):
    target_finder: _RctTarget


def board_to_spec(board: Board) -> dict[str, Any]:
    """The YAML mapping of a board (inverse of :func:`load_board`)."""
    squares = board.type in ("chessboard", "charuco")
    out: dict[str, Any] = {"type": board.type, "rows": board.rows, "columns": board.columns}
    out["square" if squares else "spacing"] = board.spacing
    if board.type == "charuco":
        out["marker"] = board.marker_size
        out["dictionary"] = board.dictionary
        if board.legacy_pattern:
            out["legacy_pattern"] = True
    if board.diameter is not None:
        out["diameter"] = board.diameter
    if board.origin_marker:
        out["origin_marker"] = True
    if board.margin is not None:
        out["margin"] = board.margin
    return out


def load_board(path: str | Path) -> Board:
    """Read a board from YAML: relcal's :class:`BoardSpec` or a robot_cal_tools ``target.yaml``.

    Raises
    ------
    RelcalError
        Naming the file, line and field when the description is incomplete or inconsistent.
    """
    data, node = load_yaml(path)
    if not isinstance(data, dict) or not ({"type", "target_finder"} & set(data)):
        raise RelcalError(
            f"{path}: not a board file (a board YAML is a mapping with type, rows, columns and "
            "square or spacing, or robot_cal_tools' target_finder)"
        )
    if isinstance(data, dict) and "target_finder" in data:
        return _board_from_rct(validate(_RctTargetFile, data, path, node).target_finder, path)
    return validate(BoardSpec, data, path, node).to_board()


def _board_from_rct(target: _RctTarget, path: str | Path) -> Board:
    kind = target.type.split("::")[-1]
    if "Charuco" in kind:
        if target.chessboard_dim is None or target.aruco_marker_dim is None:
            raise RelcalError(
                f"{path}: target_finder: a ChArUco target needs chessboard_dim and aruco_marker_dim"
            )
        dictionary = target.dictionary if target.dictionary is not None else "DICT_6X6_250"
        if isinstance(dictionary, int):
            dictionary = _dictionary_name_from_id(dictionary, path)
        spec = {
            "type": "charuco",
            "rows": target.rows,
            "columns": target.cols,
            "square": target.chessboard_dim,
            "marker": target.aruco_marker_dim,
            "dictionary": dictionary,
        }
    elif "CircleGrid" in kind:
        if target.spacing is None:
            raise RelcalError(f"{path}: target_finder.spacing: required for a circle grid (m)")
        spec = {
            "type": "circles",
            "rows": target.rows,
            "columns": target.cols,
            "spacing": target.spacing,
            "origin_marker": "Modified" in kind,
        }
    else:
        raise RelcalError(
            f"{path}: target_finder.type: '{target.type}' is not a circle grid or ChArUco target"
        )
    return validate(BoardSpec, spec, path).to_board()


def _dictionary_names() -> dict[str, int]:
    return {n: getattr(cv2.aruco, n) for n in dir(cv2.aruco) if n.startswith("DICT_")}


def _canonical_dictionary(name: str | None) -> str | None:
    if name is None:
        return None
    key = name.strip().upper()
    if not key.startswith("DICT_"):
        key = "DICT_" + key
    return key if key in _dictionary_names() else name


def _dictionary_name_from_id(value: int, path: str | Path) -> str:
    names = sorted((v, n) for n, v in _dictionary_names().items())
    for v, n in names:
        if v == value:
            return n
    raise RelcalError(f"{path}: target_finder.dictionary: {value} is not an OpenCV dictionary id")


def _dictionary_size(name: str) -> int:
    key = _canonical_dictionary(name)
    if key is None or key not in _dictionary_names():
        raise KeyError(name)
    return int(cv2.aruco.getPredefinedDictionary(_dictionary_names()[key]).bytesList.shape[0])


@functools.lru_cache(maxsize=16)
def aruco_dictionary(name: str) -> cv2.aruco.Dictionary:
    """The OpenCV ArUco dictionary called ``name`` (e.g. ``"DICT_6X6_250"``)."""
    key = _canonical_dictionary(name)
    if key is None or key not in _dictionary_names():
        raise RelcalError(f"dictionary '{name}' is not an OpenCV ArUco dictionary")
    return cv2.aruco.getPredefinedDictionary(_dictionary_names()[key])


@functools.lru_cache(maxsize=16)
def charuco_board(board: Board) -> cv2.aruco.CharucoBoard:
    """The OpenCV ``CharucoBoard`` of a ChArUco :class:`Board` (OpenCV frame: origin at the
    board's outer corner, i.e. ours shifted by one square)."""
    if board.type != "charuco":
        raise ValueError(f"not a ChArUco board: {board.type}")
    assert board.marker_size is not None and board.dictionary is not None
    cv_board = cv2.aruco.CharucoBoard(
        (board.columns, board.rows),
        board.spacing,
        board.marker_size,
        aruco_dictionary(board.dictionary),
    )
    cv_board.setLegacyPattern(board.legacy_pattern)
    return cv_board


# ----------------------------------------------------------------------------- geometry


def board_points(board: Board) -> np.ndarray:
    """Object points ``(M, 3)`` in the board frame (m, z = 0); row ``i`` is point id ``i``."""
    r, c = board.grid_shape
    rows, cols = np.meshgrid(np.arange(r), np.arange(c), indexing="ij")
    s = board.spacing
    if board.type == "acircles":
        x = (2 * cols + rows % 2) * s
    else:
        x = cols * s
    y = rows * s
    return np.stack([x.ravel(), y.ravel(), np.zeros(r * c)], axis=1).astype(float)


def pattern_extent(board: Board) -> tuple[float, float, float, float]:
    """Printed pattern ``(xmin, ymin, xmax, ymax)`` in the board frame, m, without the margin."""
    pts = board_points(board)
    if board.type in ("chessboard", "charuco"):
        s = board.spacing
        return -s, -s, (board.columns - 1) * s, (board.rows - 1) * s
    radius = board.dot_diameter * (1.0 if board.origin_marker else 0.5)
    return (
        pts[:, 0].min() - radius,
        pts[:, 1].min() - radius,
        pts[:, 0].max() + radius,
        pts[:, 1].max() + radius,
    )


def board_extent(board: Board) -> tuple[float, float, float, float]:
    """The whole sheet ``(xmin, ymin, xmax, ymax)`` (pattern plus margin), m."""
    x0, y0, x1, y1 = pattern_extent(board)
    m = board.border
    return x0 - m, y0 - m, x1 + m, y1 + m


def dark_rectangles(board: Board) -> np.ndarray:
    """Disjoint axis-aligned dark rectangles ``(K, 4)`` ``(x0, y0, x1, y1)`` in m, for
    chessboards and ChArUco boards (black squares and the black cells of every marker)."""
    if board.type not in ("chessboard", "charuco"):
        return np.zeros((0, 4))
    s = board.spacing
    white = np.zeros((board.rows, board.columns), bool)
    rects: list[tuple[float, float, float, float]] = []
    if board.type == "chessboard":
        i, j = np.indices(white.shape)
        white = (i + j) % 2 == 1
    else:
        cv_board = charuco_board(board)
        dictionary = aruco_dictionary(board.dictionary or "")
        bits = dictionary.markerSize + 2
        for corners, marker_id in zip(
            cv_board.getObjPoints(), np.ravel(cv_board.getIds()), strict=True
        ):
            corners = np.asarray(corners, float).reshape(4, 3)[:, :2] - s  # OpenCV frame -> ours
            x0, y0 = corners[0]
            size = corners[1, 0] - corners[0, 0]
            col, row = int(np.floor((x0 + s) / s)), int(np.floor((y0 + s) / s))
            white[row, col] = True
            cells = dictionary.generateImageMarker(int(marker_id), bits) < 128
            rects.extend(_cell_runs(cells, x0, y0, size / bits))
    for row, col in zip(*np.nonzero(~white), strict=True):
        rects.append(((col - 1) * s, (row - 1) * s, col * s, row * s))
    return np.asarray(rects, float).reshape(-1, 4)


def _cell_runs(cells: np.ndarray, x0: float, y0: float, cell: float):
    """Horizontal runs of dark cells as rectangles (fewer, seam-free shapes for printing)."""
    for r, row in enumerate(cells):
        c = 0
        while c < len(row):
            if row[c]:
                start = c
                while c < len(row) and row[c]:
                    c += 1
                yield (x0 + start * cell, y0 + r * cell, x0 + c * cell, y0 + (r + 1) * cell)
            else:
                c += 1


def dots(board: Board) -> tuple[np.ndarray, np.ndarray]:
    """Dot centres ``(M, 2)`` (m) and diameters ``(M,)`` (m) of a circle grid."""
    if board.type not in ("circles", "acircles"):
        return np.zeros((0, 2)), np.zeros(0)
    centres = board_points(board)[:, :2]
    diameters = np.full(len(centres), board.dot_diameter)
    if board.origin_marker:
        diameters[0] *= 2.0
    return centres, diameters


# ----------------------------------------------------------------------------- drawing


def _coverage_1d(edges: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Fraction of each pixel ``[edges[i], edges[i+1]]`` inside ``[lo, hi]``."""
    inside = np.minimum(edges[1:], hi) - np.maximum(edges[:-1], lo)
    return np.clip(inside / (edges[1] - edges[0]), 0.0, 1.0)


def reflectance(board: Board, px_per_m: float) -> tuple[np.ndarray, tuple[float, float]]:
    """The board sheet as an anti-aliased reflectance image (area coverage of the ink).

    Parameters
    ----------
    board : Board
    px_per_m : float
        Pixel density, pixels per metre.

    Returns
    -------
    image : ndarray, float32, shape (H, W)
        ``PAPER`` (1) on white, ``INK`` (0) on black, fractions on edges.
    origin : (float, float)
        Board coordinates (m) of the outer corner of pixel (0, 0): pixel ``(v, u)`` covers
        ``x in origin[0] + [u, u+1] / px_per_m``, ``y in origin[1] + [v, v+1] / px_per_m``.
    """
    if not px_per_m > 0:
        raise ValueError(f"px_per_m must be positive, got {px_per_m}")
    x0, y0, x1, y1 = board_extent(board)
    width = int(np.ceil((x1 - x0) * px_per_m))
    height = int(np.ceil((y1 - y0) * px_per_m))
    ink = np.zeros((height, width), np.float32)
    xe = x0 + np.arange(width + 1) / px_per_m
    ye = y0 + np.arange(height + 1) / px_per_m
    for rx0, ry0, rx1, ry1 in dark_rectangles(board):
        u0, u1 = _index_range(rx0, rx1, x0, px_per_m, width)
        v0, v1 = _index_range(ry0, ry1, y0, px_per_m, height)
        cx = _coverage_1d(xe[u0 : u1 + 1], rx0, rx1)
        cy = _coverage_1d(ye[v0 : v1 + 1], ry0, ry1)
        ink[v0:v1, u0:u1] += np.outer(cy, cx).astype(np.float32)
    centres, diameters = dots(board)
    for (cx_m, cy_m), diam in zip(centres, diameters, strict=True):
        r = 0.5 * diam
        u0, u1 = _index_range(cx_m - r, cx_m + r, x0, px_per_m, width)
        v0, v1 = _index_range(cy_m - r, cy_m + r, y0, px_per_m, height)
        uc = x0 + (np.arange(u0, u1) + 0.5) / px_per_m - cx_m
        vc = y0 + (np.arange(v0, v1) + 0.5) / px_per_m - cy_m
        dist = np.hypot(vc[:, None], uc[None, :])
        ink[v0:v1, u0:u1] += np.clip(0.5 + (r - dist) * px_per_m, 0.0, 1.0).astype(np.float32)
    image = PAPER + (INK - PAPER) * np.clip(ink, 0.0, 1.0)
    return image.astype(np.float32), (x0, y0)


def _index_range(lo: float, hi: float, origin: float, ppm: float, n: int) -> tuple[int, int]:
    a = int(np.floor((lo - origin) * ppm)) - 1
    b = int(np.ceil((hi - origin) * ppm)) + 1
    return max(a, 0), min(b, n)


def board_image(board: Board, px_per_m: float) -> np.ndarray:
    """The board sheet as a uint8 grayscale image ``(H, W)`` at ``px_per_m`` pixels per metre."""
    image, _ = reflectance(board, px_per_m)
    return np.round(image * 255.0).astype(np.uint8)


_CAPTION_HEIGHT = 0.022  # m below the board for the caption and the scale bar


def sheet_size(board: Board) -> tuple[float, float]:
    """Width and height (m) of the printable sheet: the board with its margin and the caption."""
    x0, y0, x1, y1 = board_extent(board)
    return x1 - x0, y1 - y0 + _CAPTION_HEIGHT


def write_printable(board: Board, path: str | Path, dpi: float = 300.0) -> Path:
    """Write :func:`printable` to ``path`` (as one unit) and return the path."""
    from relcal.io import write_bytes

    write_bytes(path, printable(board, path, dpi), "--out")
    return Path(path)


def printable(board: Board, path: str | Path, dpi: float = 300.0) -> bytes:
    """Write the board at true scale as PDF (vector) or PNG (``dpi`` pixels per inch).

    The sheet shows the pattern with its margin and, below it, the geometry (type, size,
    spacing, dictionary) and a 50 mm bar to check the print scale.

    Returns
    -------
    bytes
        The file's content, in the format of ``path``'s suffix (``.pdf`` or ``.png``).
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle, Rectangle

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".pdf", ".png"):
        raise RelcalError(f"{path}: printable boards are written as .pdf or .png, not '{suffix}'")
    if not dpi > 0:
        raise RelcalError(f"{path}: dpi must be positive, got {dpi}")
    check_sheet(board, path, dpi if suffix == ".png" else None)
    x0, y0, x1, y1 = board_extent(board)
    width, height = sheet_size(board)
    text_h = _CAPTION_HEIGHT
    inch = 0.0254
    fig = Figure(figsize=(width / inch, height / inch), dpi=dpi)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_xlim(x0, x1)
    ax.set_ylim(y1 + text_h, y0)  # y down, as in the board frame
    ax.set_aspect("equal")
    ax.axis("off")
    for rx0, ry0, rx1, ry1 in dark_rectangles(board):
        ax.add_patch(Rectangle((rx0, ry0), rx1 - rx0, ry1 - ry0, color="black", lw=0))
    for (cx, cy), diam in zip(*dots(board), strict=True):
        ax.add_patch(Circle((cx, cy), 0.5 * diam, color="black", lw=0))
    ax.plot([x0 + 0.005, x0 + 0.055], [y1 + 0.016] * 2, color="black", lw=1.0)
    fontsize = max(4.0, min(8.0, width / inch * 72 / 110))
    ax.text(x0 + 0.005, y1 + 0.004, "relcal: " + board.describe(), fontsize=fontsize, va="top")
    ax.text(x0 + 0.058, y1 + 0.016, "<- this bar must measure 50.0 mm", fontsize=fontsize)
    buffer = io.BytesIO()
    fig.savefig(buffer, format=suffix[1:], dpi=dpi)
    return buffer.getvalue()


MAX_SHEET = 2.0  # m, longest printable side (an A0 sheet is 1.19 m)
MAX_PIXELS = 1.0e8  # of a PNG sheet (about 400 MB while drawn)


def check_sheet(board: Board, path: str | Path, dpi: float | None = None) -> None:
    """Refuse a sheet no printer takes (longer than ``MAX_SHEET``) or a PNG too large to draw
    in bounded memory (more than ``MAX_PIXELS`` at ``dpi``)."""
    width, height = sheet_size(board)
    if max(width, height) > MAX_SHEET:
        raise RelcalError(
            f"{path}: the sheet would be {width:.3g} x {height:.3g} m (more than {MAX_SHEET} m); "
            "is the square or spacing in metres (0.02 for 20 mm)?"
        )
    if dpi is not None:
        px = (width / 0.0254 * dpi) * (height / 0.0254 * dpi)
        if px > MAX_PIXELS:
            raise RelcalError(
                f"{path}: {px:.3g} pixels at {dpi:g} dpi (limit {MAX_PIXELS:.0e}); lower --dpi "
                "or write a .pdf"
            )
