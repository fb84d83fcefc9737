"""Synthetic image datasets: a robot with known errors photographs a board, rendered with the
real camera model, so that the whole image pipeline can be checked against the truth.

The truth is a :class:`relcal.sim.scenario.Scenario` in a cell with this module's camera and
board: the board lies on the table with its centre at ``Cell.center`` and its z axis pointing
down (into the table), so a camera looking down at it sees its front, as OpenCV expects.
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from relcal import geometry as tf
from relcal.calibration.noise import Noise
from relcal.data.dataset import joints_in_unit, write_samples
from relcal.design.cell import Cell, default_board
from relcal.io import write_text, yaml_text
from relcal.robot.kinematics import Layout, make_layout
from relcal.robot.model import RobotModel
from relcal.sim.scenario import clean_poses, make_scenario, measure_once
from relcal.vision.boards import Board, board_to_spec
from relcal.vision.camera import Camera, save_camera
from relcal.vision.render import render_board

DEFAULT_CAMERA = Camera(
    fx=2319.0,
    fy=2319.0,
    cx=1223.5,
    cy=1023.5,
    distortion=(-0.08, 0.05, 0.0, 0.0, 0.0),
    width=2448,
    height=2048,
)  # 2448 x 2048 px, 3.45 um pixels, 8 mm lens
DEFAULT_BOARD = default_board()


@dataclass(frozen=True)
class Truth:
    """What the synthetic robot really is."""

    model: RobotModel  # true geometry
    layout: Layout
    errors: np.ndarray  # true geometric errors in ``layout``
    handeye: np.ndarray  # true flange-from-camera X
    board_pose: np.ndarray  # board frame in the robot base frame

    def errors_on(self, layout: Layout) -> np.ndarray:
        """The true errors ``(layout.size,)`` on another layout, matched by parameter name:
        e.g. a calibration's, which adds the non-geometric candidates of model selection. A
        parameter the truth does not have was not planted: its true error is 0."""
        true = dict(zip(self.layout.names, self.errors, strict=True))
        return np.array([true.get(name, 0.0) for name in layout.names])


def _render_to_file(job: tuple) -> None:
    board, camera, pose, blur, noise, seed, path = job
    image = render_board(board, camera, pose, blur, noise, 0.3, seed)
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise RuntimeError(f"could not encode {path}")
    Path(path).write_bytes(data.tobytes())


def write_image_dataset(
    root: str | Path,
    model: RobotModel,
    n_images: int = 40,
    seed: int = 0,
    board: Board = DEFAULT_BOARD,
    camera: Camera = DEFAULT_CAMERA,
    cell: Cell | None = None,
    blur_sigma: float = 0.8,
    noise_sigma: float = 2.0,
    joint_noise: float = 0.0,
    progress: bool = True,
    workers: int = 2,
) -> Truth:
    """Render ``n_images`` views of the board from a robot with random errors into a dataset
    folder (``dataset.yaml``, ``board.yaml``, ``camera.yaml``, ``robot.yaml``, ``samples.csv``,
    ``images/``) and return the truth. The nominal model is what the dataset names."""
    from relcal.robot.model import dump_model

    root = Path(root)
    rng = np.random.default_rng(seed)
    cell = replace(cell or Cell(), board=board, camera=camera)
    scenario = make_scenario(
        model, noise=Noise(joints=joint_noise), seed=rng, cell=cell, n_poses=n_images
    )
    q = scenario.q
    cams = clean_poses(scenario)  # T_board_camera
    (root / "images").mkdir(parents=True, exist_ok=True)
    names = [f"images/{k:03d}.png" for k in range(len(q))]
    jobs = [
        (board, camera, cams[k], blur_sigma, noise_sigma, seed + k, root / names[k])
        for k in range(len(q))
    ]
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(workers, mp_context=context) as pool:
        done = pool.map(_render_to_file, jobs)
        list(tqdm(done, total=len(jobs), disable=not progress, desc="rendering", unit="image"))
    q_read, _ = measure_once(scenario, rng, cams)
    ids = [f"{k:03d}" for k in range(len(q))]
    q_deg = joints_in_unit(model, q_read, "deg")
    write_text(root / "samples.csv", write_samples(root / "samples.csv", ids, q_deg, images=names))
    write_text(root / "board.yaml", yaml_text(board_to_spec(board)))
    save_camera(camera, root / "camera.yaml")
    write_text(root / "robot.yaml", dump_model(model))
    xyz, rpy = tf.to_xyz_rpy(scenario.handeye_guess)
    spec = {
        "robot": "robot.yaml",
        "hayati": "auto",
        "mode": "eye_in_hand",
        "board": "board.yaml",
        "camera": "camera.yaml",
        "handeye": {"xyz": [float(v) for v in xyz], "rpy": [float(np.degrees(v)) for v in rpy]},
        "joint_unit": "deg",
        "samples": "samples.csv",
    }
    write_text(root / "dataset.yaml", yaml_text(spec))
    return Truth(
        scenario.true_model, make_layout(model), scenario.errors, scenario.handeye, cell.board_pose
    )
