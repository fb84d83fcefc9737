"""Synthetic hand-eye data with planted truth: flange poses, frames, noisy camera poses, images."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from relcal import geometry as tf

X_TRUE = tf.from_xyz_rpy(np.array([0.03, 0.05, 0.10]), np.radians([5.0, 10.0, 110.0]))
W_TRUE = tf.from_xyz_rpy(np.array([0.15, 0.08, 0.65]), np.radians([175.0, 5.0, 20.0]))
# camera-pose noise in the camera frame: correlated translation and rotation (a tilt and a shift
# explain the same image motion), as a PnP pose's
_S = np.diag([2e-4, 2e-4, 6e-4, 1e-3, 1e-3, 3e-4])
_R = np.eye(6)
_R[0, 4] = _R[4, 0] = 0.8
_R[1, 3] = _R[3, 1] = -0.8
NOISE = _S @ _R @ _S


def flange_poses(n: int, seed: int, spread: float = 0.45, axis: np.ndarray | None = None):
    """``n`` flange poses (base frame) looking roughly down at a board near (0.5, 0, 0): rotations
    of ``spread`` rad about random axes (or all about ``axis``, flange frame)."""
    rng = np.random.default_rng(seed)
    down = tf.rot_x(np.pi)
    if axis is None:
        turns = Rotation.from_rotvec(rng.normal(size=(n, 3)) * spread).as_matrix()
    else:
        turns = Rotation.from_rotvec(np.outer(rng.uniform(-1, 1, n) * spread * 2, axis)).as_matrix()
    rot = down @ turns
    pos = np.array([0.5, 0.0, 0.45]) + rng.normal(size=(n, 3)) * [0.08, 0.08, 0.04]
    return tf.homogeneous(rot, pos)


def camera_poses(flange, x=X_TRUE, w=W_TRUE, cov=NOISE, seed: int = 0) -> np.ndarray:
    """``W F X exp(eps)``, ``eps`` drawn from ``cov`` (camera frame)."""
    rng = np.random.default_rng(seed)
    eps = rng.multivariate_normal(np.zeros(6), cov, len(flange)) if cov is not None else 0.0
    return w @ flange @ x @ tf.from_vector(np.zeros((len(flange), 6)) + eps)


def write_flange_dataset(
    folder: Path, flange, poses=None, images=None, mode="eye_in_hand", extra: str = ""
) -> Path:
    """A dataset folder with flange-pose columns (no robot) and poses or image paths."""
    folder.mkdir(parents=True, exist_ok=True)
    head = ["id", "fx", "fy", "fz", "fqx", "fqy", "fqz", "fqw"]
    head += ["image"] if images is not None else ["x", "y", "z", "qx", "qy", "qz", "qw"]
    lines = [",".join(head)]
    for k, f in enumerate(flange):
        cells = [f"s{k:03d}", *(f"{v:.15g}" for v in f[:3, 3])]
        cells += [f"{v:.15g}" for v in Rotation.from_matrix(f[:3, :3]).as_quat()]
        if images is not None:
            cells.append(str(images[k]))
        else:
            c = poses[k]
            cells += [f"{v:.15g}" for v in c[:3, 3]]
            cells += [f"{v:.15g}" for v in Rotation.from_matrix(c[:3, :3]).as_quat()]
        lines.append(",".join(cells))
    (folder / "samples.csv").write_text("\n".join(lines) + "\n")
    (folder / "dataset.yaml").write_text(f"mode: {mode}\nsamples: samples.csv\n{extra}")
    return folder


def render_dataset(
    folder: Path, mode: str, n: int = 10, seed: int = 0, spread=(0.25, 0.25, 0.6), extra: str = ""
):
    """Rendered board images (a small camera) of planted frames: eye-in-hand (camera on the
    flange, board on the table) or eye-to-hand (camera fixed below, looking up at the board on
    the flange), turned about random axes by ``spread`` (rad, about the camera's x, y, z: zeros
    leave the others only); a folder with flange poses and images (``extra`` lines added to
    dataset.yaml), and the true ``X`` and ``W``."""
    import cv2

    from relcal.io import yaml_text
    from relcal.vision.boards import BoardSpec, board_to_spec
    from relcal.vision.camera import Camera
    from relcal.vision.render import render_board

    rng = np.random.default_rng(seed)
    board = BoardSpec(type="chessboard", rows=7, columns=9, square=0.02).to_board()
    camera = Camera(320.0, 320.0, 199.5, 149.5, (0.05, -0.1, 0.0, 0.0, 0.0), 400, 300)
    centre = np.array([0.08, 0.06, 0.0])  # of the board's corners, board frame
    turns = Rotation.from_rotvec(rng.normal(size=(n, 3)) * np.asarray(spread)).as_matrix()
    if mode == "eye_in_hand":
        x = tf.from_xyz_rpy(np.array([0.03, 0.05, 0.10]), np.radians([3.0, -4.0, 110.0]))
        base_board = tf.homogeneous(tf.rot_x(np.pi), np.array([0.45, -0.05, 0.0]))
        w = tf.invert(base_board)
        cam_rot = tf.rot_x(np.pi) @ turns  # looking down, tilted
        target = base_board[:3, :3] @ centre + base_board[:3, 3]
        pos = target - 0.35 * cam_rot[:, :, 2] + rng.normal(size=(n, 3)) * 0.02
        cam = tf.homogeneous(cam_rot, pos)  # camera in base
        flange = cam @ tf.invert(x)
    else:
        x = tf.from_xyz_rpy(np.array([-0.02, 0.03, 0.12]), np.radians([180.0, 0.0, 25.0]))
        base_cam = tf.homogeneous(np.eye(3), np.array([0.45, 0.0, -0.1]))  # looking up
        w = tf.invert(base_cam)
        board_rot = turns  # board z up, away from the camera, tilted
        ray = rng.normal(size=(n, 3)) * [0.05, 0.05, 0.0] + [0.0, 0.0, 0.42]
        pos = base_cam[:3, 3] + ray - np.einsum("nij,j->ni", board_rot, centre)
        flange = tf.homogeneous(board_rot, pos) @ tf.invert(x)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "images").mkdir(exist_ok=True)
    names = []
    c = w @ flange @ x
    for k in range(n):
        board_camera = c[k] if mode == "eye_in_hand" else tf.invert(c[k])
        image = render_board(board, camera, board_camera, 0.6, 1.5, 0.0, seed + k, supersample=1)
        name = f"images/{k:03d}.png"
        cv2.imwrite(str(folder / name), image)
        names.append(name)
    (folder / "board.yaml").write_text(yaml_text(board_to_spec(board)))
    cam = {
        "fx": 320.0,
        "fy": 320.0,
        "cx": 199.5,
        "cy": 149.5,
        "width": 400,
        "height": 300,
        "distortion": [0.05, -0.1, 0.0, 0.0, 0.0],
    }
    (folder / "camera.yaml").write_text(yaml_text(cam))
    write_flange_dataset(
        folder,
        flange,
        images=names,
        mode=mode,
        extra="board: board.yaml\ncamera: camera.yaml\n" + extra,
    )
    return folder, x, w
