"""Robot model YAML: round trip, validation messages naming file, line and field."""

import numpy as np
import pytest

from relcal.errors import RelcalError
from relcal.robot.kinematics import fk
from relcal.robot.loading import get_robot
from relcal.robot.model import auto_hayati, dump_model, library_names, load_model

GOOD = """\
name: test arm
convention: dh
joints:
  - {theta_off: 0, d: 0.33, a: 0, alpha: 90, limits: [-170, 170]}
  - {theta_off: 0, d: 0, a: 0.3, alpha: 0}
  - {theta_off: 0, d: 0, a: 0, alpha: 90}
"""


def write(tmp_path, text):
    path = tmp_path / "robot.yaml"
    path.write_text(text)
    return path


def test_round_trip_preserves_kinematics(tmp_path, rng):
    for name in library_names():
        model = get_robot(name)
        again = load_model(write(tmp_path, dump_model(model)))
        q = rng.uniform(-1, 1, (5, model.n_joints))
        np.testing.assert_allclose(fk(again, q), fk(model, q), atol=1e-12)
        np.testing.assert_allclose(again.lower, model.lower)


def test_degrees_are_converted(tmp_path):
    model = load_model(write(tmp_path, GOOD))
    assert model.alpha[0] == pytest.approx(np.pi / 2)
    assert model.lower[0] == pytest.approx(np.radians(-170))
    assert model.joint_names == ("joint1", "joint2", "joint3")


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            ("alpha: 0}", "alpha: abc}"),
            r"line 5: joints\[1\]\.alpha: expected a number, got the text 'abc'",
        ),
        (("alpha: 0}", "alpha: .inf}"), r"line 5: joints\[1\]\.alpha: Input should be a finite"),
        (
            ("convention: dh", "convention: xx"),
            r"line 2: convention: Input should be 'dh' or 'mdh'",
        ),
        (("[-170, 170]", "[170, -170]"), r"line 4: joints\[0\]: limits must be"),
        (("d: 0.33,", "d: 0.33, bogus: 1,"), r"joints\[0\]\.bogus: Extra inputs are not permitted"),
        (("name: test arm\n", ""), r"name: Field required"),
        (("joints:", "joints: ["), r"line \d+: malformed YAML"),
    ],
)
def test_validation_names_file_line_and_field(tmp_path, edit, message):
    path = write(tmp_path, GOOD.replace(*edit))
    with pytest.raises(RelcalError, match=message) as info:
        load_model(path)
    assert str(path) in str(info.value)


def test_missing_file_and_unknown_robot(tmp_path):
    with pytest.raises(RelcalError, match="file not found"):
        load_model(tmp_path / "nope.yaml")
    with pytest.raises(RelcalError, match="unknown robot 'kuka'"):
        get_robot("kuka")


def test_auto_hayati_finds_the_a465_parallel_pair():
    model = auto_hayati(get_robot("a465"))
    assert model.hayati.tolist() == [False, True, False, False, False, False]
    assert model.fixed_d().tolist() == [False, True, False, False, False, False]
