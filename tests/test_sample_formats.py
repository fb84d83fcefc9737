"""Sample tables of motion-capture and tracker data: roll-pitch-yaw poses, positions alone, joint
columns by name, column mappings; and position-only datasets calibrated end to end."""

import numpy as np
import pytest
from conftest import DATA, random_q
from helpers_sim import true_errors

from relcal import geometry as tf
from relcal.calibration.measurement import tracker_frames
from relcal.calibration.pipeline import calibrate
from relcal.cli import main
from relcal.data.dataset import load_dataset, read_sample_table
from relcal.data.imaging import measure
from relcal.errors import RelcalError
from relcal.reporting.documents import validation_document
from relcal.robot.kinematics import apply_errors, fk, make_layout
from relcal.robot.loading import get_robot
from relcal.robot.model import KINDS, auto_hayati, model_from_dict

INSTRUMENT = tf.from_vector(np.array([1.1, -0.3, 0.2, 0.05, -0.1, 2.0]))  # tracker from base
MARKER = np.array([0.02, -0.01, 0.11])  # flange frame, m


def _write(root, yaml_text, header, rows, newline="\n"):
    root.mkdir(parents=True, exist_ok=True)
    (root / "dataset.yaml").write_text(yaml_text)
    lines = [",".join(header)] + [",".join(f"{v:.17g}" for v in row) for row in rows]
    (root / "samples.csv").write_bytes((newline.join(lines) + newline).encode())
    return root


def _rpy(rot: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw with R = Rz(yaw) Ry(pitch) Rx(roll), computed by hand (not via the
    library the reader uses)."""
    pitch = np.arcsin(-rot[..., 2, 0])
    roll = np.arctan2(rot[..., 2, 1], rot[..., 2, 2])
    yaw = np.arctan2(rot[..., 1, 0], rot[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


def _rz_ry_rx(rpy):
    return tf.rot_z(rpy[2]) @ tf.rot_y(rpy[1]) @ tf.rot_x(rpy[0])


@pytest.mark.parametrize("unit", ["rad", "deg"])
def test_roll_pitch_yaw_named_joints_no_id_crlf(tmp_path, unit, rng):
    model = get_robot("franka_fr3")
    q = random_q(model, 6, rng)
    poses = fk(model, q)
    rpy = _rpy(poses[:, :3, :3])
    angles = np.degrees(rpy) if unit == "deg" else rpy
    order = [3, 0, 6, 1, 2, 5, 4]  # joint columns in another order than the model's
    header = ["x", "y", "z", "roll", "pitch", "yaw", *[model.joint_names[i] for i in order]]
    rows = np.column_stack([poses[:, :3, 3], angles, q[:, order]])
    spec = f"robot: franka_fr3\njoint_unit: rad\npose_angle_unit: {unit}\n"
    root = _write(tmp_path / "d", spec, header, rows, newline="\r\n")
    ds = load_dataset(root)
    assert ds.measured == "pose"
    assert ds.ids == tuple(str(k + 1) for k in range(6))  # row numbers
    np.testing.assert_allclose(ds.q, q, atol=1e-12)
    np.testing.assert_allclose(ds.poses, poses, atol=1e-12)
    for k in range(2):
        np.testing.assert_allclose(ds.poses[k, :3, :3], _rz_ry_rx(rpy[k]), atol=1e-12)


def test_column_mapping_and_positions(tmp_path, rng):
    model = get_robot("franka_fr3")
    q = random_q(model, 5, rng)
    p = fk(model, q)[:, :3, 3]
    header = ["px", "py", "pz", *[f"J{i}" for i in range(1, 8)]]
    mapping = ", ".join([f"{a}: p{a}" for a in "xyz"] + [f"q{i}: J{i}" for i in range(1, 8)])
    spec = f"robot: franka_fr3\njoint_unit: rad\ncolumns: {{{mapping}}}\n"
    ds = load_dataset(_write(tmp_path / "d", spec, header, np.column_stack([p, q])))
    assert ds.measured == "position"
    np.testing.assert_allclose(ds.poses[:, :3, 3], p, atol=1e-15)
    np.testing.assert_allclose(ds.q, q, atol=1e-15)


@pytest.mark.parametrize(
    "header, extra, message",
    [
        (["x", "y", "z", "roll", "j"], "", "exactly one of these"),  # orientation incomplete
        (["x", "y", "z", "joint1", "joint2"], "", "missing joint3"),
        (["x", "y"], "", "expected joint columns q1"),
        (["x", "y", "z"], "columns: {x: x1}\n", "maps to 'x1', which the header lacks"),
        (["x", "x", "y", "z"], "", "appear twice"),
        (["x", "y", "z"], "columns: {rol: phix1}\n", r"unknown column name\(s\) rol"),
    ],
)
def test_bad_headers(tmp_path, header, extra, message):
    model = get_robot("franka_fr3")
    names = [] if any(h.startswith("joint") for h in header) else list(model.joint_names)
    if header == ["x", "y"]:
        names = ["q1"]
    full = header + names
    rows = np.zeros((3, len(full)))
    root = _write(tmp_path / "d", "robot: franka_fr3\njoint_unit: rad\n" + extra, full, rows)
    with pytest.raises(RelcalError, match=message):
        load_dataset(root)


@pytest.mark.skipif(not (DATA / "tiago_pro").is_dir(), reason="real data not available")
def test_real_tiago_files_read_by_joint_name():
    """The real TIAGo Pro tables (CRLF, no id, x1.. columns, joints by name) parse with a column
    mapping; an 8-joint stand-in model carries the joint names (the geometry does not matter)."""
    names = ["torso_lift_joint", *[f"arm_right_{i}_joint" for i in range(1, 8)]]
    model = model_from_dict(
        {
            "name": "tiago names",
            "convention": "dh",
            "joints": [
                {"name": n, "type": "prismatic" if k == 0 else "revolute"}
                for k, n in enumerate(names)
            ],
        }
    )
    mapping = {"x": "x1", "y": "y1", "z": "z1", "roll": "phix1", "pitch": "phiy1", "yaw": "phiz1"}
    folder = DATA / "tiago_pro"
    pose = read_sample_table(folder / "mocap_pose_20260805.csv", model, "rad", "rad", mapping)
    assert pose.measured == "pose" and pose.q.shape == (48, 8)
    first = [
        -0.21655575126365742, -0.9721404075091389, 1.1454023792604302,
        0.6505150868020597, -0.09955438663215155, -0.7787359766210464,
    ]  # fmt: skip
    np.testing.assert_allclose(pose.poses[0, :3, 3], first[:3], atol=0)
    np.testing.assert_allclose(pose.poses[0, :3, :3], _rz_ry_rx(first[3:]), atol=1e-12)
    assert pose.q[0, 0] == 0.16277711080190466  # torso in m
    points = read_sample_table(
        folder / "mocap_position_20260702.csv",
        model,
        "rad",
        "rad",
        {"x": "x1", "y": "y1", "z": "z1"},
    )
    assert points.measured == "position" and points.q.shape == (94, 8)


# --- position-only data calibrated end to end ----------------------------------------------------


def _point_dataset(root, n, noise, rng, seed_model="franka_fr3", planted=True):
    model = auto_hayati(get_robot(seed_model))
    layout = make_layout(model)
    truth = true_errors(layout, rng) * planted
    q = random_q(model, n, rng, scale=0.8)
    flange = fk(apply_errors(model, layout, truth), q)
    p = (flange[:, :3, :3] @ MARKER + flange[:, :3, 3]) @ INSTRUMENT[:3, :3].T + INSTRUMENT[:3, 3]
    p = p + rng.normal(0, noise, p.shape) if noise else p
    names = list(model.joint_names)
    header = ["id", "x", "y", "z", *names]
    rows = [[k, *p[k], *q[k]] for k in range(n)]
    root.mkdir(parents=True, exist_ok=True)
    (root / "dataset.yaml").write_text(f"robot: {seed_model}\njoint_unit: rad\n")
    lines = [",".join(header)] + [",".join(f"{v:.17g}" for v in row) for row in rows]
    (root / "samples.csv").write_text("\n".join(lines) + "\n")
    return truth


def test_points_calibrate_without_noise(tmp_path, rng):
    truth = _point_dataset(tmp_path / "d", 60, 0.0, rng)
    ds = load_dataset(tmp_path / "d")
    cal = calibrate(
        ds, measure(ds, progress=False), holdout=0.25, loss="linear", nongeometric="none"
    )
    assert cal.problem.formulation == "tracker" and cal.result.converged
    n_geo = cal.problem.layout.size
    ok = cal.result.identifiable[:n_geo]
    assert ok.sum() == n_geo - 6  # base-like (4) and marker-like (2) combinations left out
    np.testing.assert_allclose(cal.result.params[:n_geo][ok], truth[ok], atol=1e-8)
    after = validation_document(cal.validation)["calibrated"]["position_mm"]
    before = validation_document(cal.validation)["baseline"]["position_mm"]
    assert after["max"] < 1e-6  # mm
    assert before["rms"] > 0.3  # the planted errors show with T and m fitted to nominal


def test_points_calibrate_with_noise_reaches_the_noise_floor(tmp_path, rng, capsys):
    sigma = 50e-6
    _point_dataset(tmp_path / "d", 120, sigma, rng)
    ds = load_dataset(tmp_path / "d")
    cal = calibrate(ds, measure(ds, progress=False), holdout=0.25)
    val = validation_document(cal.validation)
    # The norm of a 3-D Gaussian error has RMS sqrt(3) sigma; estimation error adds a little.
    floor = np.sqrt(3) * sigma * 1e3
    assert val["calibrated"]["position_mm"]["rms"] < 1.3 * floor
    assert val["baseline"]["position_mm"]["rms"] > 5 * floor
    assert abs(cal.settings["point_sigma_m"] - sigma) < 0.3 * sigma
    assert cal.exported == "calibrated"  # model selection keeps the geometry
    std = cal.std[cal.selection[cal.chosen].candidate.columns]  # every estimated parameter
    assert np.all(np.isfinite(std)) and np.all(std > 0)
    # Through the command: the summary names the absolute check, T's absorptions and the baseline.
    report = tmp_path / "report.html"
    argv = ["calibrate", str(tmp_path / "d"), "--out", str(tmp_path / "out"), "--report", report]
    assert main([str(a) for a in argv]) == 0
    assert "absolute position errors of 30 points" in report.read_text()
    out = capsys.readouterr().out
    assert "held-out absolute position error over 30 points" in out
    assert "instrument-to-base transform T absorbs it" in out
    assert "baseline (nominal, instrument and marker fitted)" in out
    assert "chosen: geometric" in out
    # relcal measure writes the points back as points (no invented orientation).
    assert main(["measure", str(tmp_path / "d"), "--out", str(tmp_path / "m"), "--quiet"]) == 0
    header = (tmp_path / "m" / "poses.csv").read_text().splitlines()[0]
    assert header == "id,q1,q2,q3,q4,q5,q6,q7,x,y,z"


def test_points_without_errors_export_the_baseline(tmp_path, rng):
    """Nothing planted: cross-validation finds no support for a kinematic correction, and the
    nominal model with T and m fitted is what is kept."""
    _point_dataset(tmp_path / "d", 80, 50e-6, rng, planted=False)
    ds = load_dataset(tmp_path / "d")
    cal = calibrate(ds, measure(ds, progress=False), holdout=0.25)
    assert cal.exported == "baseline"
    assert cal.selection[cal.chosen].candidate.name == "instrument and marker only"
    n_geo = cal.problem.layout.size
    assert np.all(cal.result.params[:n_geo] == 0.0)


def test_points_conservative_keeps_only_significant_link_parameters(tmp_path, rng):
    _point_dataset(tmp_path / "d", 60, 0.3e-3, rng)
    ds = load_dataset(tmp_path / "d")
    m = measure(ds, progress=False)
    cv = calibrate(ds, m, selection="cv")
    cal = calibrate(ds, m, selection="conservative")
    kinds = cal.problem.full_layout.kinds
    free = np.flatnonzero(np.isfinite(cal.result.std))
    links = [k for k in free if kinds[k] not in ("instrument", "marker")]
    z = np.abs(cal.result.params[links]) / cal.result.std[links]
    assert np.all(z >= 3.0) and len(links) < len(
        [k for k in np.flatnonzero(np.isfinite(cv.result.std)) if kinds[k] in KINDS]
    )
    assert "dropped (--selection conservative)" in cal.reason


def test_points_in_millimetres_are_not_a_calibration(tmp_path, rng):
    _point_dataset(tmp_path / "d", 40, 0.0, rng)
    text = (tmp_path / "d" / "samples.csv").read_text().splitlines()
    rows = [line.split(",") for line in text[1:]]
    for row in rows:
        row[1:4] = [f"{float(v) * 1e3:.12g}" for v in row[1:4]]  # x, y, z in mm
    (tmp_path / "d" / "samples.csv").write_text("\n".join([text[0], *map(",".join, rows)]))
    ds = load_dataset(tmp_path / "d")
    # named before anything is fitted (the input gate of every kind), with the fix
    with pytest.raises(RelcalError, match=r"look like millimetres.*divided by 1000"):
        calibrate(ds, measure(ds, progress=False))


def test_mocap_poses_calibrate_with_the_board_formulation(tmp_path, rng):
    """Full mocap poses (roll-pitch-yaw, named joints): the mocap-to-base transform is the world
    W and the marker mounting the hand-eye X; planted errors are recovered without noise."""
    model = auto_hayati(get_robot("franka_fr3"))
    layout = make_layout(model)
    truth = true_errors(layout, rng)
    q = random_q(model, 40, rng, scale=0.8)
    mount = tf.from_vector(np.array([0.01, -0.02, 0.14, 0.3, -0.2, 1.0]))  # flange to marker
    poses = INSTRUMENT @ fk(apply_errors(model, layout, truth), q) @ mount
    header = ["x", "y", "z", "roll", "pitch", "yaw", *model.joint_names]
    rows = np.column_stack([poses[:, :3, 3], _rpy(poses[:, :3, :3]), q])
    root = _write(tmp_path / "d", "robot: franka_fr3\njoint_unit: rad\n", header, rows)
    ds = load_dataset(root)
    cal = calibrate(ds, measure(ds, progress=False), holdout=0.25, nongeometric="none")
    assert cal.problem.formulation == "board"
    after = validation_document(cal.validation)["calibrated"]
    assert after["position_mm"]["max"] < 1e-6 and after["orientation_deg"]["max"] < 1e-7
    n_geo = cal.problem.layout.size
    ok = cal.result.identifiable[:n_geo]
    np.testing.assert_allclose(cal.result.params[:n_geo][ok], truth[ok], atol=1e-8)


@pytest.mark.skipif(not (DATA / "tiago_pro").is_dir(), reason="real data not available")
@pytest.mark.parametrize("which", ["pose", "position"])
def test_real_tiago_through_the_urdf(tmp_path, which):
    """The real TIAGo Pro motion-capture sessions through its URDF chain (needs the URDF loader):
    48 full poses (relative, hand-eye = marker mounting) and 94 marker positions (tracker
    formulation, instrument transform estimated). Held-out errors must improve on the baseline,
    with the 95 % interval of the ratio below 1. The arm's joint offsets reach 2.2 deg against its
    URDF (above the default 2 deg plausibility tolerance), and the positions leave a few
    parameters near the marker undetermined: tolerance 5 deg, conservative selection."""
    pytest.importorskip("relcal.robot.urdf")
    folder = DATA / "tiago_pro"
    chain = "root: base_footprint, tip: gripper_right_pal_atc_base_link"
    if which == "pose":
        samples, cols = "mocap_pose_20260805.csv", "x: x1, y: y1, z: z1, roll: phix1, "
        cols += "pitch: phiy1, yaw: phiz1"
    else:
        samples, cols = "mocap_position_20260702.csv", "x: x1, y: y1, z: z1"
    (tmp_path / "dataset.yaml").write_text(
        f"robot: {{urdf: {folder / 'tiago_pro.urdf'}, {chain}}}\njoint_unit: rad\n"
        f"columns: {{{cols}}}\nsamples: {folder / samples}\ntolerances: {{angle_deg: 5}}\n"
    )
    ds = load_dataset(tmp_path)
    assert ds.measured == which and len(ds.ids) == (48 if which == "pose" else 94)
    cal = calibrate(ds, measure(ds, progress=False), selection="conservative")
    ratio = validation_document(cal.validation)["ratio_to_baseline"]["position_mm"]
    assert ratio["ci95"][1] < 1.0, ratio
    texts = cal.result.unidentifiable
    if which == "position":
        assert any("instrument-to-base transform T absorbs it" in t for t in texts)
        instrument, _ = tracker_frames(cal.problem, cal.result.params)
        assert np.abs(instrument[:3, 3]).max() < 0.05  # the data's README: close to identity
        assert np.degrees(np.linalg.norm(tf.to_vector(instrument)[3:])) < 2.0
    else:
        assert any("hand-eye transform X" in t for t in texts)


def test_the_report_names_what_the_fit_compared(tmp_path, rng):
    """The HTML report's settings count training points for points, not pairs of poses."""
    from relcal.reporting.calibration_report import calibration_report
    from relcal.reporting.documents import results_document

    _point_dataset(tmp_path / "d", 40, 50e-6, rng)
    ds = load_dataset(tmp_path / "d")
    cal = calibrate(ds, measure(ds, progress=False), nongeometric="none")
    html = calibration_report(cal, results_document(cal))
    assert f"<td>training points</td><td>{len(cal.train) - len(cal.outliers)}</td>" in html
    assert "training pairs" not in html


# --- tables as spreadsheets export them: decimal commas, millimetres, other Euler sequences -----


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


_SPREADSHEET_YAML = """robot: a465
joint_unit: rad
decimal: ","
position_unit: mm
euler: XYZ
pose_angle_unit: deg
columns: {x: mx, y: my, z: mz, roll: mrx, pitch: mry, yaw: mrz}
"""


def _spreadsheet(root, rows, yaml_text=_SPREADSHEET_YAML, delimiter=";"):
    """A table as a German spreadsheet writes it: semicolons, decimal commas, mm, degrees."""
    root.mkdir(parents=True, exist_ok=True)
    (root / "dataset.yaml").write_text(yaml_text)
    header = ["stamp", *[f"q{i}" for i in range(1, 7)], "mx", "my", "mz", "mrx", "mry", "mrz"]
    text = [delimiter.join(header)]
    for row in rows:
        text.append(delimiter.join(f"{v:.10g}".replace(".", ",") for v in row))
    (root / "samples.csv").write_text("\n".join(text) + "\n")
    return root


def test_decimal_commas_millimetres_and_intrinsic_xyz(tmp_path):
    """Semicolons with decimal commas, positions in mm, intrinsic X-Y-Z Euler angles in degrees
    (R = Rx(a) Ry(b) Rz(c), built here by hand): read as the same poses in m."""
    rng = np.random.default_rng(3)
    q = rng.uniform(-1, 1, (6, 6))
    xyz_mm = rng.uniform(-900, 900, (6, 3))
    angles = rng.uniform(-170, 170, (6, 3))
    rows = np.column_stack([np.arange(6) * 1e13, q, xyz_mm, angles])
    data = load_dataset(_spreadsheet(tmp_path / "ds", rows))
    np.testing.assert_allclose(data.q, q, atol=1e-9)
    np.testing.assert_allclose(data.poses[:, :3, 3], xyz_mm / 1000, atol=1e-12)
    for pose, (a, b, c) in zip(data.poses, np.radians(angles), strict=True):
        np.testing.assert_allclose(pose[:3, :3], _rx(a) @ _ry(b) @ _rz(c), atol=1e-9)


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        ({"delimiter": ","}, "columns separated by commas, but dataset.yaml declares decimal"),
        ({"yaml_text": _SPREADSHEET_YAML.replace("XYZ", "XXY")}, "euler"),
        ({"yaml_text": _SPREADSHEET_YAML.replace("mm", "cm")}, "position_unit"),
    ],
)
def test_spreadsheet_declarations_refused_with_the_cause(tmp_path, change, expected):
    rows = np.column_stack([np.zeros(6), np.full((6, 6), 0.5), np.arange(36).reshape(6, 6) + 0.5])
    with pytest.raises(RelcalError, match=expected):
        load_dataset(_spreadsheet(tmp_path / "ds", rows, **change))


def test_decimal_point_in_a_decimal_comma_table_named(tmp_path):
    rows = np.column_stack([np.zeros(6), np.full((6, 6), 0.25), np.arange(36).reshape(6, 6) + 0.5])
    root = _spreadsheet(tmp_path / "ds", rows)
    lines = (root / "samples.csv").read_text().splitlines()
    lines[3] = lines[3].replace("0,25", "0.25", 1)  # the first joint of line 4
    (root / "samples.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(RelcalError, match=r"samples.csv line 4: q1: expected a number with a"):
        load_dataset(root)


def test_undeclared_decimal_comma_points_to_the_declaration(tmp_path):
    rows = np.column_stack([np.zeros(6), np.full((6, 6), 0.25), np.arange(36).reshape(6, 6) + 0.5])
    root = _spreadsheet(tmp_path / "ds", rows)
    (root / "dataset.yaml").write_text(_SPREADSHEET_YAML.replace('decimal: ","\n', ""))
    with pytest.raises(RelcalError, match=r"declare decimal: ',' in dataset.yaml"):
        load_dataset(root)


@pytest.mark.skipif(not (DATA / "ipa_ur10").is_dir(), reason="real data not available")
def test_real_ipa_ur10_table_read_as_exported(tmp_path):
    """The IPA UR10 tracker table, decimal commas and all: the first row's pose is the one its
    text says (mm -> m, intrinsic XYZ degrees computed by hand)."""
    source = DATA / "ipa_ur10" / "measurements_joint_configurations.csv"
    root = tmp_path / "ipa"
    root.mkdir()
    (root / "dataset.yaml").write_text(
        "robot: ur5e\njoint_unit: rad\ndecimal: ','\nposition_unit: mm\neuler: XYZ\n"
        "pose_angle_unit: deg\nsamples: " + str(source) + "\ncolumns: {q1: shoulder_pan_joint, "
        "q2: shoulder_lift_joint, q3: elbow_joint, q4: wrist_1_joint, q5: wrist_2_joint, "
        "q6: wrist_3_joint, x: measurement_x, y: measurement_y, z: measurement_z, "
        "roll: measurement_rx, pitch: measurement_ry, yaw: measurement_rz}\n"
    )
    data = load_dataset(root)
    assert data.q.shape == (1495, 6)
    header, first = source.read_text().splitlines()[:2]
    cells = dict(zip(header.split(";"), first.split(";"), strict=True))
    value = {k: float(v.replace(",", ".")) for k, v in cells.items() if k != "Timestamp"}
    np.testing.assert_allclose(
        data.poses[0, :3, 3], [value[f"measurement_{a}"] / 1000 for a in "xyz"], atol=1e-12
    )
    a, b, c = np.radians([value[f"measurement_r{a}"] for a in "xyz"])
    np.testing.assert_allclose(data.poses[0, :3, :3], _rx(a) @ _ry(b) @ _rz(c), atol=1e-9)
    assert data.q[0, 0] == value["shoulder_pan_joint"]
