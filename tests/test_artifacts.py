"""What is exported is what was validated: every loadable file carries its own held-out error,
measured on the file read back and checked here by an independent forward kinematics (Pinocchio,
yourdfpy); model.yaml reloads to the validated model exactly; the verdict, joint names, units and
the one rank figure appear in the terminal, the HTML report and results.json."""

import contextlib
import io
import json
import re
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yourdfpy
from conftest import DATA, random_q
from helpers_artifacts import ur5e_with_harmonics
from helpers_sim import with_plausible_loads
from scipy.spatial.transform import Rotation
from urdf_helpers import TIAGO_CHAIN, TIAGO_JOINTS, pin_fk

from relcal import geometry as tf
from relcal.calibration.artifacts import _refusal
from relcal.calibration.validate import Validation
from relcal.calibration.verdict import MIN_HELD_OUT, MIN_JUDGED, verdict
from relcal.cli import main
from relcal.data.dataset import load_dataset
from relcal.data.imaging import measure
from relcal.robot.kinematics import apply_errors, fk, make_layout
from relcal.robot.loading import get_robot
from relcal.robot.model import dump_model, load_model, with_nongeometric

ROOT = Path(__file__).resolve().parents[1]
POSITIONS = ROOT / "examples" / "tiago-pro-positions"


def _run(args, capsys) -> str:
    assert main(args) == 0
    return capsys.readouterr().out


def _files(doc: dict) -> dict:
    return {f["file"]: f for f in doc["artifacts"]["files"]}


# --- TIAGo Pro positions, compliance chosen (--selection conservative) ------------------------


@pytest.fixture(scope="module")
def tiago(tmp_path_factory):
    if not (DATA / "tiago_pro").is_dir():
        pytest.skip("real data not available")
    out = tmp_path_factory.mktemp("tiago")
    args = ["calibrate", str(POSITIONS), "--selection", "conservative", "--out", str(out / "cal")]
    args += ["--json", str(out / "r.json"), "--report", str(out / "r.html")]
    buf = io.StringIO()  # a module fixture cannot take capsys
    with contextlib.redirect_stdout(buf):
        assert main(args) == 0
    doc = json.loads((out / "r.json").read_text())
    return SimpleNamespace(out=out / "cal", doc=doc, text=buf.getvalue(), html=(out / "r.html"))


def _held_out(doc: dict, dataset) -> np.ndarray:
    """Dataset indices of the held-out samples that the validation used."""
    left_out = set(doc["held_out_outliers"])
    ids = [i for i in doc["held_out_ids"] if i not in left_out]
    where = {sid: k for k, sid in enumerate(dataset.ids)}
    return np.array([where[i] for i in ids])


def _transform(doc: dict) -> np.ndarray:
    """A transform of the JSON documents (``xyz_m``, ``rpy_deg``: URDF roll-pitch-yaw)."""
    return tf.from_xyz_rpy(np.array(doc["xyz_m"]), np.radians(doc["rpy_deg"]))


def _point_rms(flange: np.ndarray, frames: dict, measured: np.ndarray) -> np.ndarray:
    """Per-point error norms (mm) of ``T F(q) m`` against the measured points."""
    instrument, marker = _transform(frames["instrument"]), np.array(frames["marker_xyz_m"])
    predicted = (instrument @ flange @ np.r_[marker, 1.0])[:, :3]
    return np.linalg.norm(measured - predicted, axis=1) * 1e3


def test_tiago_urdf_error_matches_pinocchio_on_the_written_file(tiago):
    doc = tiago.doc
    assert "compliance" in doc["model_selection"]["chosen"]
    files = _files(doc)
    urdf = files["robot.urdf"]
    assert urdf["written"] and urdf["holds"] == "geometry only"
    assert urdf["model"] == "geometry-only refit"  # compliance cannot be written into a URDF
    assert not doc["artifacts"]["geometry_is_validated_model"]
    dataset = load_dataset(POSITIONS)
    test = _held_out(doc, dataset)
    measured = measure(dataset, progress=False).poses[test, :3, 3]
    flange = pin_fk(tiago.out / "robot.urdf", *TIAGO_CHAIN, TIAGO_JOINTS, dataset.q[test])
    errors = _point_rms(flange, urdf["frames"], measured)
    rms = float(np.sqrt(np.mean(errors**2)))
    assert rms == pytest.approx(urdf["held_out"]["position_rms_mm"], rel=1e-8)
    assert urdf["held_out"]["n_samples"] == len(test)
    # printed and stored, and worse than the validated model (geometry alone cannot hold it)
    assert f"robot.urdf (geometry only, refitted): {rms:.3f} mm" in tiago.text
    model_rms = files["model.yaml"]["held_out"]["position_rms_mm"]
    assert model_rms < rms < doc["validation"]["baseline"]["position_mm"]["rms"]
    assert f"model.yaml (full model): {model_rms:.3f} mm" in tiago.text
    html = tiago.html.read_text()
    assert 'id="artifacts"' in html and f"{rms:.3f}" in html


def test_tiago_model_yaml_reloads_to_the_validated_model(tiago):
    doc = tiago.doc
    dataset = load_dataset(POSITIONS)
    test = _held_out(doc, dataset)
    model = load_model(tiago.out / "model.yaml")
    assert model.compliance.any()  # the terms are in the file
    measured = measure(dataset, progress=False).poses[test, :3, 3]
    entry = _files(doc)["model.yaml"]
    errors = _point_rms(fk(model, dataset.q[test]), entry["frames"], measured)
    validated = np.array([p["calibrated_mm"] for p in doc["validation"]["pairs"]])
    assert [p["ids"][0] for p in doc["validation"]["pairs"]] == [dataset.ids[k] for k in test]
    np.testing.assert_allclose(errors, validated, rtol=0, atol=1e-9)  # mm
    assert entry["held_out"]["position_rms_mm"] == pytest.approx(
        doc["validation"]["calibrated"]["position_mm"]["rms"], rel=1e-12
    )


def test_tiago_report_is_honest_everywhere(tiago):
    doc, text, html = tiago.doc, tiago.text, tiago.html.read_text()
    v = doc["verdict"]
    assert v["code"] == "deploy" and v["n_held_out"] == 24 and not v["warnings"]
    lo, hi = v["interval"]
    ratio = doc["validation"]["ratio_to_baseline"]["position_mm"]
    assert lo == pytest.approx(1 / ratio["ci95"][1]) and hi == pytest.approx(1 / ratio["ci95"][0])
    assert v["text"].startswith(f"deploy: {v['factor']:.2g}x better on held-out points")
    assert f"95% interval {lo:.2g}x..{hi:.2g}x, 24 held-out samples" in v["text"]
    assert f"verdict: {v['text']}" in text.splitlines()
    assert 'id="verdict"' in html and v["text"] in html
    # joint names, not indices, for a URDF robot; theta_off[3] is the second arm joint
    rows = {r["name"]: r for r in doc["parameters"]}
    assert rows["theta_off[3]"]["label"] == "theta_off[arm_right_2_joint]"
    assert "theta_off[arm_right_2_joint]" in text and "theta_off[arm_right_2_joint]" in html
    assert not re.search(r"\b(theta_off|a|d|alpha|compliance)\[\d", text)
    # units from the kind: compliance in urad/Nm (um/N on the prismatic torso), never mm
    for row in doc["parameters"]:
        if row["name"].startswith("compliance"):
            assert row["unit"] in ("urad/Nm", "um/N"), row
    lines = [t for t in text.splitlines() if t.strip().startswith("compliance[")]
    assert lines and all("urad/Nm" in t and " mm" not in t for t in lines)
    # one rank figure: the terminal's and the report's are the same
    ident = doc["identification"]
    figure = f"{ident['rank']} of {ident['n_params']}"
    assert f"rank {figure} parameters" in text and figure in html
    assert not re.search(r"identifiable \d+ of", html)
    # the weighted residual with its unit; points worded as points
    assert f"weighted residual RMS {ident['initial_residual_rms']:.3g}" in text
    assert ident["residual_unit"] in text and ident["residual_unit"] in html
    assert "Errors per point" in html and "Errors per pair" not in html
    assert "Histograms of the absolute position errors" in html and "relative pose" not in html
    held = [t for t in text.splitlines() if t.startswith("held-out")][0]
    assert "over 24 points" in held and "pairs" not in held
    if doc["outliers"]:  # (which samples are trained on depends on the held-out draw)
        assert "outliers (they fit badly" in text


def test_registry_record_carries_the_files_and_the_verdict(tiago):
    from relcal.calibration.pipeline import calibrate
    from relcal.fleet.records import calibration_record
    from relcal.reporting.documents import results_document

    dataset = load_dataset(POSITIONS)
    cal = calibrate(dataset, measure(dataset, progress=False), selection="conservative")
    doc = results_document(cal)
    record = calibration_record(cal, doc)
    assert record["settings"]["verdict"] == "deploy"
    stored = {a["file"]: a for a in record["settings"]["artifacts"]}
    assert stored["robot.urdf"]["position_rms_mm"] == pytest.approx(
        tiago.doc["artifacts"]["files"][1]["held_out"]["position_rms_mm"], rel=1e-9
    )
    # units from the kind in the record too: `relcal history` showed compliances in mm
    from relcal.fleet.drift import display

    units = {p["name"]: p["unit"] for p in record["parameters"]}
    assert units["compliance[2]"] == "rad/(N m)" and units["compliance[1]"] == "m/N"
    assert units["theta_off[3]"] == "rad" and units["d[4]"] == "m"
    assert record["settings"]["parameter_labels"]["theta_off[3]"] == "theta_off[arm_right_2_joint]"
    row = next(p for p in record["parameters"] if p["name"] == "compliance[2]")
    shown = {r["name"]: r for r in doc["parameters"]}["compliance[2]"]
    assert display(row["value"], row["unit"]) == pytest.approx((shown["error"], "urad/Nm"))


def test_history_names_the_joints_and_their_units(tiago, tmp_path):
    """relcal history of the TIAGo record: parameters under their joints' names, compliances in
    urad/Nm."""
    from relcal.calibration.pipeline import calibrate
    from relcal.fleet import registry as reg
    from relcal.fleet.records import calibration_record
    from relcal.fleet.text import history_text
    from relcal.reporting.documents import results_document

    dataset = load_dataset(POSITIONS)
    cal = calibrate(dataset, measure(dataset, progress=False), selection="conservative")
    with reg.open_registry(tmp_path / "h.sqlite") as registry:
        run = registry.get(registry.add(calibration_record(cal, results_document(cal))))
    text = history_text(run.robot_id, [run], [None], "h.sqlite")
    row = next(t for t in text.splitlines() if t.startswith("compliance[arm_right_1_joint]"))
    assert "urad/Nm" in row and "mm" not in row
    assert "theta_off[arm_right_2_joint]" in text and "theta_off[3]" not in text


def test_a_refused_file_is_not_written(tiago):
    """The writer writes only what the validation let through."""
    from relcal.calibration.pipeline import calibrate
    from relcal.reporting.documents import results_document
    from relcal.reporting.outputs import calibration_files

    dataset = load_dataset(POSITIONS)
    cal = calibrate(dataset, measure(dataset, progress=False), selection="conservative")
    files = calibration_files(cal, results_document(cal), "run")
    assert {"model.yaml", "robot.urdf", "origin_corrections.yaml"} <= set(files)
    refused = tuple(
        replace(a, refused="planted") if a.name == "robot.urdf" else a for a in cal.artifacts
    )
    cal.__dict__["artifacts"] = refused  # the cached property, as a refusal would leave it
    files = calibration_files(cal, results_document(cal), "run")
    assert "robot.urdf" not in files and "model.yaml" in files
    assert "ros2/calibrated.launch.py" not in files  # no overlay without its URDF
    assert files["model.yaml"].startswith(b"# relcal run run\n")


# --- a simulated UR5e with harmonics ------------------------------------------------------------


def test_ur5e_harmonics_urdf_error_matches_yourdfpy(tmp_path, capsys):
    ur5e_with_harmonics(tmp_path / "d", n=32)
    args = ["calibrate", str(tmp_path / "d"), "--out", str(tmp_path / "cal")]
    text = _run([*args, "--json", str(tmp_path / "r.json")], capsys)
    doc = json.loads((tmp_path / "r.json").read_text())
    assert "harmonic" in doc["model_selection"]["chosen"]
    files = _files(doc)
    urdf, full = files["robot.urdf"], files["model.yaml"]
    assert urdf["model"] == "geometry-only refit" and urdf["written"]
    dataset = load_dataset(tmp_path / "d")
    poses = measure(dataset, progress=False).poses
    where = {sid: k for k, sid in enumerate(dataset.ids)}
    pairs = np.array([[where[i] for i in p["ids"]] for p in doc["validation"]["pairs"]])

    def relative_errors(flange: np.ndarray, frames: dict) -> np.ndarray:
        """Position error norms (mm) of each held-out pose in the world frame, ``W F X`` against
        the measured pose, flange poses by sample index."""
        handeye, world = _transform(frames["handeye"]), _transform(frames["world"])
        out = []
        for i, j in pairs:
            assert i == j  # one pose each
            model = world @ flange[i] @ handeye
            out.append(np.linalg.norm(poses[i][:3, 3] - model[:3, 3]) * 1e3)
        return np.array(out)

    robot = yourdfpy.URDF.load(
        str(tmp_path / "cal" / "robot.urdf"), load_meshes=False, build_scene_graph=True
    )
    names = dataset.model.joint_names
    flange = {}
    for k in np.unique(pairs):
        robot.update_cfg(dict(zip(names, dataset.q[k], strict=True)))
        flange[int(k)] = robot.get_transform("tool0", "base_link")
    errors = relative_errors(flange, urdf["frames"])
    rms = float(np.sqrt(np.mean(errors**2)))
    assert rms == pytest.approx(urdf["held_out"]["position_rms_mm"], rel=1e-8)
    assert f"robot.urdf (geometry only, refitted): {rms:.3f} mm" in text
    # model.yaml: the harmonics are in it and it reloads to the validated model exactly
    model = load_model(tmp_path / "cal" / "model.yaml")
    assert model.harmonic_c.any()
    flange = dict(enumerate(fk(model, dataset.q)))
    errors = relative_errors(flange, full["frames"])
    validated = np.array([p["calibrated_mm"] for p in doc["validation"]["pairs"]])
    np.testing.assert_allclose(errors, validated, rtol=0, atol=1e-8)
    assert full["held_out"]["position_rms_mm"] < rms
    assert "held-out poses" in doc["verdict"]["text"]
    assert doc["verdict"]["warnings"]  # 8 held-out samples: fewer than 10
    assert f"warning: {doc['verdict']['warnings'][0]}" in text


# --- the rules ------------------------------------------------------------------------------------


def _points(before: np.ndarray, after: np.ndarray) -> Validation:
    """A per-point validation (pairs (k, k)) with position errors along x (m)."""
    n = len(before)

    def errors(values):
        out = np.full((n, 6), np.nan)
        out[:, :3] = 0.0
        out[:, 0] = values
        return out

    k = np.arange(n)
    return Validation(np.stack([k, k], 1), errors(before), errors(after), errors(before))


def test_verdict_reads_the_interval_and_the_count():
    rng = np.random.default_rng(0)
    before = rng.uniform(1e-3, 3e-3, 30)
    better = verdict(_points(before, before / 4), formulation="tracker")
    assert better.code == "deploy" and better.factor == pytest.approx(4.0)
    assert better.text.startswith("deploy: 4x better on held-out points") and not better.warnings
    worse = verdict(_points(before, before * 3), formulation="tracker")
    assert worse.code == "do not deploy" and "3x worse" in worse.text
    assert verdict(_points(before, before / 48)).text.startswith("deploy: 48x better")
    noisy = verdict(_points(before, before * rng.uniform(0.2, 1.9, 30)), formulation="tracker")
    assert noisy.code == "collect more samples" and "the interval spans 1" in noisy.text
    lo, hi = noisy.interval
    assert lo < 1 < hi
    few = verdict(_points(before[: MIN_HELD_OUT - 1], before[: MIN_HELD_OUT - 1] / 4))
    assert few.warnings and f"{MIN_HELD_OUT - 1} held-out samples" in few.warnings[0]
    assert "pairs of poses" in few.text
    assert not verdict(_points(before[:MIN_HELD_OUT], before[:MIN_HELD_OUT] / 4)).warnings
    # a handful of held-out samples (two: one pair, a bootstrap without spread): no deploy
    for k in (2, MIN_JUDGED - 1):
        tiny = verdict(_points(before[:k], before[:k] / 60))
        assert tiny.code == "collect more samples" and "too few to judge" in tiny.text, k
    scatter = rng.uniform(0.01, 0.03, MIN_JUDGED)
    five = verdict(_points(before[:MIN_JUDGED], before[:MIN_JUDGED] * scatter))
    assert five.code == "deploy" and five.interval[0] < five.interval[1]
    assert verdict(_points(before, before / 4), exported="baseline").code == "do not deploy"
    assert verdict(None).code == "not validated"


def test_a_geometry_file_worse_than_the_baseline_is_refused():
    rng = np.random.default_rng(1)
    before = rng.uniform(1e-3, 3e-3, 20)
    cal = SimpleNamespace(exported="calibrated")
    assert _refusal(cal, _points(before, before * 0.9), refit=True) is None
    reason = _refusal(cal, _points(before, before * 1.05), refit=True)
    assert reason and "worse than the baseline" in reason
    assert "cannot be measured" in _refusal(cal, None, refit=True)
    assert _refusal(cal, None, refit=False) is None  # the validated model's own geometry


def test_model_file_keeps_the_gravity_reference_of_compliance(tmp_path):
    model = with_nongeometric(with_plausible_loads(get_robot("a465"), "a465"), ["compliance"])
    layout = make_layout(model)
    rng = np.random.default_rng(2)
    errors = np.where(layout.is_angle(), 2e-3, 2e-3) * rng.choice([-1.0, 1.0], layout.size)
    errors[~layout.is_geometric()] = 2e-4  # rad/(N m)
    calibrated = apply_errors(model, layout, errors)
    assert "gravity_reference" not in dump_model(model)  # a nominal model: no extra block
    path = tmp_path / "m.yaml"
    path.write_text(dump_model(calibrated))
    reloaded = load_model(path)
    q = random_q(model, 20, rng)
    np.testing.assert_allclose(fk(reloaded, q), fk(calibrated, q), rtol=0, atol=1e-12)
    # what a file without the block gives: the torques of the calibrated geometry
    geometry = replace(reloaded, loads=None, compliance=None, nongeometric=())
    naive = replace(reloaded, loads=replace(reloaded.loads, reference=geometry))
    assert np.abs(fk(naive, q) - fk(calibrated, q)).max() > 1e-6


def test_each_file_is_validated_on_every_fold_too(tiago):
    """--kfold: every fold's files read back and validated on that fold's held-out samples;
    model.yaml pooled over the folds is the pooled validation of the chosen models."""
    from relcal.calibration.pipeline import cross_validate
    from relcal.reporting.documents import cross_validation_document

    dataset = load_dataset(POSITIONS)
    folds = cross_validate(dataset, k=3, selection="conservative")
    doc = cross_validation_document(folds)
    files = doc["artifacts"]
    assert files["model.yaml"]["position_rms_mm"] == pytest.approx(
        doc["pooled"]["calibrated"]["position_mm"]["rms"], rel=1e-9
    )
    assert files["robot.urdf"]["holds"] == "geometry only"
    assert files["model.yaml"]["position_rms_mm"] < files["robot.urdf"]["position_rms_mm"]
    assert files["robot.urdf"]["position_rms_mm"] < doc["pooled"]["baseline"]["position_mm"]["rms"]


def test_compensate_names_the_model_files_own_error(tiago, tmp_path, capsys):
    """relcal compensate reads the held-out error that results.json records for that very
    model.yaml, and says when the file was changed since."""
    model_path = tiago.out / "model.yaml"
    model = load_model(model_path)
    dataset = load_dataset(POSITIONS)
    poses = fk(model, dataset.q[:3])
    rows = []
    for k, pose in enumerate(poses):
        x, y, z, w = Rotation.from_matrix(pose[:3, :3]).as_quat()
        rows.append(f"t{k}," + ",".join(f"{v:.12g}" for v in (*pose[:3, 3], x, y, z, w)))
    targets = tmp_path / "targets.csv"
    targets.write_text("id,x,y,z,qx,qy,qz,qw\n" + "\n".join(rows) + "\n")
    args = ["compensate", "--model", str(model_path), "--targets", str(targets)]
    assert main([*args, "--out", str(tmp_path / "j.csv"), "--json", str(tmp_path / "j.json")]) == 0
    rms = _files(tiago.doc)["model.yaml"]["held_out"]["position_rms_mm"]
    assert f"held-out position RMS {rms:.3f} mm over 24 samples" in capsys.readouterr().err
    assert json.loads((tmp_path / "j.json").read_text())["model_validation"]["matches"]
    changed = tmp_path / "other" / "model.yaml"
    changed.parent.mkdir()
    text = model_path.read_text()
    assert "compliance: 0.08" in text
    changed.write_text(text.replace("compliance: 0.08", "compliance: 0.09", 1))
    (changed.parent / "results.json").write_text(json.dumps(tiago.doc))
    args = ["compensate", "--model", str(changed), "--targets", str(targets)]
    assert main([*args, "--out", str(tmp_path / "k.csv")]) == 0
    assert "differs from the model.yaml that results.json validated" in capsys.readouterr().err


@pytest.mark.parametrize("robot", ["ur5e", "panda"])
def test_every_robot_file_reads_back_to_its_model(robot, tmp_path):
    """What the artifacts are measured on: each file of relcal.robot_files read back (the UR
    and Franka files written into the nominal URDF's origins) gives the model's kinematics."""
    from urdf_helpers import UR5E_KINEMATICS, real, ur_description_urdf

    from relcal.calibration.artifacts import read_back
    from relcal.robot.export import calibrated_model, robot_files
    from relcal.robot.urdf import load_urdf

    if robot == "ur5e":
        path = tmp_path / "ur5e.urdf"
        path.write_text(ur_description_urdf(UR5E_KINEMATICS))
        nominal = load_urdf(path, "base_link", "tool0")
        expected = {"robot.urdf", "origin_corrections.yaml", "ur_calibration.yaml"}
    else:
        nominal = load_urdf(*real("panda"))
        expected = {"robot.urdf", "origin_corrections.yaml", "franka_kinematics.yaml"}
    rng = np.random.default_rng(3)
    layout = make_layout(nominal)
    model = calibrated_model(nominal, layout, rng.normal(0, 1e-3, layout.size))
    files = robot_files(model)
    assert expected <= set(files)
    q = random_q(model, 10, rng)
    for name, content in files.items():
        folder = tmp_path / name.replace(".", "_")
        folder.mkdir()
        loaded = read_back(name, content, nominal, folder)
        np.testing.assert_allclose(fk(loaded, q), fk(model, q), rtol=0, atol=1e-9, err_msg=name)


def test_board_formulation_files_are_validated_on_the_validation_pairs(tmp_path):
    """The board formulation validates each held-out pose in the world frame: each written file
    is scored on the same held-out poses, with its errors those of the validation (the files
    hold the validated geometry). It was refused once: the board's per-sample pairs (k, k)
    were handed to the relative formulation."""
    rng = np.random.default_rng(5)
    model = get_robot("a465")
    layout = make_layout(model)
    truth = rng.normal(0, 3e-4, layout.size)  # m and rad
    n = 60
    q = random_q(model, n, rng) * 0.8
    handeye = tf.from_vector(np.array([0.0, 0.04, 0.06, 0.01, -0.02, 0.0]))
    board = tf.from_vector(np.array([0.5, 0.1, -0.2, 3.0, 0.1, 0.4]))
    noise = np.c_[rng.normal(0, 5e-5, (n, 3)), rng.normal(0, np.radians(0.01), (n, 3))]
    poses = board @ fk(apply_errors(model, layout, truth), q) @ handeye @ tf.from_vector(noise)
    root = tmp_path / "board"
    root.mkdir()
    (root / "dataset.yaml").write_text(
        "robot: a465\njoint_unit: deg\nhandeye: {xyz: [0, 0.04, 0.06]}\n"
    )
    from relcal.calibration.pipeline import calibrate
    from relcal.data.dataset import write_samples

    ids = [f"s{k:03d}" for k in range(n)]
    (root / "samples.csv").write_text(
        write_samples(root / "samples.csv", ids, np.degrees(q), poses=poses)
    )
    dataset = load_dataset(root)
    cal = calibrate(dataset, measure(dataset, progress=False), pairing="board", seed=0)
    assert cal.problem.formulation == "board"
    val = cal.validation
    assert len(val.pairs) and np.all(val.pairs[:, 0] == val.pairs[:, 1])  # one pose each
    assert val.what == "poses"
    assert cal.geometry is None  # the geometric model chosen: every file holds it
    assert len(cal.artifacts) >= 2
    for art in cal.artifacts:
        assert art.refused is None, art.refused
        np.testing.assert_array_equal(art.validation.pairs, val.pairs)
        np.testing.assert_allclose(art.validation.calibrated, val.calibrated, atol=1e-9)
        assert art.rms() == pytest.approx(val.rms("calibrated"), rel=1e-6)
        assert art.rms() < 0.5 * val.rms("before")
