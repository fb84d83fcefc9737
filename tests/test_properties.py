"""Property tests (Hypothesis): FK, IK and Jacobian invariants on random chains, and loaders that
answer any text with a result or a clear RelcalError, never another exception."""

from dataclasses import replace

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from relcal import geometry as tf
from relcal.errors import RelcalError
from relcal.robot.ik import solve
from relcal.robot.kinematics import apply_errors, fk, make_layout, pose_jacobian
from relcal.robot.loading import get_robot
from relcal.robot.model import load_model

FAST = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
angles = st.floats(-np.pi, np.pi, allow_nan=False)
lengths = st.floats(-0.5, 0.5, allow_nan=False)


@st.composite
def chains(draw):
    """Random 3..7-joint chains in either convention, with random base and tool."""
    n = draw(st.integers(3, 7))
    convention = draw(st.sampled_from(["dh", "mdh"]))
    model = get_robot("franka_fr3" if convention == "mdh" else "a465")
    vec = arrays(float, n, elements=lengths)
    ang = arrays(float, n, elements=angles)
    six = arrays(float, 6, elements=st.floats(-1, 1))
    return replace(
        model,
        convention=convention,
        theta_off=draw(ang),
        d=draw(vec),
        a=draw(vec),
        alpha=draw(ang),
        beta=np.zeros(n),
        prismatic=np.zeros(n, bool),
        hayati=np.zeros(n, bool),
        lower=np.full(n, -np.pi),
        upper=np.full(n, np.pi),
        joint_names=tuple(f"j{i}" for i in range(n)),
        base=tf.from_vector(draw(six)),
        tool=tf.from_vector(draw(six)),
    )


@FAST
@given(chains(), st.integers(0, 2**31))
def test_fk_is_a_rigid_transform_and_base_tool_compose(model, seed):
    q = np.random.default_rng(seed).uniform(-np.pi, np.pi, (5, model.n_joints))
    poses = fk(model, q)
    rot = poses[:, :3, :3]
    np.testing.assert_allclose(
        rot @ np.swapaxes(rot, 1, 2), np.broadcast_to(np.eye(3), rot.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-12)
    bare = fk(replace(model, base=np.eye(4), tool=np.eye(4)), q)
    np.testing.assert_allclose(poses, model.base @ bare @ model.tool, atol=1e-12)


@FAST
@given(chains(), st.integers(0, 2**31))
def test_jacobian_predicts_small_parameter_changes(model, seed):
    rng = np.random.default_rng(seed)
    layout = make_layout(model, base=True, tool=True)
    q = rng.uniform(-np.pi, np.pi, (4, model.n_joints))
    pose, jac = pose_jacobian(model, q, layout)
    step = rng.normal(0, 1e-6, layout.size)
    moved = fk(apply_errors(model, layout, step), q)
    predicted = jac @ step
    np.testing.assert_allclose(moved[:, :3, 3] - pose[:, :3, 3], predicted[:, :3], atol=1e-10)


@FAST
@given(st.integers(0, 2**31))
def test_ik_round_trip_on_the_a465(seed):
    model = get_robot("a465")
    rng = np.random.default_rng(seed)
    q = rng.uniform(model.lower * 0.9, model.upper * 0.9, (3, 6))
    targets = fk(model, q)
    sol = solve(model, targets)
    assert np.all(sol.converged)
    np.testing.assert_allclose(fk(model, sol.q), targets, atol=1e-9)


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(st.text(max_size=200))
def test_model_loader_never_crashes(tmp_path, text):
    path = tmp_path / "robot.yaml"
    path.write_text(text)
    try:
        load_model(path)
    except RelcalError as exc:
        assert str(path) in str(exc)


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    st.lists(
        st.lists(
            st.sampled_from(["1", "-2.5", "nan", "x", "", "1e9", "0"]), min_size=1, max_size=16
        ),
        max_size=6,
    )
)
def test_samples_loader_never_crashes(tmp_path, rows):
    from relcal.data.dataset import load_dataset

    (tmp_path / "dataset.yaml").write_text("robot: a465\nhandeye: {xyz: [0, 0, 0.1]}\n")
    header = "id,q1,q2,q3,q4,q5,q6,x,y,z,qx,qy,qz,qw"
    (tmp_path / "samples.csv").write_text("\n".join([header, *[",".join(r) for r in rows]]) + "\n")
    try:
        load_dataset(tmp_path)
    except RelcalError as exc:
        assert "samples.csv" in str(exc) or "dataset.yaml" in str(exc)
