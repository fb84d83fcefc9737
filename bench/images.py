"""Throughput of the image pipeline: relcal's ``measure_images`` (read, detect on a downscaled
copy, refine at full resolution, pose with covariance; 2 threads) against plain OpenCV detection
at full resolution (``findChessboardCorners`` on the whole image, then ``cornerSubPix`` as in
OpenCV's calibration tutorial) over 2 threads and over 2 processes, the faster counting, on
rendered chessboard images.

Decoding the PNG dominates on clean 5 MP images (~30 ms of ~40 ms each), so both run at about
the same rate there; the search on a downscaled copy pays off on hard frames: OpenCV's
full-resolution ``findChessboardCorners`` spends seconds on an image whose board is partly out of
view, where ``relcal.vision.detect.detect`` rejects it in a fraction of a second.

Run ``python bench/images.py`` for a table; ``run()`` returns the rows.
"""

from __future__ import annotations

import multiprocessing
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from relcal.vision.boards import Board, board_points
from relcal.vision.camera import Camera
from relcal.vision.detect import measure_images
from relcal.vision.render import look_at, render_board

WORKERS = 2

#: (label, camera, board, distance m, distinct images rendered, images measured, aim offset m)
SETUPS = (
    (
        "640x480",
        Camera(600.0, 600.0, 319.5, 239.5, (-0.1, 0.05, 0.0, 0.0, 0.0), 640, 480),
        Board("chessboard", 8, 11, 0.015),
        0.4,
        8,
        96,
        0.0,
    ),
    (
        "2448x2048 (5 MP)",
        Camera(2400.0, 2400.0, 1223.5, 1023.5, (-0.1, 0.05, 0.0, 0.0, 0.0), 2448, 2048),
        Board("chessboard", 8, 11, 0.025),
        0.55,
        4,
        24,
        0.0,
    ),
    (
        "1280x1024, board partly out of view (rejected)",
        Camera(2400.0, 2400.0, 639.5, 511.5, (-0.1, 0.05, 0.0, 0.0, 0.0), 1280, 1024),
        Board("chessboard", 8, 11, 0.015),
        0.5,
        2,
        4,
        0.11,
    ),
)


def _render_set(
    folder: Path, camera: Camera, board: Board, distance: float, n: int, aim: float = 0.0
) -> list[Path]:
    rng = np.random.default_rng(1)
    centre = board_points(board).mean(axis=0)
    paths = []
    for k in range(n):
        tilt = rng.uniform(-20, 20, 2)
        direction = Rotation.from_euler("xy", tilt, degrees=True).apply([0, 0, -1.0])
        T = look_at(centre + direction * distance, centre + [aim, 0.0, 0.0])
        T[:3, :3] = (
            T[:3, :3] @ Rotation.from_euler("z", rng.uniform(-30, 30), degrees=True).as_matrix()
        )
        image = render_board(board, camera, T, 0.8, 2.0, 0.3, seed=k, supersample=2)
        path = folder / f"{k}.png"
        cv2.imwrite(str(path), image)
        paths.append(path)
    return paths


def _init() -> None:
    cv2.setNumThreads(1)


def _opencv_full(job: tuple[str, tuple[int, int]]) -> bool:
    path, size = job
    gray = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
    ok, corners = cv2.findChessboardCorners(gray, size)
    if ok:
        criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 1e-3)
        cv2.cornerSubPix(gray, corners, (11, 11), (-1, -1), criteria)
    return bool(ok)


def _opencv_rate(paths: list[Path], board: Board, pool_kind: str) -> tuple[float, int]:
    rows, cols = board.grid_shape
    jobs = [(str(p), (cols, rows)) for p in paths]
    if pool_kind == "threads":
        pool = ThreadPoolExecutor(WORKERS)
    else:
        context = multiprocessing.get_context("spawn")
        pool = ProcessPoolExecutor(WORKERS, mp_context=context, initializer=_init)
    start = time.perf_counter()
    with pool:
        found = list(pool.map(_opencv_full, jobs))
    return len(paths) / (time.perf_counter() - start), sum(found)


def _relcal_rate(paths: list[Path], board: Board, camera: Camera) -> tuple[float, int]:
    start = time.perf_counter()
    results = measure_images(paths, board, camera, workers=WORKERS, progress=False)
    return len(paths) / (time.perf_counter() - start), sum(r.ok for r in results)


def run() -> list[dict]:
    """Images per second (2 workers, process start-up included) for each image size.

    Returns
    -------
    list of dict
        Rows ``{"task", "value", "unit", "peer", "ratio"}``: ``value`` is relcal, ``peer`` plain
        OpenCV full-resolution detection, ``ratio = value / peer`` (above 1: relcal is faster).
    """
    rows = []
    for label, camera, board, distance, distinct, total, aim in SETUPS:
        with tempfile.TemporaryDirectory() as tmp:
            rendered = _render_set(Path(tmp), camera, board, distance, distinct, aim)
            paths = [rendered[k % distinct] for k in range(total)]
            ours, ours_ok = _relcal_rate(paths, board, camera)
            # The peer at its best: OpenCV's calls release the GIL, so threads avoid the
            # start-up of processes; both are measured and the faster one counts.
            peers = [_opencv_rate(paths, board, kind) for kind in ("threads", "processes")]
            peer, peer_ok = max(peers)
        rows.append(
            {
                "task": f"chessboard detect+pose, {label}, {WORKERS} workers "
                f"({ours_ok}/{total} posed; OpenCV found {peer_ok}/{total})",
                "value": round(ours, 2),
                "unit": "images/s",
                "peer": round(peer, 2),
                "ratio": round(ours / peer, 3),
            }
        )
    return rows


if __name__ == "__main__":
    for row in run():
        print(
            f"{row['task']}: {row['value']} {row['unit']} vs OpenCV {row['peer']} "
            f"(ratio {row['ratio']})"
        )
