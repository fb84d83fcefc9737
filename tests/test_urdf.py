"""URDF chains as relcal models: forward kinematics against Pinocchio on real URDFs (TIAGo Pro,
UR5, Panda, Kinova, Z1) and on hand-made ones with the awkward cases (prismatic, axis 0 0 -1,
parallel and nearly parallel axes, collinear axes, mimic and branch links), names, limits and
inertials against Pinocchio, and a clear error for each kind of bad URDF."""

import numpy as np
import pytest
from conftest import random_q
from urdf_helpers import REAL, TIAGO, TIAGO_CHAIN, TIAGO_JOINTS, pin_fk, real, substitute

from relcal import geometry as tf
from relcal.errors import RelcalError
from relcal.robot.export import calibrated_model
from relcal.robot.kinematics import fk, make_layout, pose_jacobian
from relcal.robot.loading import get_robot
from relcal.robot.model import auto_hayati
from relcal.robot.urdf import chain_fk, load_urdf


def rotation_error(a: np.ndarray, b: np.ndarray) -> float:
    """Largest rotation angle (rad) between matching rotations of ``(N, 4, 4)`` poses."""
    rel = np.swapaxes(a[:, :3, :3], -1, -2) @ b[:, :3, :3]
    return float(np.linalg.norm(tf.log_rotation(rel), axis=-1).max())


@pytest.mark.parametrize("name", list(REAL))
def test_fk_matches_pinocchio(name, rng):
    path, root, tip = real(name)
    model = load_urdf(path, root, tip)
    q = random_q(model, 30, rng, scale=1.0)
    ours = fk(model, q)
    theirs = pin_fk(path, model.urdf.root, model.urdf.tip, model.joint_names, q)
    assert np.abs(ours[:, :3, 3] - theirs[:, :3, 3]).max() < 1e-12
    assert rotation_error(ours, theirs) < 1e-12


def test_tiago_chain_names_limits_and_units():
    import pinocchio as pin

    model = load_urdf(TIAGO, *TIAGO_CHAIN)
    assert model.joint_names == TIAGO_JOINTS
    assert model.prismatic.tolist() == [True] + [False] * 7
    pm = pin.buildModelFromUrdf(str(TIAGO))
    for i, name in enumerate(model.joint_names):
        idx = pm.joints[pm.getJointId(name)].idx_q
        assert model.lower[i] == pm.lowerPositionLimit[idx]
        assert model.upper[i] == pm.upperPositionLimit[idx]
    # the torso slides in metres: 0.1 m of torso_lift_joint lifts the gripper by 0.1 m
    q0 = np.zeros((1, 8))
    q1 = q0.copy()
    q1[0, 0] = 0.1
    lift = fk(model, q1)[0, :3, 3] - fk(model, q0)[0, :3, 3]
    np.testing.assert_allclose(lift, [0, 0, 0.1], atol=1e-12)


def test_get_robot_gives_the_tiago_chain():
    model = get_robot(TIAGO, root=TIAGO_CHAIN[0], tip=TIAGO_CHAIN[1])
    assert model.joint_names == TIAGO_JOINTS
    assert model.urdf is not None and model.urdf.tip == TIAGO_CHAIN[1]


def test_parallel_axes_get_hayati_beta_and_auto_hayati_agrees():
    model = load_urdf(*real("ur5"))
    # UR: shoulder_lift, elbow and wrist_1 axes are parallel -> beta on elbow and wrist_1
    assert model.hayati.tolist() == [False, False, True, True, False, False]
    np.testing.assert_array_equal(auto_hayati(model).hayati, model.hayati)
    assert np.all(model.d[model.fixed_d()] == 0)


def test_identification_jacobian_matches_finite_differences(rng):
    model = load_urdf(*real("tiago_pro"))
    layout = make_layout(model)
    q = random_q(model, 5, rng)
    _, jac = pose_jacobian(model, q, layout)
    h = 1e-7
    for k in range(layout.size):
        step = np.zeros(layout.size)
        step[k] = h
        plus = fk(calibrated_model(model, layout, step), q)
        minus = fk(calibrated_model(model, layout, -step), q)
        dpos = (plus[:, :3, 3] - minus[:, :3, 3]) / (2 * h)
        drot = tf.log_rotation(plus[:, :3, :3] @ np.swapaxes(minus[:, :3, :3], -1, -2)) / (2 * h)
        np.testing.assert_allclose(jac[:, :3, k], dpos, atol=1e-6)
        np.testing.assert_allclose(jac[:, 3:, k], drot, atol=1e-6)


# --- hand-made URDFs -----------------------------------------------------------------------------


def joint(name, kind, parent, child, xyz="0 0 0", rpy="0 0 0", axis="0 0 1", extra=""):
    axis_tag = f'<axis xyz="{axis}"/>' if axis is not None else ""
    limit = '<limit lower="-2" upper="2" effort="1" velocity="1"/>' if kind != "fixed" else ""
    return (
        f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="{xyz}" rpy="{rpy}"/>{axis_tag}{limit}{extra}</joint>\n'
    )


def robot(body: str, links) -> str:
    tags = "".join(
        f'<link name="{name}"><inertial><origin xyz="0.01 0.02 0.03" rpy="0.1 0.2 0.3"/>'
        '<mass value="1.5"/><inertia ixx="0.01" ixy="0.001" ixz="0" iyy="0.02" iyz="0" izz="0.03"/>'
        "</inertial></link>\n"
        for name in links
    )
    return f'<?xml version="1.0"?>\n<robot name="test">\n{tags}{body}</robot>\n'


AWKWARD = robot(
    joint("mount", "fixed", "world", "base", "0.1 0.2 0.3", "0.3 -0.2 0.1")
    + joint("slide", "prismatic", "base", "l1", "0 0 0.2", "0 0 0", "0.6 0 0.8")
    + joint("j2", "revolute", "l1", "l2", "0.1 0 0.3", "0.2 0.1 0", "0 0 -1")
    + joint("j3", "continuous", "l2", "l3", "0.3 0.05 0", "0 0 0", "0 0 1")  # parallel to j2
    + joint("j4", "revolute", "l3", "l4", "0.25 0 0.01", "0.006 0.006 0", "0 0 1")  # 0.5 deg off
    + joint("j5", "revolute", "l4", "l5", "0 0 0.1", "0 0 0.7", "0 0 1")  # collinear with j4
    + joint("j6", "revolute", "l5", "l6", "0 0.1 0.1", "1.2 0 0", "0 1 0")
    + joint("flange", "fixed", "l6", "tip", "0 0 0.08", "0 0.5 0")
    + joint("finger", "prismatic", "l6", "f1", "0 0.02 0", axis="0 1 0")
    + joint(
        "finger2",
        "prismatic",
        "l6",
        "f2",
        "0 -0.02 0",
        axis="0 1 0",
        extra='<mimic joint="finger"/>',
    )
    + joint("sensor", "fixed", "l3", "cam", "0 0 0.05"),
    ["world", "base", "l1", "l2", "l3", "l4", "l5", "l6", "tip", "f1", "f2", "cam"],
)


def test_awkward_chain_matches_pinocchio(tmp_path, rng):
    path = tmp_path / "awkward.urdf"
    path.write_text(AWKWARD)
    model = load_urdf(path, tip="tip")
    assert model.joint_names == ("slide", "j2", "j3", "j4", "j5", "j6")
    assert model.hayati.tolist() == [False, False, True, True, True, False]
    assert abs(model.beta[3]) > 1e-3  # the nearly parallel pair needs a real beta
    q = random_q(model, 40, rng, scale=1.0)
    ours = fk(model, q)
    theirs = pin_fk(path, "world", "tip", model.joint_names, q)
    assert np.abs(ours[:, :3, 3] - theirs[:, :3, 3]).max() < 1e-12
    assert rotation_error(ours, theirs) < 1e-12
    np.testing.assert_allclose(chain_fk(model.urdf, q), ours, atol=1e-12)


def test_inertials_match_pinocchio(tmp_path):
    import pinocchio as pin

    for path, root, tip in [real("tiago_pro"), real("panda")]:
        model = load_urdf(path, root, tip)
        pm = pin.buildModelFromUrdf(str(path))
        for i, name in enumerate(model.joint_names):
            body = pm.inertias[pm.getJointId(name)]  # in the URDF joint frame
            frame = model.urdf.frames[i]  # URDF joint frame in relcal's joint frame
            rot = frame[:3, :3]
            assert model.inertials.mass[i] == pytest.approx(body.mass, rel=1e-12)
            np.testing.assert_allclose(
                model.inertials.com[i], frame[:3, :3] @ body.lever + frame[:3, 3], atol=1e-12
            )
            np.testing.assert_allclose(
                model.inertials.inertia[i], rot @ body.inertia @ rot.T, atol=1e-12
            )


def test_obvious_chain_found_without_root_and_tip(tmp_path):
    path = tmp_path / "awkward.urdf"
    path.write_text(AWKWARD)
    model = load_urdf(path)
    # the mimic finger is ignored; the other finger is the chain's end
    assert model.urdf.root == "world" and model.urdf.tip == "f1"
    assert model.joint_names[-1] == "finger"


# --- bad URDFs -----------------------------------------------------------------------------------


def load_bad(tmp_path, text, *patterns, root=None, tip="tip"):
    path = tmp_path / "bad.urdf"
    path.write_text(text)
    with pytest.raises(RelcalError) as err:
        load_urdf(path, root, tip)
    message = str(err.value)
    assert "bad.urdf" in message
    for pattern in patterns:
        assert pattern in message, message
    return message


def test_bad_missing_link(tmp_path):
    text = AWKWARD.replace('<child link="l3"/>', '<child link="l33"/>')
    load_bad(tmp_path, text, "line", "joint 'j3'", "child link 'l33' is not defined", "'l3'")


def test_bad_loop(tmp_path):
    text = AWKWARD.replace("</robot>", joint("back", "fixed", "l4", "l2") + "</robot>")
    load_bad(tmp_path, text, "link 'l2' is the child of two joints", "'j2'", "'back'", "tree")
    cycle = robot(
        joint("a", "fixed", "x", "y")
        + joint("b", "fixed", "y", "z")
        + joint("c", "fixed", "z", "x"),
        ["x", "y", "z"],
    )
    load_bad(tmp_path, cycle, "loop", "remove the joint")


@pytest.mark.parametrize("kind", ["floating", "planar"])
def test_bad_floating_or_planar_joint_in_chain(tmp_path, kind):
    text = AWKWARD.replace('name="mount" type="fixed"', f'name="mount" type="{kind}"')
    load_bad(tmp_path, text, f"joint 'mount' is of type '{kind}'", "root: base")


def test_bad_unknown_root_or_tip(tmp_path):
    load_bad(tmp_path, AWKWARD, "tip link 'tipp' is not in the file", "tip", tip="tipp")
    load_bad(tmp_path, AWKWARD, "root link 'wrold' is not in the file", "world", root="wrold")
    load_bad(tmp_path, AWKWARD, "tip link 'l2' is not below root link 'l4'", root="l4", tip="l2")


def test_bad_joint_without_axis(tmp_path):
    text = AWKWARD.replace('<axis xyz="0 0 -1"/>', "")
    load_bad(tmp_path, text, "joint 'j2' (revolute) has no <axis>", '<axis xyz="0 0 1"/>')
    zero = AWKWARD.replace('<axis xyz="0 0 -1"/>', '<axis xyz="0 0 0"/>')
    load_bad(tmp_path, zero, "joint 'j2'", "non-zero")


def test_bad_non_serial_tree_without_root_and_tip(tmp_path):
    branch = joint("other", "revolute", "l2", "arm2", axis="1 0 0")
    text = AWKWARD.replace('<link name="cam">', f'{branch}<link name="arm2"/><link name="cam">')
    load_bad(tmp_path, text, "not a serial chain below link 'l2'", "'j3'", "'other'", tip=None)
    load_bad(tmp_path, text, "--root/--tip", tip=None)
    msg = load_bad(tmp_path, TIAGO.read_text(), "not a serial chain", tip=None)
    assert "torso_fixed_joint" in msg


def test_bad_mimic_in_chain_xml_and_file(tmp_path):
    load_bad(tmp_path, AWKWARD, "joint 'finger2' mimics 'finger'", "tip: l6", tip="f2")
    load_bad(tmp_path, AWKWARD.replace("</robot>", "<robot>"), "line", "malformed XML")
    with pytest.raises(RelcalError, match="nope.urdf: file not found"):
        load_urdf(tmp_path / "nope.urdf")


# --- the origins parametrisation -----------------------------------------------------------------


def origins_model(name_or_text, tmp_path=None):
    if name_or_text in REAL:
        return load_urdf(*real(name_or_text), parametrisation="origins")
    path = tmp_path / "awkward.urdf"
    path.write_text(name_or_text)
    return load_urdf(path, tip="tip", parametrisation="origins")


def planted_origins(layout, rng, length: float, angle: float) -> np.ndarray:
    """Random errors of an origins layout: ``length`` (m) and ``angle`` (rad) standard deviations
    on the lengths and angles."""
    return rng.normal(0, 1, layout.size) * np.where(layout.is_angle(), angle, length)


def moved_origins(model, errors) -> dict:
    """The URDF origins that ``errors`` of ``make_layout(model)`` describe, straight from the
    file: ``origin from_vector(motion + zero * direction)``, the zero offset along the joint
    axis (a rotation, or a shift for a prismatic joint)."""
    per_joint = np.asarray(errors).reshape(model.n_joints, 7)
    out = {}
    for i, k in enumerate(model.urdf.movable):
        joint = model.urdf.joints[k]
        motion = per_joint[i, 1:].copy()
        start = 0 if joint.type == "prismatic" else 3
        motion[start : start + 3] += per_joint[i, 0] * joint.axis
        out[joint.name] = joint.origin @ tf.from_vector(motion)
    return out


@pytest.mark.parametrize("which", ["tiago_pro", "awkward"])
def test_origin_errors_move_the_urdf_origins_exactly(which, tmp_path, rng):
    """Planted origin errors and zero offsets give the FK of the URDF chain with those origins
    (``origin from_vector(motion)``, the zero offset added along the joint axis), computed
    straight from the joints; errors add up: moving by x, then by y, is moving by x + y."""
    model = origins_model(which if which in REAL else AWKWARD, tmp_path)
    layout = make_layout(model)
    assert layout.size == 7 * model.n_joints
    errors = planted_origins(layout, rng, 1e-2, np.radians(5))
    moved = calibrated_model(model, layout, errors)
    q = random_q(model, 20, rng)
    expected = chain_fk(model.urdf, q, moved_origins(model, errors))
    np.testing.assert_allclose(fk(moved, q), expected, atol=1e-12)
    more = planted_origins(layout, rng, 1e-2, np.radians(5))
    twice = calibrated_model(moved, layout, more)
    np.testing.assert_allclose(
        fk(twice, q), fk(calibrated_model(model, layout, errors + more), q), atol=1e-12
    )
    # at zero origin errors the zero offset is the joint offset itself
    zero = np.zeros(layout.size)
    zero[::7] = errors[::7]
    np.testing.assert_allclose(
        fk(calibrated_model(model, layout, zero), q),
        chain_fk(model.urdf, q + errors[::7]),
        atol=1e-12,
    )


@pytest.mark.parametrize("which", ["tiago_pro", "panda"])
def test_moved_origins_match_pinocchio(which, tmp_path, rng):
    """The moved model's FK is Pinocchio's on the URDF file with those origins written in."""
    nominal = origins_model(which)
    layout = make_layout(nominal)
    errors = planted_origins(layout, rng, 1e-2, np.radians(5))
    path = tmp_path / "moved.urdf"
    path.write_bytes(substitute(nominal.urdf.data, moved_origins(nominal, errors)))
    q = random_q(nominal, 20, rng, scale=1.0)
    ours = fk(calibrated_model(nominal, layout, errors), q)
    theirs = pin_fk(path, nominal.urdf.root, nominal.urdf.tip, nominal.joint_names, q)
    assert np.abs(ours[:, :3, 3] - theirs[:, :3, 3]).max() < 1e-12
    assert rotation_error(ours, theirs) < 1e-12


def numeric_pose_jacobian(nominal, layout, errors, q, h=1e-6):
    """Central differences ``(N, 6, P)`` of the tool pose at ``apply_errors(nominal, errors)``: the
    position change and the small rotation, base frame, as :func:`pose_jacobian` gives them."""
    out = np.zeros((len(q), 6, layout.size))
    for k in range(layout.size):
        step = np.zeros(layout.size)
        step[k] = h
        plus = fk(calibrated_model(nominal, layout, errors + step), q)
        minus = fk(calibrated_model(nominal, layout, errors - step), q)
        out[:, :3, k] = (plus[:, :3, 3] - minus[:, :3, 3]) / (2 * h)
        rel = plus[:, :3, :3] @ np.swapaxes(minus[:, :3, :3], -1, -2)
        out[:, 3:, k] = tf.log_rotation(rel) / (2 * h)
    return out


@pytest.mark.parametrize("which", ["tiago_pro", "awkward", "ur5", "panda", "kinova", "z1"])
def test_origins_jacobian_matches_finite_differences(which, tmp_path, rng):
    """The analytic Jacobian is the derivative of the tool pose with respect to the total errors
    from the URDF's own origins (what the solver moves), exactly at any error: central
    differences agree to 1e-7 relative at 0, 1 mm / 1 deg, 10 mm / 5 deg and 50 mm / 20 deg."""
    from relcal.robot.kinematics import spatial_jacobian

    nominal = origins_model(which if which in REAL else AWKWARD, tmp_path)
    layout = make_layout(nominal)
    q = random_q(nominal, 4, rng)
    for length, angle in [(0, 0), (1e-3, 1), (1e-2, 5), (5e-2, 20)]:
        errors = planted_origins(layout, rng, length, np.radians(angle))
        model = calibrated_model(nominal, layout, errors)
        tip, jac = pose_jacobian(model, q, layout)
        numeric = numeric_pose_jacobian(nominal, layout, errors, q)
        assert np.linalg.norm(jac - numeric) < 1e-7 * np.linalg.norm(numeric), (length, angle)
        # per column too: no column is right only on average
        scale = np.linalg.norm(numeric, axis=1).max()
        np.testing.assert_allclose(jac, numeric, rtol=0, atol=1e-7 * scale)
        # the same motions, velocity taken at the base origin instead of the tool point
        _, spatial = spatial_jacobian(model, q, layout)
        np.testing.assert_allclose(spatial[:, 3:], jac[:, 3:], atol=1e-15)
        np.testing.assert_allclose(
            spatial[:, :3], jac[:, :3] + tf.skew(tip[:, :3, 3]) @ jac[:, 3:], atol=1e-12
        )


def test_origins_jacobian_with_nongeometric_terms(rng):
    """Joint scale and harmonic values change the joint motion: the origin frames the Jacobian
    uses take the effective joint values out, so it stays exact with those terms present."""
    from dataclasses import replace

    nominal = load_urdf(*real("tiago_pro"), parametrisation="origins")
    terms = [("scale",) if p else ("scale", "harmonic") for p in nominal.prismatic]
    nominal = replace(nominal, nongeometric=tuple(terms))
    layout = make_layout(nominal)
    assert "scale" in layout.kinds and "harmonic_c" in layout.kinds
    errors = planted_origins(layout, rng, 1e-2, np.radians(5))
    other = ~np.isin(layout.kinds, ("origin", "theta_off", "d"))
    errors[other] = rng.normal(0, 2e-2, other.sum())
    q = random_q(nominal, 4, rng)
    _, jac = pose_jacobian(calibrated_model(nominal, layout, errors), q, layout)
    numeric = numeric_pose_jacobian(nominal, layout, errors, q)
    assert np.linalg.norm(jac - numeric) < 1e-7 * np.linalg.norm(numeric)


@pytest.mark.parametrize("name", ["tiago_pro", "ur5", "panda"])
def test_origins_and_minimal_identify_the_same_motions(name, rng):
    """Both parametrisations span the same space of tool motions (absolute poses, base and tool
    free): the origins one only adds redundant directions."""
    minimal = load_urdf(*real(name))
    origins = load_urdf(*real(name), parametrisation="origins")
    q = random_q(minimal, 40, rng)

    def rank(model):
        layout = make_layout(model, base=True, tool=True)
        _, jac = pose_jacobian(model, q, layout)
        stacked = jac.reshape(-1, layout.size)
        sv = np.linalg.svd(stacked / np.linalg.norm(stacked, axis=0), compute_uv=False)
        return int(np.sum(sv > 1e-9 * sv[0])), layout.size

    (r_min, p_min), (r_org, p_org) = rank(minimal), rank(origins)
    assert r_min == r_org and p_org > p_min
    # 4 per revolute joint, 2 per prismatic joint, 6 for the base (Everett's count)
    expected = 4 * int((~minimal.prismatic).sum()) + 2 * int(minimal.prismatic.sum()) + 6
    assert r_min == expected


def test_redundant_origin_parameters_are_named_as_such(rng):
    """A joint's zero offset and its origin's rotation about the joint axis are one motion: the
    identifiability analysis says so (at any pose), instead of blaming the chosen poses."""
    from helpers_sim import make_problem

    from relcal.calibration.identifiability import analyse_problem, explainer

    model = auto_hayati(load_urdf(*real("tiago_pro"), parametrisation="origins"))
    problem, _ = make_problem(model, "invariant", "pose", rng, n_poses=30)
    names = problem.full_layout.names
    explain = explainer(problem)

    def vector(**terms):
        v = np.zeros(len(names))
        for name, value in terms.items():
            v[names.index(name.replace("__", "."))] = value
        return v

    same = vector(arm_right_5_joint__zero=1.0, arm_right_5_joint__origin__rz=-1.0)
    assert "same motion described twice" in explain(same)
    other = vector(arm_right_5_joint__zero=1.0, arm_right_5_joint__origin__rx=-1.0)
    assert "at these poses" in explain(other)  # not a redundancy: blamed on the poses
    combos = analyse_problem(problem).combinations
    assert sum("same motion described twice" in c.reason for c in combos) >= 7
    assert not any("at these poses" in c.reason for c in combos)


def test_bad_numbers_and_missing_attributes(tmp_path):
    nan = AWKWARD.replace('xyz="0.1 0 0.3"', 'xyz="nan 0 0.3"')
    load_bad(tmp_path, nan, "joint 'j2'", "<origin xyz rpy> must be finite")
    swapped = AWKWARD.replace(
        '<limit lower="-2" upper="2" effort="1" velocity="1"/></joint>\n<joint name="j3"',
        '<limit lower="2" upper="-2" effort="1" velocity="1"/></joint>\n<joint name="j3"',
    )
    load_bad(tmp_path, swapped, "joint 'j2'", "lower 2.0 is above upper -2.0")
    load_bad(
        tmp_path, AWKWARD.replace('<parent link="l2"/>', "<parent/>"), "joint 'j3' needs <parent"
    )
    load_bad(tmp_path, AWKWARD.replace('<link name="cam">', "<link>"), "<link> without a name")


def test_mangled_urdfs_load_or_fail_clearly(tmp_path):
    """Random cuts, reversals and insertions in a valid URDF: a model or a RelcalError, never
    another exception, and never a model with non-finite numbers."""
    rng = np.random.default_rng(5)
    path = tmp_path / "mangled.urdf"
    for _ in range(300):
        text = AWKWARD
        for _ in range(rng.integers(1, 4)):
            i = int(rng.integers(0, len(text)))
            j = i + int(rng.integers(1, 20))
            choice = rng.integers(0, 4)
            if choice == 0:
                text = text[:i] + text[j:]
            elif choice == 1:
                text = text[:i] + text[i:j][::-1] + text[j:]
            elif choice == 2:
                text = text[:i] + str(rng.choice(list('<>"/= 0.-1axyzjoint'))) + text[i:]
            else:
                text = text[:i] + str(rng.choice(["nan", "inf", "1e308", "x", ""])) + text[j:]
        path.write_text(text)
        for tip in (None, "tip"):
            try:
                model = load_urdf(path, tip=tip)
            except RelcalError as exc:
                assert "mangled.urdf" in str(exc)
                continue
            arrays = (model.theta_off, model.d, model.a, model.alpha, model.beta, model.base)
            assert all(np.all(np.isfinite(v)) for v in (*arrays, model.tool))
            assert not np.isnan(model.lower).any() and not np.isnan(model.upper).any()


def test_xacro_files_are_refused_with_the_fix():
    with pytest.raises(
        RelcalError, match=r"expand it to a URDF first \(xacro arm.urdf.xacro > arm.urdf\)"
    ):
        get_robot("robots/arm.urdf.xacro")


def random_chain(rng) -> str:
    """A random serial URDF: origins with random rotations, or the degenerate cases (axes
    parallel, antiparallel, collinear, intersecting, nearly parallel), random joint types."""
    n = int(rng.integers(1, 8))
    body, links = "", ["l0"]
    for i in range(n):
        case = rng.integers(0, 6)
        xyz = rng.normal(0, 0.2, 3)
        rpy = rng.uniform(-np.pi, np.pi, 3)
        if case == 1:  # parallel to the previous axis (z), offset
            rpy = [0, 0, rpy[2]]
        elif case == 2:  # antiparallel
            rpy = [np.pi, 0, rpy[2]]
        elif case == 3:  # collinear
            xyz, rpy = [0, 0, xyz[2]], [0, 0, rpy[2]]
        elif case == 4:  # intersecting at the origin, perpendicular
            xyz, rpy = [0, 0, 0], [np.pi / 2, 0, rpy[2]]
        elif case == 5:  # nearly parallel
            rpy = [rng.normal(0, 0.01), rng.normal(0, 0.01), rpy[2]]
        kind = str(rng.choice(["revolute", "continuous", "prismatic"], p=[0.6, 0.2, 0.2]))
        body += joint(
            f"j{i + 1}",
            kind,
            f"l{i}",
            f"l{i + 1}",
            " ".join(repr(float(v)) for v in xyz),
            " ".join(repr(float(v)) for v in rpy),
            "0 0 1" if rng.random() < 0.7 else " ".join(repr(float(v)) for v in rng.normal(size=3)),
        )
        links.append(f"l{i + 1}")
    body += joint("flange", "fixed", f"l{n}", "tip", "0.01 0.02 0.1", "0.1 0.2 0.3")
    return robot(body, [*links, "tip"])


def test_random_chains_match_pinocchio(tmp_path, rng):
    path = tmp_path / "random.urdf"
    for _ in range(60):
        path.write_text(random_chain(rng))
        model = load_urdf(path)
        q = random_q(model, 10, rng, scale=1.0)
        ours = fk(model, q)
        theirs = pin_fk(path, "l0", "tip", model.joint_names, q)
        assert np.abs(ours[:, :3, 3] - theirs[:, :3, 3]).max() < 1e-12
        assert rotation_error(ours, theirs) < 1e-12


def test_panda_converts_to_frankas_published_modified_dh():
    """Franka's documented modified-DH table (a, d, alpha up to the sign choice of each x axis;
    relcal keeps a >= 0) comes out of the Panda URDF."""
    model = load_urdf(*real("panda"))
    np.testing.assert_allclose(np.abs(model.a), [0, 0, 0, 0.0825, 0.0825, 0, 0.088], atol=1e-12)
    np.testing.assert_allclose(model.d, [0.333, 0, 0.316, 0, 0.384, 0, 0], atol=1e-12)
    np.testing.assert_allclose(
        np.abs(np.degrees(model.alpha)), [0, 90, 90, 90, 90, 90, 90], atol=1e-9
    )
    assert not model.hayati.any() and np.all(model.beta == 0)
    # the flange (panda_joint8): 0.107 m along joint 7's axis
    np.testing.assert_allclose(model.tool[:3, 3], [0, 0, 0.107], atol=1e-12)


def test_origin_corrections_are_judged_in_their_units():
    from relcal.calibration.plausibility import check_corrections

    with pytest.raises(RelcalError, match=r"j1.origin.x corrected by \+200 mm"):
        check_corrections(["j1.origin.x"], ["origin"], np.array([0.2]), "here")
    with pytest.raises(RelcalError, match=r"j1.origin.rz corrected by \+57.3 deg"):
        check_corrections(["j1.origin.rz"], ["origin"], np.array([1.0]), "here")
    check_corrections(["j1.origin.x", "j1.origin.ry"], ["origin"] * 2, np.array([1e-3, 1e-3]), "h")
