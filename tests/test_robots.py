"""The built-in robot library: every file loads, and its forward kinematics match hand algebra."""

import numpy as np
import pytest

from relcal.robot.ik import closed_form_problem, has_spherical_wrist
from relcal.robot.kinematics import fk, forward_frames
from relcal.robot.loading import get_robot
from relcal.robot.model import library_names

LIBRARY = ["a465", "puma560", "ur5e", "ur10", "franka_fr3", "irb120"]
DEG = np.pi / 180


def dh(theta, d, a, alpha):
    """Standard DH link Rz(theta) Tz(d) Tx(a) Rx(alpha), written out (independent of fk)."""
    ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
    return np.array(
        [
            [ct, -st * ca, st * sa, a * ct],
            [st, ct * ca, -ct * sa, a * st],
            [0.0, sa, ca, d],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def puma_by_hand(q):
    """Product of the PUMA 560 link transforms with the toolbox's numbers typed in again."""
    d = [26.45 * 0.0254, 0, 0.15005, 0.4318, 0, 0]  # d1 = 26.45 in, as in the toolbox
    a = [0, 0.4318, 0.0203, 0, 0, 0]
    alpha = np.array([90, 0, -90, 90, -90, 0]) * DEG
    out = np.eye(4)
    for i in range(6):
        out = out @ dh(q[i], d[i], a[i], alpha[i])
    return out


@pytest.mark.parametrize("name", LIBRARY)
def test_library_robot_loads(name):
    assert name in library_names()
    model = get_robot(name)
    assert model.source.strip(), "every library robot cites where its numbers come from"
    assert model.n_joints == (7 if name == "franka_fr3" else 6)
    assert np.all(np.isfinite(model.lower)) and np.all(model.lower < model.upper)
    assert not model.prismatic.any()
    assert np.isfinite(fk(model, np.zeros((1, model.n_joints)))).all()


# PUMA 560, worked by hand (rtb.models.DH.Puma560, pedestal included):
# qz = 0: all Rz = I, the twists cancel (90 - 90 + 90 - 90) so R = I; the offsets add up to
#   x = a2 + a3 = 0.4521, y = -d3 = -0.15005 (z1 points along -y0), z = d1 + d4 = 1.10363.
# qr = (0, 90, -90, 0, 0, 0) deg, arm up: the upper arm points up (z += a2), joint 3 undoes joint 2,
#   so R = I, x = a3 = 0.0203, y = -d3, z = d1 + a2 + d4 = 1.53543.
# q = (90, 0, 0, 0, 90, 0) deg: the 'L' pose turned to face +y, then the wrist bent 90 deg about
#   axis 5 (= +x0): x = d3 = 0.15005, y = a2 + a3 = 0.4521, z = 1.10363; tool x (was +y) -> +z,
#   tool y (was -x) stays -x, tool z (was +z) -> -y.
PUMA_HAND = [
    ([0, 0, 0, 0, 0, 0], np.eye(3), [0.4521, -0.15005, 0.67183 + 0.4318]),
    ([0, 90, -90, 0, 0, 0], np.eye(3), [0.0203, -0.15005, 0.67183 + 0.4318 + 0.4318]),
    (
        [90, 0, 0, 0, 90, 0],
        [[0, -1, 0], [0, 0, -1], [1, 0, 0]],
        [0.15005, 0.4521, 0.67183 + 0.4318],
    ),
]


@pytest.mark.parametrize(("q_deg", "rot", "pos"), PUMA_HAND)
def test_puma560_fk_matches_hand_computation(q_deg, rot, pos):
    q = np.array(q_deg, dtype=float) * DEG
    expected = np.eye(4)
    expected[:3, :3], expected[:3, 3] = rot, pos
    np.testing.assert_allclose(puma_by_hand(q), expected, atol=1e-12)
    np.testing.assert_allclose(fk(get_robot("puma560"), q[None])[0], expected, atol=1e-12)


def test_puma560_fk_matches_written_out_dh_product(rng):
    q = rng.uniform(-np.pi, np.pi, (5, 6))
    ours = fk(get_robot("puma560"), q)
    for qi, pose in zip(q, ours, strict=True):
        np.testing.assert_allclose(pose, puma_by_hand(qi), atol=1e-12)


def test_ur5e_zero_pose():
    # All Rz = I: R = Rx(90 + 0 + 0 + 90 - 90 + 0) = Rx(90);
    # x = a2 + a3, y = -(d4 + d6), z = d1 - d5.
    pose = fk(get_robot("ur5e"), np.zeros((1, 6)))[0]
    np.testing.assert_allclose(pose[:3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)
    np.testing.assert_allclose(pose[:3, 3], [-0.8172, -0.2329, 0.0628], atol=1e-12)


def test_ur10_zero_pose_and_a_bent_elbow():
    # Classic UR10 (CB3) at zero, as the UR5e: R = Rx(90), x = a2 + a3 = -1.1843,
    # y = -(d4 + d6) = -0.256141, z = d1 - d5 = 0.0116.
    model = get_robot("ur10")
    pose = fk(model, np.zeros((1, 6)))[0]
    np.testing.assert_allclose(pose[:3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)
    np.testing.assert_allclose(pose[:3, 3], [-1.1843, -0.256141, 0.0116], atol=1e-12)
    # Any configuration: the written-out DH product with the table typed in again.
    q = np.array([0.3, -1.1, 1.57, -0.4, 0.8, 2.0])
    d = [0.1273, 0, 0, 0.163941, 0.1157, 0.0922]
    a = [0, -0.612, -0.5723, 0, 0, 0]
    alpha = np.array([90, 0, 0, 90, -90, 0]) * DEG
    by_hand = np.eye(4)
    for i in range(6):
        by_hand = by_hand @ dh(q[i], d[i], a[i], alpha[i])
    np.testing.assert_allclose(fk(model, q[None])[0], by_hand, atol=1e-12)
    assert np.degrees(model.upper[2]) == 180 and np.degrees(model.upper[0]) == 360


def test_franka_fr3_zero_pose():
    # Modified DH at q = 0: R = Rx(sum of twists) = Rx(180); x = 0.0825 - 0.0825 + 0.088,
    # z = 0.333 + 0.316 + 0.384 - 0.107 (the flange points down).
    pose = fk(get_robot("franka_fr3"), np.zeros((1, 7)))[0]
    np.testing.assert_allclose(pose[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    np.testing.assert_allclose(pose[:3, 3], [0.088, 0.0, 0.926], atol=1e-12)


def test_irb120_zero_is_abb_calibration_position():
    model = get_robot("irb120")
    frames = forward_frames(model, np.zeros((1, 6)))[0]
    # Upper arm vertical, forearm horizontal: wrist centre at x = 0.302, z = 0.29 + 0.27 + 0.07.
    np.testing.assert_allclose(frames[4, :3, 3], [0.302, 0.0, 0.63], atol=1e-12)
    pose = fk(model, np.zeros((1, 6)))[0]
    # ABB tool0 at zero: z along +x (flange normal), x pointing down.
    np.testing.assert_allclose(pose[:3, :3], [[0, 0, 1], [0, 1, 0], [-1, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(pose[:3, 3], [0.374, 0.0, 0.63], atol=1e-12)


def test_irb120_axes_turn_as_abb_defines_them():
    model = get_robot("irb120")
    zero = fk(model, np.zeros((1, 6)))[0, :3, 3]
    forward = fk(model, np.array([[0, 0.1, 0, 0, 0, 0]]))[0, :3, 3]
    down = fk(model, np.array([[0, 0, 0.1, 0, 0, 0]]))[0, :3, 3]
    left = fk(model, np.array([[0.1, 0, 0, 0, 0, 0]]))[0, :3, 3]
    assert forward[0] > zero[0] + 0.01  # axis 2 positive tilts the arm forward
    assert down[2] < zero[2] - 0.01  # axis 3 positive lowers the forearm
    assert left[1] > zero[1] + 0.01  # axis 1 positive turns counter-clockwise seen from above


@pytest.mark.parametrize("name", LIBRARY)
def test_closed_form_availability(name):
    model = get_robot(name)
    spherical = name in ("a465", "puma560", "irb120")
    assert has_spherical_wrist(model) == spherical
    assert (closed_form_problem(model) is None) == spherical
