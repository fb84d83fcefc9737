"""easy_handeye2's saved samples imported for ``relcal handeye``: planted frames come back."""

from __future__ import annotations

import numpy as np
import pytest
from helpers_handeye import W_TRUE, X_TRUE, camera_poses, flange_poses
from scipy.spatial.transform import Rotation

import relcal
from relcal import geometry as tf
from relcal.cli import main


def _transform_yaml(pose: np.ndarray, indent: str) -> str:
    """A geometry_msgs/Transform as rosidl's message_to_yaml writes it (block style)."""
    q = Rotation.from_matrix(pose[:3, :3]).as_quat()
    t = pose[:3, 3]
    return (
        f"{indent}translation:\n"
        + "".join(f"{indent}  {k}: {float(v)!r}\n" for k, v in zip("xyz", t, strict=True))
        + f"{indent}rotation:\n"
        + "".join(f"{indent}  {k}: {float(v)!r}\n" for k, v in zip("xyzw", q, strict=True))
    )


def _samples_file(path, robot: np.ndarray, tracking: np.ndarray) -> None:
    text = "samples:\n"
    for r, t in zip(robot, tracking, strict=True):
        text += "- robot:\n" + _transform_yaml(r, "    ") + "  tracking:\n"
        text += _transform_yaml(t, "    ")
    path.write_text(text)


@pytest.mark.parametrize("calibration_type", ["eye_in_hand", "eye_on_base"])
def test_easy_handeye2_samples_give_the_planted_transform(tmp_path, capsys, calibration_type):
    """A session saved by easy_handeye2 (its tf lookups: ``robot`` base -> effector for
    eye-in-hand, effector -> base for eye-on-base; ``tracking`` camera -> marker) imports into a
    dataset whose hand-eye is the planted one, within its noise."""
    flange = flange_poses(16, seed=40)
    measured = camera_poses(flange, seed=40)  # relcal's C = W F X
    if calibration_type == "eye_in_hand":  # C: the camera in the board frame
        robot, tracking = flange, tf.invert(measured)
    else:  # C: the marker (board on the flange) in the camera frame
        robot, tracking = tf.invert(flange), measured
    source = tmp_path / "cell.samples"
    _samples_file(source, robot, tracking)
    mode = "eye_in_hand" if calibration_type == "eye_in_hand" else "eye_to_hand"
    out = tmp_path / "ds"
    assert main(["import", "easy-handeye2", str(source), "--mode", mode, "--out", str(out)]) == 0
    assert "16 samples" in capsys.readouterr().out
    result = relcal.handeye(relcal.load_dataset(out))
    x = result.fit.handeye
    error = tf.to_vector(tf.invert(X_TRUE) @ x)
    assert np.abs(error[:3]).max() < 2e-3 and np.abs(error[3:]).max() < np.radians(0.3)
    w = result.fit.world
    assert np.abs(tf.to_vector(tf.invert(W_TRUE) @ w)[:3]).max() < 5e-3


def test_easy_handeye2_import_refuses_what_it_cannot_read(tmp_path, capsys):
    """No --mode (the file does not say it, and the other reading fits as well), a rotation that
    is not a unit quaternion, a file of another kind: exit 2, nothing written."""
    flange = flange_poses(6, seed=41)
    source = tmp_path / "cell.samples"
    _samples_file(source, flange, tf.invert(camera_poses(flange, seed=41)))
    out = tmp_path / "ds"
    assert main(["import", "easy-handeye2", str(source), "--out", str(out)]) == 2
    assert "--mode eye_in_hand or eye_to_hand" in capsys.readouterr().err
    source.write_text(source.read_text().replace("    w: ", "    w: 2", 1))
    assert main(["import", "easy-handeye2", str(source), "--mode", "eye_in_hand",
                 "--out", str(out)]) == 2  # fmt: skip
    assert "expected a unit quaternion" in capsys.readouterr().err
    source.write_text("parameters:\n  name: x\n")
    assert main(["import", "easy-handeye2", str(source), "--mode", "eye_in_hand",
                 "--out", str(out)]) == 2  # fmt: skip
    assert "samples" in capsys.readouterr().err
    assert not out.exists()
