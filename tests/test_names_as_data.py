"""Names from files are data everywhere: a URDF whose joint names hold ``'``, ``&``, ``<``,
``"`` (written as entities, valid XML) and a Unicode bidirectional override is calibrated end to
end; its calibrated URDF is found and rewritten through the XML parser (the origins land on the
right joints, checked by forward kinematics of the file read back), and the HTML report shows
the override as a visible escape, never raw (a name that displays reversed)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import random_q
from urdf_helpers import UR5E_KINEMATICS, ur_description_urdf

import relcal
from relcal import geometry as tf
from relcal.errors import RelcalError
from relcal.outputset import tracking
from relcal.reporting import htmlkit
from relcal.robot.export import _replace_origins, calibrated_model, calibrated_urdf
from relcal.robot.kinematics import fk, make_layout
from relcal.robot.urdf import load_urdf

RLO = "\u202e"  # RIGHT-TO-LEFT OVERRIDE
# (name in ur_description, the name as the parser reads it, as written in the file)
RENAMED = [
    ("shoulder_pan_joint", "j1's", "j1&apos;s"),
    ("shoulder_lift_joint", "j2&apos;s", "j2&amp;apos;s"),  # the issue's spelling, read literally
    ("elbow_joint", "a&b<c>", "a&amp;b&lt;c&gt;"),
    ("wrist_1_joint", 'w"1', "w&quot;1"),
    ("wrist_2_joint", f"wrist_2{RLO}tnioj", f"wrist_2{RLO}tnioj"),
    ("wrist_3_joint", "w3", "w3"),
]


@pytest.fixture(scope="module")
def odd(tmp_path_factory):
    """The UR5e skeleton with those joint names, and the file."""
    text = ur_description_urdf(UR5E_KINEMATICS)
    for old, _, written in RENAMED:
        text = text.replace(f'name="{old}"', f'name="{written}"')
    path = tmp_path_factory.mktemp("odd") / "odd.urdf"
    path.write_text(text, encoding="utf-8")
    return path


def test_the_parser_reads_the_names_and_the_export_rewrites_their_origins(odd, tmp_path):
    model = load_urdf(odd, "base_link", "tool0")
    assert model.joint_names == tuple(name for _, name, _ in RENAMED)
    rng = np.random.default_rng(3)
    layout = make_layout(model)
    calibrated = calibrated_model(model, layout, rng.normal(0, 1e-3, layout.size))
    out = calibrated_urdf(calibrated)
    path = tmp_path / "calibrated.urdf"
    path.write_bytes(out)
    back = load_urdf(path, "base_link", "tool0")
    assert back.joint_names == model.joint_names
    q = random_q(model, 12, rng)
    np.testing.assert_allclose(fk(back, q), fk(calibrated, q), atol=1e-12)
    # only origin tags changed: the entities in the names are written as they were
    for _, _, written in RENAMED:
        assert f'name="{written}"'.encode() in out


def test_a_name_inside_a_comment_or_another_attribute_is_never_taken_for_the_joint():
    data = (
        b'<?xml version="1.0"?>\n<robot name="r">\n'
        b'<!-- <joint name="j1" type="revolute"><origin xyz="9 9 9"/></joint> -->\n'
        b'<link name="a"/><link name="b"/>\n'
        b'<transmission name="t"><joint name="j1"><origin xyz="8 8 8"/></joint></transmission>\n'
        b'<joint name="j1" type=\'revolute\'><parent link="a"/><child link="b"/>'
        b'<origin note=\' xyz="7 7 7"\' xyz="0 0 1" rpy="0 0 0"/><axis xyz="0 0 1"/></joint>\n'
        b"</robot>\n"
    )
    out = _replace_origins("r.urdf", data, {"j1": tf.from_xyz_rpy([1.0, 2.0, 3.0], [0, 0, 0])})
    assert out.replace(b'xyz="1.0 2.0 3.0" rpy="0.0 0.0 0.0"', b'xyz="0 0 1" rpy="0 0 0"') == data
    with pytest.raises(RelcalError, match="found 0 <joint> elements named 'j9'"):
        _replace_origins("r.urdf", data, {"j9": np.eye(4)})


def test_html_escapes_markup_and_shows_bidirectional_controls_as_escapes():
    text = htmlkit.escape(f"<b>{RLO}x&y</b>\x1b[31m")
    assert RLO not in text and "\x1b" not in text
    assert text == "&lt;b&gt;\\u202ex&amp;y&lt;/b&gt;\\x1b[31m"
    assert htmlkit.escape(htmlkit.Html("<b>ok</b>")) == "<b>ok</b>"


def test_a_calibration_of_that_robot_runs_end_to_end_and_its_report_is_safe(odd, tmp_path):
    model = load_urdf(odd, "base_link", "tool0")
    rng = np.random.default_rng(4)
    layout = make_layout(model)
    truth = calibrated_model(model, layout, rng.normal(0, 5e-4, layout.size))
    q = random_q(model, 40, rng)
    handeye = tf.from_xyz_rpy([0.0, 0.04, 0.06], [0.0, 0.0, 0.0])
    poses = tf.from_xyz_rpy([0.6, 0.1, 0.0], [np.pi, 0, 0]) @ fk(truth, q) @ handeye
    with tracking():
        dataset = relcal.Dataset.from_arrays(model, q, poses, handeye=handeye)
        cal = relcal.calibrate(dataset, nongeometric="none")
        files = relcal.write_calibration(
            cal, tmp_path / "cal", report_path=tmp_path / "report.html"
        )
    names = {p.name for p in files}
    assert "robot.urdf" in names and "report.html" in names
    html = (tmp_path / "report.html").read_text(encoding="utf-8")
    assert RLO not in html and "\\u202e" in html
    urdf = load_urdf(tmp_path / "cal" / "robot.urdf", "base_link", "tool0")
    assert urdf.joint_names == model.joint_names
    np.testing.assert_allclose(fk(urdf, q[:5])[:, :3, 3], fk(cal.model, q[:5])[:, :3, 3], atol=1e-6)
