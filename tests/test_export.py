"""Exports: the URDF reproduces relcal's forward kinematics when loaded by a maintained URDF
library (yourdfpy), for standard and modified DH, calibrated (non-ideal) chains included."""

from dataclasses import replace

import numpy as np
import pytest
import yourdfpy
from conftest import random_q

from relcal import geometry as tf
from relcal.robot.export import calibrated_model, parameter_csv, urdf
from relcal.robot.kinematics import fk, make_layout
from relcal.robot.loading import get_robot
from relcal.robot.model import auto_hayati, library_names


def calibrated(name, rng):
    """A library robot with Hayati joints, random base and tool and random geometric errors."""
    model = auto_hayati(get_robot(name))
    model = replace(
        model,
        base=tf.from_vector(rng.normal(0, 0.2, 6)),
        tool=tf.from_vector(rng.normal(0, 0.1, 6)),
    )
    layout = make_layout(model)
    return calibrated_model(model, layout, rng.normal(0, 1e-3, layout.size))


@pytest.mark.parametrize("name", library_names())
def test_urdf_matches_forward_kinematics(name, tmp_path, rng):
    model = calibrated(name, rng)
    path = tmp_path / "robot.urdf"
    path.write_text(urdf(model))
    robot = yourdfpy.URDF.load(str(path), load_meshes=False, build_scene_graph=True)
    q = random_q(model, 20, rng)
    ours = fk(model, q)
    for k in range(len(q)):
        robot.update_cfg(dict(zip(model.joint_names, q[k], strict=True)))
        theirs = robot.get_transform("tool0", "base_link")
        np.testing.assert_allclose(theirs, ours[k], atol=1e-9)


def test_calibrated_model_name_and_csv(rng):
    model = calibrated("a465", rng)
    assert model.name == "Thermo CRS A465 (calibrated)"
    text = parameter_csv([{"name": "a[1]", "value": 1.0}, {"name": "d[2]", "value": 2.0}])
    assert text.splitlines() == ["name,value", "a[1],1.0", "d[2],2.0"]
