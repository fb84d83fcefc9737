"""Exports of URDF-loaded models back into the robot's own files: the calibrated URDF differs from
the input only in the calibrated joints' origins (a byte diff proves it) and reproduces relcal's
kinematics in Pinocchio and yourdfpy; the origin corrections, UR calibration.yaml and Franka
kinematics.yaml, written into the URDF the way xacro would, do too."""

import json
import re
from dataclasses import replace

import numpy as np
import pytest
import yaml
import yourdfpy
from conftest import random_q
from urdf_helpers import TIAGO, UR5E_KINEMATICS, pin_fk, real, substitute, ur_description_urdf

from relcal import geometry as tf
from relcal.errors import RelcalError
from relcal.robot.export import (
    calibrated_model,
    calibrated_urdf,
    franka_kinematics_yaml,
    origin_corrections_yaml,
    ur_calibration_yaml,
)
from relcal.robot.kinematics import fk, make_layout
from relcal.robot.loading import get_robot
from relcal.robot.model import NONGEOMETRIC_KINDS, with_nongeometric
from relcal.robot.urdf import load_urdf


def planted(name, rng, tool=False, size=1e-3):
    """The URDF robot with random geometric errors (and a tool error if asked)."""
    path, root, tip = real(name)
    model = load_urdf(path, root, tip)
    layout = make_layout(model, tool=tool)
    return model, calibrated_model(model, layout, rng.normal(0, size, layout.size))


def check_fk(path, model, q, tol=1e-9):
    """Pinocchio and yourdfpy FK of the URDF at ``path`` against relcal's ``model``."""
    ours = fk(model, q)
    root, tip = model.urdf.root, model.urdf.tip
    np.testing.assert_allclose(pin_fk(path, root, tip, model.joint_names, q), ours, atol=tol)
    robot = yourdfpy.URDF.load(str(path), load_meshes=False, build_scene_graph=True)
    for k in range(len(q)):
        robot.update_cfg(dict(zip(model.joint_names, q[k], strict=True)))
        np.testing.assert_allclose(robot.get_transform(tip, root), ours[k], atol=tol)


def origins_masked(data: bytes, names) -> bytes:
    """``data`` with the <origin> tag of each named top-level joint replaced by a placeholder."""
    for name in names:
        pattern = rb'(<joint name="' + name.encode() + rb'" type="[a-z]+">.*?)<origin [^>]*>'
        data = re.sub(pattern, rb"\1<ORIGIN>", data, count=1, flags=re.S)
    return data


def test_nominal_export_is_the_input_file():
    for name in ("tiago_pro", "ur5"):
        model = load_urdf(*real(name))
        assert calibrated_urdf(model) == model.urdf.data


def test_calibrated_tiago_urdf_changes_only_joint_origins(tmp_path, rng):
    nominal, model = planted("tiago_pro", rng)
    out = calibrated_urdf(model)
    assert out != nominal.urdf.data
    names = model.joint_names
    assert origins_masked(out, names) == origins_masked(nominal.urdf.data, names)
    # every movable chain joint's origin changed, and nothing else did
    assert origins_masked(out, names).count(b"<ORIGIN>") == len(names)
    path = tmp_path / "calibrated.urdf"
    path.write_bytes(out)
    check_fk(path, model, random_q(model, 10, rng))


def test_calibrated_urdf_carries_the_geometry_of_a_model_with_nongeometric_terms(tmp_path, rng):
    """Compliance (the URDF's inertials as loads) and harmonics deflect the joints even at
    q = 0; the exported origins are those of the geometry alone, as in :func:`urdf`."""
    _, model = planted("tiago_pro", rng)
    model = with_nongeometric(model, ["compliance", "harmonic"])
    n = model.n_joints
    model = replace(
        model,
        compliance=rng.normal(0, 1e-3, n),
        harmonic_c=rng.normal(0, 1e-3, n) * ~model.prismatic,
    )
    q = random_q(model, 10, rng)
    geometry = replace(model, **{k: None for k in NONGEOMETRIC_KINDS})
    assert np.abs(fk(model, q) - fk(geometry, q))[:, :3, 3].max() > 1e-3  # the terms matter
    path = tmp_path / "calibrated.urdf"
    path.write_bytes(calibrated_urdf(model))
    check_fk(path, geometry, q)


COMMENTED = (
    '<!-- a comment that names <joint name="j2" type="revolute"> and an <origin xyz="1 1 1"/> -->'
)


def test_comments_crlf_and_missing_origin_are_respected(tmp_path, rng):
    from test_urdf import AWKWARD

    text = AWKWARD.replace('<robot name="test">', f'<robot name="test">\n{COMMENTED}')
    text = text.replace('<origin xyz="0 0 0.1" rpy="0 0 0.7"/>', "")  # j5 without an <origin>
    text = text.replace('<origin xyz="0 0.1 0.1" rpy="1.2 0 0"/>', '<origin rpy="1.2 0 0"/>')
    data = text.replace("\n", "\r\n").encode()
    src = tmp_path / "awkward.urdf"
    src.write_bytes(data)
    model = load_urdf(src, tip="tip")
    layout = make_layout(model)
    model = calibrated_model(model, layout, rng.normal(0, 1e-3, layout.size))
    out = calibrated_urdf(model)
    assert COMMENTED.encode() in out and out.count(b"\r\n") == data.count(b"\r\n")
    path = tmp_path / "calibrated.urdf"
    path.write_bytes(out)
    check_fk(path, model, random_q(model, 10, rng))


def test_tool_change_goes_into_the_last_fixed_joint(tmp_path, rng):
    nominal, model = planted("panda", rng, tool=True)
    out = calibrated_urdf(model)
    names = (*model.joint_names, "panda_joint8")  # the flange joint carries the tool change
    assert origins_masked(out, names) == origins_masked(nominal.urdf.data, names)
    path = tmp_path / "calibrated.urdf"
    path.write_bytes(out)
    check_fk(path, model, random_q(model, 10, rng))
    # UR5's default tip is wrist_3_joint's own child: no fixed joint can take a tool change
    _, ur = planted("ur5", rng, tool=True)
    with pytest.raises(RelcalError, match="tool transform cannot be written"):
        calibrated_urdf(ur)


def test_origin_corrections_round_trip(tmp_path, rng):
    nominal, model = planted("tiago_pro", rng)
    doc = yaml.safe_load(origin_corrections_yaml(model))
    assert set(doc["joints"]) == set(model.joint_names)
    origins = {}
    for name, entry in doc["joints"].items():
        old = tf.from_xyz_rpy(entry["nominal"]["xyz"], entry["nominal"]["rpy"])
        fix = tf.from_xyz_rpy(entry["correction"]["xyz"], entry["correction"]["rpy"])
        origins[name] = old @ fix
    path = tmp_path / "corrected.urdf"
    path.write_bytes(substitute(TIAGO.read_bytes(), origins))
    check_fk(path, model, random_q(model, 10, rng))


def origin_of(entry: dict) -> np.ndarray:
    return tf.from_xyz_rpy(
        [entry["x"], entry["y"], entry["z"]], [entry["roll"], entry["pitch"], entry["yaw"]]
    )


def test_ur_calibration_yaml_round_trip(tmp_path, rng):
    """A UR5e laid out as ur_description builds it from default kinematics: the exported
    calibration.yaml, fed to the same construction, reproduces the calibrated model."""
    nominal_path = tmp_path / "ur5e.urdf"
    nominal_path.write_text(ur_description_urdf(UR5E_KINEMATICS))
    model = load_urdf(nominal_path, "base_link", "tool0")
    layout = make_layout(model)
    model = calibrated_model(model, layout, rng.normal(0, 1e-3, layout.size))
    doc = yaml.safe_load(ur_calibration_yaml(model))
    kin = doc["kinematics"]
    segments = ["shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3"]
    assert list(kin) == [*segments, "hash"] and re.fullmatch(r"calib_\d+", kin["hash"])
    assert all(set(kin[s]) == {"x", "y", "z", "roll", "pitch", "yaw"} for s in segments)
    path = tmp_path / "ur5e_calibrated.urdf"
    path.write_text(ur_description_urdf(kin))
    check_fk(path, model, random_q(model, 10, rng))
    # a nominal model gives back the defaults (the same origins; rpy in canonical form)
    nominal = yaml.safe_load(ur_calibration_yaml(load_urdf(nominal_path, "base_link", "tool0")))
    for segment in segments:
        np.testing.assert_allclose(
            origin_of(nominal["kinematics"][segment]),
            origin_of(UR5E_KINEMATICS[segment]),
            atol=1e-15,
        )


def test_ur_export_refuses_other_layouts():
    """example-robot-data's UR5 predates ur_description's layout (no base_link_inertia): its
    joint origins are not what the driver's kinematics entries mean."""
    with pytest.raises(RelcalError, match="base_link_inertia"):
        ur_calibration_yaml(load_urdf(*real("ur5")))


def test_franka_kinematics_yaml_round_trip(tmp_path, rng):
    nominal, model = planted("panda", rng, tool=True)
    doc = yaml.safe_load(franka_kinematics_yaml(model))
    assert list(doc) == [f"joint{k}" for k in range(1, 9)]
    origins = {f"panda_{key}": origin_of(entry["kinematic"]) for key, entry in doc.items()}
    path = tmp_path / "panda_calibrated.urdf"
    path.write_bytes(substitute(nominal.urdf.data, origins))
    check_fk(path, model, random_q(model, 10, rng))


def test_exports_need_a_urdf_robot():
    for export in (calibrated_urdf, origin_corrections_yaml, franka_kinematics_yaml):
        with pytest.raises(RelcalError, match="needs a robot loaded from a URDF"):
            export(get_robot("a465"))
    with pytest.raises(RelcalError, match="shoulder_pan_joint"):
        ur_calibration_yaml(load_urdf(*real("panda")))


@pytest.mark.parametrize("parametrisation", ["minimal", "origins"])
def test_calibrate_command_on_a_urdf_dataset(parametrisation, tmp_path, rng):
    """A UR5e dataset whose robot: is the URDF: calibrate writes the URDF files, the written
    URDF reproduces the calibrated model.yaml, and the planted errors are found (held-out
    error far below the baseline's)."""
    from helpers_sim import BOARD, HANDEYE

    from relcal.cli import main
    from relcal.data.dataset import load_dataset, write_samples
    from relcal.robot.model import auto_hayati, load_model

    root = tmp_path / "ur5e_run"
    root.mkdir()
    (root / "ur5e.urdf").write_text(ur_description_urdf(UR5E_KINEMATICS))
    (root / "dataset.yaml").write_text(
        "robot: {urdf: ur5e.urdf, root: base_link, tip: tool0, parametrisation: "
        f"{parametrisation}}}\njoint_unit: rad\n"
        "handeye: {xyz: [0, 0.04, 0.06]}\n"
    )
    model = auto_hayati(load_urdf(root / "ur5e.urdf", "base_link", "tool0", parametrisation))
    layout = make_layout(model)
    truth = calibrated_model(model, layout, rng.normal(0, 5e-4, layout.size))
    q = random_q(model, 40, rng, scale=0.8)
    noise = tf.from_vector(rng.normal(0, 2e-5, (len(q), 6)))  # 20 um, 20 urad
    poses = BOARD @ fk(truth, q) @ HANDEYE @ noise
    ids = [f"s{k:02d}" for k in range(len(q))]
    (root / "samples.csv").write_text(write_samples(root / "samples.csv", ids, q, poses=poses))
    out = tmp_path / "out"
    assert load_dataset(root).model.joint_names == model.joint_names
    assert main(["calibrate", str(root), "--out", str(out), "--quiet"]) == 0
    doc = json.loads((out / "results.json").read_text())
    assert doc["validation"]["calibrated"]["position_mm"]["rms"] < 0.2  # noise: 0.02 mm per pose
    for name in ("robot.urdf", "origin_corrections.yaml", "ur_calibration.yaml"):
        assert (out / name).is_file()
    calibrated = load_model(out / "model.yaml")
    ours = fk(calibrated, q[:10])
    theirs = pin_fk(out / "robot.urdf", "base_link", "tool0", calibrated.joint_names, q[:10])
    np.testing.assert_allclose(theirs, ours, atol=1e-9)


def test_dataset_and_command_line_take_a_urdf_chain(tmp_path, capsys):
    import argparse

    from urdf_helpers import TIAGO_CHAIN, TIAGO_JOINTS

    from relcal.cli import main
    from relcal.cli.common import load_robot, robot_args
    from relcal.data.dataset import load_dataset

    parser = argparse.ArgumentParser()
    robot_args(parser)
    args = parser.parse_args(
        ["--robot", str(TIAGO), "--root", TIAGO_CHAIN[0], "--tip", TIAGO_CHAIN[1]]
    )
    assert load_robot(args).joint_names == TIAGO_JOINTS
    assert main(["simulate", "--robot", str(TIAGO), "--tip", "nowhere_link"]) == 2
    assert "tip link 'nowhere_link' is not in the file" in capsys.readouterr().err
    root = tmp_path / "ds"
    root.mkdir()
    (root / "dataset.yaml").write_text(f"robot:\n  urdf: {TIAGO}\n  tipp: x\n")
    with pytest.raises(RelcalError, match=r"dataset.yaml: robot line 3: tipp"):
        load_dataset(root)


@pytest.mark.parametrize("off", [0.0, 1.8e-9, 1e-6, 0.3])
def test_rpy_of_origins_rebuilds_the_rotation_near_gimbal_lock(off, rng):
    """URDFs write pitch = 1.570796325 (UR): the rpy written back must rebuild the rotation to
    round-off, not to the 1e-9 that independent Euler formulas give there."""
    for sign in (1, -1):
        roll, yaw = rng.uniform(-np.pi, np.pi, 2)
        rot = tf.from_xyz_rpy([0, 0, 0], [roll, sign * (np.pi / 2 - off), yaw])
        _, rpy = tf.to_xyz_rpy(rot)
        np.testing.assert_allclose(tf.from_xyz_rpy([0, 0, 0], rpy), rot, atol=2e-15)
