"""Non-geometric joint terms: joint scale, compliance under gravity, first harmonic.

Against independent truth: the effective joint value written out by hand, gravity torques as the
derivative of the potential energy, the analytic Jacobians against finite differences of the
forward kinematics, and planted errors recovered within their predicted standard deviations.
"""

from dataclasses import replace

import numpy as np
import pytest
import yaml
from conftest import random_q
from helpers_sim import BOARD, HANDEYE, with_plausible_loads

from relcal import geometry as tf
from relcal.calibration.identify import identify
from relcal.calibration.measurement import Problem, make_pairs, residuals
from relcal.calibration.noise import Noise
from relcal.calibration.uncertainty import parameter_covariance
from relcal.errors import RelcalError
from relcal.robot import kinematics
from relcal.robot.export import urdf
from relcal.robot.kinematics import (
    apply_errors,
    effective_joints,
    fk,
    forward_frames,
    gravity_torques,
    make_layout,
    pose_jacobian,
    spatial_jacobian,
)
from relcal.robot.loading import get_robot
from relcal.robot.model import (
    auto_hayati,
    dump_model,
    model_from_dict,
    model_to_dict,
    nongeometric_options,
    with_nongeometric,
)

ALL = ["scale", "compliance", "harmonic"]


def loaded(name: str, terms=ALL):
    return with_nongeometric(with_plausible_loads(auto_hayati(get_robot(name)), name), terms)


def with_values(model, rng, size=1e-3, compliance=5e-5):
    n = model.n_joints
    return replace(
        model,
        scale=rng.normal(0, size, n),
        compliance=rng.normal(0, compliance, n),
        harmonic_c=rng.normal(0, size, n),
        harmonic_s=rng.normal(0, size, n) * ~model.prismatic,
    )


# --- the effective joint value and the gravity torques --------------------------------------------


def test_effective_joints_written_out(rng):
    model = with_values(loaded("a465"), rng)
    q = random_q(model, 7, rng)
    tau = gravity_torques(model, q)
    expected = (
        q
        + model.scale * q
        + model.compliance * tau
        + model.harmonic_c * np.cos(q)
        + model.harmonic_s * np.sin(q)
    )
    np.testing.assert_allclose(effective_joints(model, q), expected, rtol=0, atol=1e-15)
    geometry = replace(model, scale=None, compliance=None, harmonic_c=None, harmonic_s=None)
    np.testing.assert_allclose(fk(model, q), fk(geometry, expected), rtol=0, atol=1e-14)


@pytest.mark.parametrize("name", ["a465", "franka_fr3", "prismatic"])
def test_gravity_torques_are_minus_the_potential_gradient(name, rng):
    """tau_i = -dV/dq_i with V = -sum m g . p_com, by central differences of positions."""
    base = get_robot("a465" if name == "prismatic" else name)
    if name == "prismatic":
        base = replace(base, prismatic=np.array([False, False, True, False, False, False]))
    model = with_plausible_loads(base, "franka_fr3" if name == "franka_fr3" else "a465")
    model = replace(model, loads=replace(model.loads, gravity=np.array([0.5, -1.0, -9.7])))
    loads, n = model.loads, model.n_joints

    def potential(q):
        frames = forward_frames(model, q)
        com = np.einsum("nkij,kj->nki", frames[:, 1:, :3, :3], loads.com) + frames[:, 1:, :3, 3]
        tip = frames[:, -1] @ model.tool
        payload = tip[:, :3, :3] @ loads.payload_com + tip[:, :3, 3]
        heights = com @ loads.gravity * loads.mass
        return -(heights.sum(axis=1) + payload @ loads.gravity * loads.payload_mass)

    q = random_q(model, 5, rng)
    h = 1e-6
    numeric = np.stack(
        [
            -(potential(q + h * np.eye(n)[i]) - potential(q - h * np.eye(n)[i])) / (2 * h)
            for i in range(n)
        ],
        axis=1,
    )
    np.testing.assert_allclose(gravity_torques(model, q), numeric, rtol=0, atol=1e-6)
    assert np.abs(numeric).max() > 10  # torques of tens of N m: the check is not vacuous


def test_gravity_torques_use_the_reference_geometry(rng):
    model = loaded("a465")
    q = random_q(model, 4, rng)
    layout = make_layout(model)
    moved = apply_errors(model, layout, rng.normal(0, 1e-2, layout.size))
    assert np.array_equal(gravity_torques(moved, q), gravity_torques(model, q))
    assert np.array_equal(gravity_torques(get_robot("a465"), q), np.zeros((4, 6)))


# --- analytic Jacobians against finite differences ------------------------------------------------


def _finite_difference(model, layout, p0, q, h=1e-6):
    """Pose (tool point, base frame) and spatial Jacobians by central differences."""
    pose = fk(apply_errors(model, layout, p0), q)
    jp, js = np.zeros((len(q), 6, layout.size)), np.zeros((len(q), 6, layout.size))
    for k in range(layout.size):
        step = h * np.eye(layout.size)[k]
        d = (fk(apply_errors(model, layout, p0 + step), q)
             - fk(apply_errors(model, layout, p0 - step), q)) / (2 * h)  # fmt: skip
        w = d[:, :3, :3] @ np.swapaxes(pose[:, :3, :3], -1, -2)
        jp[:, :3, k], jp[:, 3:, k] = d[:, :3, 3], np.stack([w[:, 2, 1], w[:, 0, 2], w[:, 1, 0]], 1)
        s = d @ tf.invert(pose)
        js[:, :3, k], js[:, 3:, k] = s[:, :3, 3], np.stack([s[:, 2, 1], s[:, 0, 2], s[:, 1, 0]], 1)
    return jp, js


@pytest.mark.parametrize("name", ["a465", "franka_fr3", "prismatic"])
def test_jacobians_match_finite_differences(name, rng):
    if name == "prismatic":  # joint 3 slides: scale and compliance apply, harmonic does not
        base = replace(get_robot("a465"), prismatic=np.array([0, 0, 1, 0, 0, 0], dtype=bool))
        model = with_nongeometric(with_plausible_loads(auto_hayati(base), "a465"), ALL)
        assert "harmonic_c[3]" not in make_layout(model).names
        assert make_layout(model).units()[make_layout(model).names.index("compliance[3]")] == "m/N"
    else:
        model = loaded(name)
    layout = make_layout(model, base=True, tool=True)
    p0 = rng.normal(0, 1e-3, layout.size) * layout.is_geometric()
    p0[np.isin(layout.kinds, ("base", "tool"))] = 0.0  # frame errors compose: FD at zero only
    p0 += np.where(np.array(layout.kinds) == "compliance", rng.normal(0, 5e-5, layout.size), 0)
    q = random_q(model, 6, rng)
    numeric_pose, numeric_spatial = _finite_difference(model, layout, p0, q)
    truth = apply_errors(model, layout, p0)
    _, jp = pose_jacobian(truth, q, layout)
    _, js = spatial_jacobian(truth, q, layout)
    np.testing.assert_allclose(jp, numeric_pose, rtol=0, atol=1e-7)
    np.testing.assert_allclose(js, numeric_spatial, rtol=0, atol=1e-7)
    nongeo = ~layout.is_geometric()
    assert np.abs(jp[..., nongeo]).max() > 1e-2  # the new columns are not all zero


# --- layout, model files, defaults ----------------------------------------------------------------


def test_layout_names_order_and_units():
    model = with_nongeometric(with_plausible_loads(get_robot("a465"), "a465"), ALL, [2, 3])
    layout = make_layout(model, tool=True)
    geometric = make_layout(get_robot("a465"), tool=True)
    new = [n for n in layout.names if n not in geometric.names]
    assert new == [
        "scale[2]", "scale[3]", "compliance[2]", "compliance[3]",
        "harmonic_c[2]", "harmonic_c[3]", "harmonic_s[2]", "harmonic_s[3]",
    ]  # fmt: skip
    assert layout.names[-6:] == geometric.names[-6:]  # frames stay last
    units = dict(zip(layout.names, layout.display()[1], strict=True))
    assert (units["scale[2]"], units["compliance[2]"], units["harmonic_s[3]"]) == (
        "ppm", "urad/Nm", "deg",
    )  # fmt: skip


def test_defaults_off_leave_models_and_files_unchanged(rng):
    for name in ("a465", "franka_fr3", "puma560"):
        model = get_robot(name)
        text = dump_model(model)
        for key in ("mass", "com", "scale", "compliance", "harmonic", "nongeometric", "payload"):
            assert f"{key}:" not in text
        assert make_layout(model).is_geometric().all()
        q = random_q(model, 5, rng)
        assert np.array_equal(effective_joints(model, q), q)
    # Options on but no values yet: the same kinematics.
    model = loaded("a465")
    q = random_q(model, 5, rng)
    assert np.array_equal(fk(model, q), fk(auto_hayati(get_robot("a465")), q))


def test_model_file_round_trip(rng):
    model = with_values(loaded("franka_fr3"), rng)
    again = model_from_dict(yaml.safe_load(dump_model(model)))
    assert again.nongeometric == model.nongeometric
    for kind in ("scale", "compliance", "harmonic_c", "harmonic_s"):
        np.testing.assert_allclose(getattr(again, kind), getattr(model, kind), rtol=1e-12)
    np.testing.assert_allclose(again.loads.mass, model.loads.mass)
    np.testing.assert_allclose(again.loads.com, model.loads.com)
    assert again.loads.payload_mass == 1.0
    q = random_q(model, 5, rng)
    np.testing.assert_allclose(fk(again, q), fk(model, q), rtol=0, atol=1e-12)


def test_model_file_keys():
    spec = model_to_dict(get_robot("a465"))
    spec["joints"][1].update(mass=6.0, com=[-0.15, 0, 0], nongeometric=["compliance", "scale"])
    spec["joints"][1].update(scale=1e-3, harmonic=[0.01, 0.0])
    spec["payload"] = {"mass": 2.0, "com": [0, 0, 0.1]}
    spec["gravity"] = [0, 0, -9.8]
    model = model_from_dict(spec)
    assert model.nongeometric[1] == ("scale", "compliance")
    assert model.scale[1] == 1e-3 and np.isclose(model.harmonic_c[1], np.radians(0.01))
    assert model.loads.payload_mass == 2.0 and model.loads.gravity[2] == -9.8
    assert make_layout(model).names[-2:] == ("scale[2]", "compliance[2]")


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"nongeometric": ["compliance"]}, "compliance needs gravity torques"),
        ({"type": "prismatic", "nongeometric": ["harmonic"]}, "prismatic joint has no first"),
        ({"nongeometric": ["backlash"]}, "nongeometric"),
        ({"mass": -1.0}, "mass"),
        ({"com": [0, 0]}, "com"),
    ],
)
def test_model_file_errors_name_the_field(change, message):
    spec = model_to_dict(get_robot("a465"))
    spec["joints"][2].update(change)
    with pytest.raises(RelcalError, match=message):
        model_from_dict(spec, "arm.yaml")


def test_options_a_model_can_have():
    assert nongeometric_options(get_robot("a465")) == ("scale", "harmonic")
    assert nongeometric_options(loaded("a465")) == ("scale", "compliance", "harmonic")
    slider = replace(get_robot("a465"), prismatic=np.ones(6, dtype=bool))
    assert nongeometric_options(slider) == ("scale",)


def test_with_nongeometric_refuses_what_cannot_be():
    prismatic = replace(get_robot("a465"), prismatic=np.array([0, 0, 1, 0, 0, 0], dtype=bool))
    with pytest.raises(RelcalError, match="joint 3 .* prismatic"):
        with_nongeometric(prismatic, ["harmonic"], [3])
    with pytest.raises(RelcalError, match="needs gravity torques"):
        with_nongeometric(get_robot("a465"), ["compliance"])
    with pytest.raises(RelcalError, match="unknown non-geometric term"):
        with_nongeometric(get_robot("a465"), ["backlash"])
    with pytest.raises(RelcalError, match="joint 9"):
        with_nongeometric(get_robot("a465"), ["scale"], [9])


def test_urdf_keeps_the_geometry_and_says_what_it_drops(rng):
    model = with_values(loaded("a465"), rng)
    geometry = replace(model, scale=None, compliance=None, harmonic_c=None, harmonic_s=None)
    lines = urdf(model).splitlines()
    assert "not expressible in URDF" in lines[2]
    assert lines[:2] + lines[3:] == urdf(geometry).splitlines()  # the geometry, no offsets


def test_numba_backend_without_numba_is_a_clear_error(monkeypatch, a465):
    monkeypatch.setattr(kinematics, "_fast_available", lambda: False)
    with pytest.raises(RelcalError, match=r"optional: pip install 'relcal\[fast\]'"):
        fk(a465, np.zeros((2, 6)), backend="numba")
    q = np.full((kinematics._LOAD_MIN, 6), 0.1)
    assert np.array_equal(fk(a465, q[:3], backend="auto"), fk(a465, q[:3]))
    assert not kinematics._use_fast("auto", len(q))  # auto falls back to NumPy


# --- identification: planted terms recovered, none planted gives zero ---------------------------

NOISE = Noise(position=2e-5, orientation=2e-5)


def _problem(model, layout, true_model, true_x, q, rng, noise=NOISE):
    poses = BOARD @ fk(true_model, q) @ true_x
    delta = np.concatenate(
        [rng.normal(0, noise.position, (len(q), 3)), rng.normal(0, noise.orientation, (len(q), 3))],
        axis=1,
    )
    poses = poses @ tf.from_vector(delta)
    return Problem(model, layout, q, poses, "invariant", "pose", make_pairs(len(q)), HANDEYE)


def _rms(problem, params):
    return float(np.sqrt(np.mean(residuals(problem, params, jacobian=False) ** 2)))


PLANTED = {  # SI: scale (1), compliance (rad/(N m)), harmonics (rad)
    "a465": {
        "scale[1]": 8e-4, "scale[2]": -5e-4, "scale[3]": 6e-4,
        "compliance[2]": 2e-5, "compliance[3]": 4e-5,
        "harmonic_c[1]": 2e-4, "harmonic_s[2]": -3e-4, "harmonic_c[4]": 3e-4,
    },
    "franka_fr3": {
        "scale[1]": -6e-4, "scale[4]": 7e-4, "scale[6]": -5e-4,
        "compliance[2]": 3e-5, "compliance[4]": 5e-5,
        "harmonic_c[1]": 2e-4, "harmonic_s[3]": -3e-4, "harmonic_c[5]": 3e-4,
    },
}  # fmt: skip


def _scenario(name, rng, planted: bool, n_train=80):
    """Nominal model with all three terms on every joint, a truth with geometric errors and the
    planted terms (or none), training and held-out problems."""
    model = loaded(name)
    layout = make_layout(model)
    truth = rng.normal(0, 2e-4, layout.size) * layout.is_geometric()
    if planted:
        for key, value in PLANTED[name].items():
            truth[layout.names.index(key)] = value
    true_model = apply_errors(model, layout, truth)
    true_x = HANDEYE @ tf.from_vector(np.r_[rng.normal(0, 1e-3, 3), rng.normal(0, 5e-3, 3)])
    train = _problem(model, layout, true_model, true_x, random_q(model, n_train, rng), rng)
    held = _problem(model, layout, true_model, true_x, random_q(model, 40, rng), rng)
    handeye_truth = tf.to_vector(tf.invert(HANDEYE) @ true_x)
    return model, layout, train, held, np.r_[truth, handeye_truth]


@pytest.mark.parametrize("name", ["a465", "franka_fr3"])
def test_planted_terms_recovered_within_three_sigma(name, rng):
    model, layout, train, held, truth = _scenario(name, rng, planted=True)
    result = identify(train)
    assert result.converged
    unc = parameter_covariance(train, NOISE, identifiability=result.identifiability)
    names = train.full_layout.names
    for key, value in PLANTED[name].items():
        k = names.index(key)
        assert result.identifiable[k], f"{key} should be identifiable"
        z = (result.params[k] - value) / unc.std[k]
        assert abs(z) < 3, f"{key}: {result.params[k]:.3g} vs {value:.3g}, {z:+.1f} sigma"
        assert unc.std[k] < abs(value) / 5  # determined, not merely consistent
        # The result's own covariance (noise estimated from its residuals) agrees.
        assert 0.7 < result.std[k] / unc.std[k] < 1.3
    # Held-out relative poses down to the noise floor (the truth's own residual) ...
    floor = _rms(held, truth)
    assert _rms(held, result.params) < 1.1 * floor
    # ... which a geometric-only model of the same data does not reach.
    geometric = make_layout(auto_hayati(get_robot(name)))
    geo_train = replace(train, model=auto_hayati(get_robot(name)), layout=geometric)
    geo = identify(geo_train)
    geo_held = replace(held, model=geo_train.model, layout=geometric)
    assert _rms(geo_held, geo.params) > 3 * floor


@pytest.mark.parametrize("name", ["a465", "franka_fr3"])
def test_nothing_planted_fits_zero(name, rng):
    model, layout, train, held, truth = _scenario(name, rng, planted=False)
    result = identify(train)
    unc = parameter_covariance(train, NOISE, identifiability=result.identifiability)
    nongeo = np.flatnonzero(~train.full_layout.is_geometric() & result.identifiable)
    nongeo = nongeo[np.isin(nongeo, unc.subset)]
    z = result.params[nongeo] / unc.std[nongeo]
    assert len(nongeo) >= 3 * model.n_joints
    assert np.abs(z).max() < 3.5, dict(
        zip(np.array(train.full_layout.names)[nongeo], z, strict=True)
    )
    assert np.mean(z**2) < 2.0  # about one for an honest covariance


def test_identifiability_of_the_new_terms(rng):
    """In relative data theta_off[1] is a base rotation, but the harmonic and the scale of joint
    1 vary with q_1 and are identified; compliance of the vertical joint 1 has no torque."""
    _, _, train, _, _ = _scenario("a465", rng, planted=True, n_train=40)
    result = identify(train)
    ok = dict(zip(train.full_layout.names, result.identifiable, strict=True))
    assert not ok["theta_off[1]"]
    assert ok["harmonic_c[1]"] and ok["harmonic_s[1]"] and ok["scale[1]"]
    assert not ok["compliance[1]"]
    texts = result.unidentifiable
    assert "compliance[1]: has no effect on the tool pose" in texts


def test_dataset_builder_plants_and_calibration_recovers(tmp_path):
    from helpers_dataset import synthetic_dataset

    from relcal.calibration.pipeline import calibrate
    from relcal.calibration.validate import stats
    from relcal.data.dataset import load_dataset
    from relcal.data.imaging import measure

    syn = synthetic_dataset(tmp_path / "d", n=40, nongeometric=("scale", "harmonic"), seed=3)
    dataset = load_dataset(tmp_path / "d")
    assert dataset.model.nongeometric[0] == ("scale", "harmonic")  # written as options
    # every planted term estimated (selection "all"): what is checked is their recovery
    measured = measure(dataset, progress=False)
    cal = calibrate(dataset, measured, nongeometric="none", selection="all")
    layout = cal.problem.layout
    assert layout.names == syn.layout.names
    nongeo = np.flatnonzero(~layout.is_geometric())
    assert len(nongeo) == 18 and cal.result.identifiable[nongeo].all()
    z = (cal.result.params[nongeo] - syn.truth[nongeo]) / cal.std[nongeo]
    assert np.abs(z).max() < 4, z
    after = stats(cal.validation.calibrated)["position_mm"]["rms"]
    assert after < 0.1  # the noise floor of 0.02 mm poses, where the terms are not fitted: mm


def test_simulate_command_plants_the_terms(tmp_path, capsys):
    import json

    from relcal.cli import main

    errors = tmp_path / "errors.yaml"
    errors.write_text("errors:\n  scale[2]: 0.0005\n  harmonic_c[3]: 0.01\n  theta_off[2]: 0.1\n")
    out = tmp_path / "out.json"
    argv = ["simulate", "--measure", "pose", "--poses", "30", "--errors", str(errors)]
    argv += ["--json", str(out)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "scale[2]        ppm  500.0000   500.0000" in text
    rows = {p["name"]: p for p in json.loads(out.read_text())["parameters"]}
    assert rows["scale[2]"]["unit"] == "1" and rows["harmonic_s[3]"]["unit"] == "rad"
    assert np.isclose(rows["harmonic_c[3]"]["identified"], np.radians(0.01), rtol=1e-9)
    assert "scale[1]" not in rows  # only the joints the file names
    assert (
        main(["simulate", "--measure", "pose", "--poses", "30", "--nongeometric", "scale,harmonic"])
        == 0
    )
    assert "harmonic_s[6]" in capsys.readouterr().out
    assert main(["simulate", "--nongeometric", "compliance"]) == 2
    assert "needs gravity torques" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["a465", "franka_fr3"])
def test_inverse_kinematics_with_the_terms(name, rng):
    """The closed form of the geometry only seeds; the solution reproduces the pose with the
    terms (what compensation of a calibrated model needs)."""
    from relcal.robot.ik import solve

    model = with_values(loaded(name), rng, size=1e-3, compliance=5e-5)
    q = random_q(model, 20, rng, scale=0.7)
    target = fk(model, q)
    result = solve(model, target, q_near=q + 0.05)
    assert result.converged.all()
    np.testing.assert_allclose(fk(model, result.q), target, rtol=0, atol=1e-9)
    if model.n_joints == 6:  # the branch nearest q_near is q itself (the FR3 is redundant)
        np.testing.assert_allclose(result.q, q, rtol=0, atol=1e-7)


def test_errors_file_units_of_the_new_terms(tmp_path):
    from relcal.sim.scenario import load_errors, nongeometric_in_errors

    path = tmp_path / "errors.yaml"
    path.write_text(
        "angle_unit: deg\nerrors:\n  scale[2]: 0.001\n  compliance[3]: 0.002\n"
        "  harmonic_s[1]: 0.05\n  d[4]: 0.3\n"
    )
    assert nongeometric_in_errors(path) == {"scale": [2], "compliance": [3], "harmonic": [1]}
    model = loaded("a465")
    layout = make_layout(model)
    values = dict(zip(layout.names, load_errors(path, layout), strict=True))
    assert values["scale[2]"] == 0.001  # a plain number
    assert np.isclose(values["compliance[3]"], np.radians(0.002))  # deg per N m
    assert np.isclose(values["harmonic_s[1]"], np.radians(0.05))
    assert np.isclose(values["d[4]"], 0.3e-3)
    with pytest.raises(RelcalError, match="need the joint's option"):
        load_errors(path, make_layout(get_robot("a465")))


@pytest.mark.parametrize("name", ["panda", "tiago_pro"])
def test_gravity_torques_match_pinocchio_on_urdf_robots(name, rng):
    """A URDF robot's link inertials serve as loads; the torques are Pinocchio's generalised
    gravity (negated), the TIAGo Pro's prismatic torso included (a force, N)."""
    pin = pytest.importorskip("pinocchio", reason="Pinocchio is in the dev extra")
    from urdf_helpers import real

    from relcal.robot.urdf import load_urdf

    path, root, tip = real(name)
    model = with_nongeometric(load_urdf(path, root, tip), ALL)
    assert model.loads is not None and "compliance" in model.nongeometric[0]
    if model.prismatic.any():
        assert "harmonic" not in model.nongeometric[int(np.flatnonzero(model.prismatic)[0])]
    full = pin.buildModelFromUrdf(str(path))
    ids = [full.getJointId(n) for n in model.joint_names]
    for j in range(1, full.njoints):  # only the chain's bodies pull, as in relcal's inertials
        if j not in ids:
            full.inertias[j] = pin.Inertia.Zero()
    data = full.createData()
    q = random_q(model, 4, rng, scale=0.5)
    ours = gravity_torques(model, q)
    for k in range(len(q)):
        config = pin.neutral(full)
        for i, joint in enumerate(ids):
            config[full.joints[joint].idx_q] = q[k, i]
        g = pin.computeGeneralizedGravity(full, data, config)
        theirs = -np.array([g[full.joints[joint].idx_v] for joint in ids])
        np.testing.assert_allclose(ours[k], theirs, rtol=0, atol=1e-9)
    assert np.abs(ours).max() > 1.0
