"""Hand-eye calibration: closed forms, the refined estimate, its held-out proof, planted truth."""

from __future__ import annotations

import numpy as np
import pytest
from helpers_handeye import (
    NOISE,
    W_TRUE,
    X_TRUE,
    camera_poses,
    flange_poses,
    render_dataset,
    write_flange_dataset,
)
from scipy.spatial.transform import Rotation

import relcal
from relcal import geometry as tf
from relcal.calibration.handeye_closed import (
    METHODS,
    _checked,
    closed_forms,
    informative_samples,
)
from relcal.calibration.handeye_fit import fit_poses
from relcal.calibration.handeye_job import handeye
from relcal.data.flange import flange_chain
from relcal.errors import RelcalError
from relcal.reporting.handeye_report import title


def _frame_error(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """The 6-vector of ``truth^-1 estimate`` (m, rad): the perturbation of the fit's covariance."""
    return tf.to_vector(tf.invert(truth) @ estimate)


@pytest.mark.parametrize("mode", ["camera on the flange", "marker on the flange"])
def test_every_closed_form_recovers_exact_frames(mode):
    flange = flange_poses(12, seed=1)
    x = X_TRUE if mode == "camera on the flange" else tf.invert(X_TRUE)
    poses = camera_poses(flange, x, W_TRUE, cov=None)
    answers, selection = closed_forms(flange, poses)
    assert len(selection.used) == 12 and not selection.left_out
    assert [a.method for a in answers] == list(METHODS)
    for a in answers:
        assert a.ok, a.failure
        assert np.abs(a.handeye - x).max() < 1e-8, a.method
        assert np.abs(a.world - W_TRUE).max() < 1e-8, a.method


def test_closed_form_failures_are_named_never_used():
    rot = np.eye(3)
    assert _checked("andreff", np.full((3, 3), np.nan), np.zeros(3))[1].endswith(
        "returned NaN (a known failure of the method on such data)"
    )
    flip = np.diag([1.0, 1.0, -1.0])
    x, why = _checked("horaud", flip, np.zeros(3))
    assert x is None and "not a rotation" in why
    assert _checked("tsai", rot, np.zeros(3))[1] is None
    answers, _ = closed_forms(flange_poses(2, 0), camera_poses(flange_poses(2, 0), cov=None))
    assert all(not a.ok and "the closed forms need 3" in a.failure for a in answers)


def test_informative_samples_leave_out_tiny_and_half_turn_pairs_whatever_the_order():
    flange = flange_poses(10, seed=2)
    twin = flange[3] @ tf.from_vector([0.001, 0, 0, 0, 0, np.radians(0.5)])  # 0.5 deg, 1 mm
    slide = flange[4] @ tf.from_vector([0.05, 0, 0, 0, 0, 0])  # a pure translation: kept
    flip = flange[5] @ tf.from_vector([0, 0, 0, np.radians(178.0), 0, 0])  # 178 deg from 5
    all_f = np.concatenate([flange, twin[None], flip[None], slide[None]])
    poses = camera_poses(all_f, cov=None)
    sel = informative_samples(all_f, poses)
    assert len(sel.used) == 11 and len(sel.left_out) == 2
    assert any("moves less than 2 mm" in why for why in sel.left_out.values())
    assert any("near 180 deg" in why for why in sel.left_out.values())
    perm = np.random.default_rng(0).permutation(len(all_f))
    sel2 = informative_samples(all_f[perm], poses[perm])
    assert sorted(perm[sel2.used].tolist()) == sorted(sel.used.tolist())


def test_refined_estimate_within_its_std_and_at_least_as_good_as_the_closed_forms():
    flange = flange_poses(30, seed=3)
    poses = camera_poses(flange, seed=4)
    poses[7] = poses[7] @ tf.from_vector([0.02, 0.0, 0.0, 0.0, 0.05, 0.0])  # a bad frame
    model, q = flange_chain(flange)
    result = handeye(relcal.Dataset.from_arrays(model, q, poses), folds=5)
    fit = result.fit
    assert result.outliers and list(result.outliers) == ["7"]
    err = _frame_error(result.handeye, X_TRUE)
    std = np.sqrt(np.diag(fit.covariance))[:6]
    assert np.all(np.abs(err) < 3 * std), (err, std)
    assert fit.converged
    # on the same data, the closed forms' own error in the frame is not smaller
    mine = np.linalg.norm(err[:3])
    best = min(np.linalg.norm(_frame_error(a.handeye, X_TRUE)[:3]) for a in result.closed if a.ok)
    assert mine <= best
    # and on the same held-out samples
    val = result.validation
    assert val.rms("refined") <= min(val.rms(m) for m in METHODS)
    assert result.verdict.code == "deploy"
    assert result.exported == "refined"


def test_refined_spread_over_200_seeds_is_the_cramer_rao_bound():
    """200 data sets of 80 noisy camera poses (correlated noise in the camera frame): the spread of
    the refined frames matches the Cramer-Rao bound of the true noise within 10 %."""
    n = 80
    flange = flange_poses(n, seed=5)
    model, q = flange_chain(flange)
    truth = W_TRUE @ flange @ X_TRUE

    def residual(p):
        x, w = X_TRUE @ tf.from_vector(p[:6]), W_TRUE @ tf.from_vector(p[6:])
        return tf.to_vector(tf.invert(w @ flange @ x) @ truth).ravel()

    jac = np.empty((6 * n, 12))
    for i in range(12):  # finite differences of the residual, independent of the fit's own
        d = np.zeros(12)
        d[i] = 1e-6
        jac[:, i] = (residual(d) - residual(-d)) / 2e-6
    info = jac.T @ np.kron(np.eye(n), np.linalg.inv(NOISE)) @ jac
    crb = np.linalg.inv(info)
    start = closed_forms(flange[:10], truth[:10], ("park",))[0][0]
    est, std = [], []
    for seed in range(200):
        poses = camera_poses(flange, seed=100 + seed)
        fit = fit_poses(model, q, poses, start.handeye, start.world, reject=False)
        est.append(np.r_[_frame_error(fit.handeye, X_TRUE), _frame_error(fit.world, W_TRUE)])
        std.append(np.sqrt(np.diag(fit.covariance)))
    est = np.array(est)
    # the spread in units of the bound: 1 for an efficient estimator (sampling error ~3 %)
    spread = np.mean(np.einsum("ni,ij,nj->n", est, info, est)) / 12
    assert abs(spread - 1.0) < 0.10, spread
    spread_x = (
        np.mean(np.einsum("ni,ij,nj->n", est[:, :6], np.linalg.inv(crb[:6, :6]), est[:, :6])) / 6
    )
    assert abs(spread_x - 1.0) < 0.10, spread_x
    # and the fit's own covariance predicts it (on average over the data sets: each learns its
    # own noise)
    assert np.allclose(np.mean(std, axis=0), np.sqrt(np.diag(crb)), rtol=0.10)


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_rendered_images_planted_truth(tmp_path, mode):
    folder, x, w = render_dataset(tmp_path / mode, mode)
    dataset = relcal.load_dataset(folder)
    assert dataset.flange is not None  # flange poses, no robot model
    result = handeye(dataset, folds=5)
    assert result.validation.criterion == "px"
    err = _frame_error(result.handeye, x)
    std = np.sqrt(np.diag(result.fit.covariance))[:6]
    assert np.all(np.abs(err) < 3 * std), err / std
    best = min(np.linalg.norm(_frame_error(a.handeye, x)[:3]) for a in result.closed if a.ok)
    assert np.linalg.norm(err[:3]) <= best
    val = result.validation
    assert val.rms("refined") <= min(val.rms(m) for m in METHODS)
    delivered = result.transform("handeye")
    truth = x if mode == "eye_in_hand" else tf.invert(w)  # the fixed camera in the base frame
    assert np.abs(delivered[:3, 3] - truth[:3, 3]).max() < 1e-3


def test_numbers_do_not_change_when_rows_are_reordered(tmp_path):
    flange = flange_poses(16, seed=6)
    poses = camera_poses(flange, seed=7)
    a = handeye(relcal.load_dataset(write_flange_dataset(tmp_path / "a", flange, poses)))
    perm = np.random.default_rng(1).permutation(16)
    b = handeye(
        relcal.load_dataset(write_flange_dataset(tmp_path / "b", flange[perm], poses[perm]))
    )
    assert np.allclose(a.handeye, b.handeye, atol=1e-12)
    for m in ("refined", *METHODS):
        sa, sb = a.validation.summary(m), b.validation.summary(m)
        assert sa["position_mm"]["rms"] == pytest.approx(sb["position_mm"]["rms"], rel=1e-9)
        assert sa["position_mm"]["ci95"] == pytest.approx(sb["position_mm"]["ci95"], rel=1e-9)
    assert a.verdict.text == b.verdict.text


def test_flange_columns_must_be_complete(tmp_path):
    flange = flange_poses(6, seed=8)
    folder = write_flange_dataset(tmp_path / "d", flange, camera_poses(flange, cov=None))
    text = (folder / "samples.csv").read_text().replace(",fqw,", ",fqw_,", 1)
    (folder / "samples.csv").write_text(text)
    with pytest.raises(RelcalError, match="fqw"):
        relcal.load_dataset(folder)


def _flange_rewritten(folder, columns, values, extra: str = "") -> None:
    """The flange columns of ``folder``'s table replaced by ``columns`` holding ``values``
    ``(N, k)``, and ``extra`` lines added to its dataset.yaml."""
    lines = [line.split(",") for line in (folder / "samples.csv").read_text().splitlines()]
    keep = [k for k, name in enumerate(lines[0]) if not name.startswith("f")]
    out = [[lines[0][0], *columns, *(lines[0][k] for k in keep[1:])]]
    for row, v in zip(lines[1:], values, strict=True):
        out.append([row[0], *(f"{x:.15g}" for x in v), *(row[k] for k in keep[1:])])
    (folder / "samples.csv").write_text("\n".join(",".join(r) for r in out) + "\n")
    spec = folder / "dataset.yaml"
    spec.write_text(spec.read_text() + extra)


@pytest.mark.parametrize(
    "form", ["rotation vector", "rotation vector in deg, mm", "ZYX angles in deg"]
)
def test_flange_poses_as_a_controller_logs_them(tmp_path, form):
    """Flange poses as controllers log them (a UR's x, y, z, rx, ry, rz; millimetres and
    degrees; three angles of a rotation sequence), declared in dataset.yaml, give the transform
    of the same poses written as quaternions; undeclared, they are refused naming the field."""
    from scipy.spatial.transform import Rotation

    flange = flange_poses(16, seed=31)
    poses = camera_poses(flange, seed=31)
    reference = handeye(relcal.load_dataset(write_flange_dataset(tmp_path / "q", flange, poses)))
    folder = write_flange_dataset(tmp_path / "d", flange, poses)
    rotation = Rotation.from_matrix(flange[:, :3, :3])
    position = flange[:, :3, 3]
    if form == "rotation vector":
        columns, values, extra = ("frx", "fry", "frz"), rotation.as_rotvec(), ""
        refused = None
    elif form == "rotation vector in deg, mm":
        columns, values = ("frx", "fry", "frz"), np.degrees(rotation.as_rotvec())
        position = position * 1000
        extra, refused = "flange_unit: mm\nflange_angle_unit: deg\n", "flange_angle_unit: deg"
    else:
        columns, values = ("froll", "fpitch", "fyaw"), rotation.as_euler("ZYX", degrees=True)
        extra, refused = "flange_angle_unit: deg\nflange_euler: ZYX\n", "flange_angle_unit: deg"
    _flange_rewritten(folder, ("fx", "fy", "fz", *columns), np.c_[position, values])
    if refused is not None:
        with pytest.raises(RelcalError, match=refused):
            relcal.load_dataset(folder)
    spec = folder / "dataset.yaml"
    spec.write_text(spec.read_text() + extra)
    result = handeye(relcal.load_dataset(folder))
    assert np.abs(result.transform("handeye") - reference.transform("handeye")).max() < 1e-9


def test_a_flange_pose_of_two_rotations_or_none_is_refused(tmp_path):
    flange = flange_poses(6, seed=8)
    folder = write_flange_dataset(tmp_path / "d", flange, camera_poses(flange, cov=None))
    text = (folder / "samples.csv").read_text().splitlines()
    (folder / "samples.csv").write_text(
        "\n".join([text[0] + ",frx,fry,frz", *(t + ",0,0,0" for t in text[1:])]) + "\n"
    )
    with pytest.raises(RelcalError, match="not one complete pose"):
        relcal.load_dataset(folder)


# --- degenerate motions: named, never a confident number -----------------------------------------


def test_rotations_about_one_axis_are_named_and_refused_without_a_guess(tmp_path):
    """Every motion turns about the flange's z axis: X's translation along it trades with W's,
    so it is named and the transform is refused (no value printed, no file to load)."""
    flange = flange_poses(20, seed=9, spread=0.6, axis=np.array([0.0, 0.0, 1.0]))
    poses = camera_poses(flange, seed=10)
    result = handeye(relcal.load_dataset(write_flange_dataset(tmp_path / "d", flange, poses)))
    assert any("rotations about parallel axes" in f for f in result.findings)
    assert any("(+0.00, +0.00, +1.00)" in f for f in result.findings)
    he = result.delivered[0]
    assert he.undetermined and "translation" in he.undetermined[0]
    assert result.exported is None and result.verdict.code == "do not deploy"
    from relcal.reporting.handeye_report import handeye_document, handeye_files, handeye_text

    doc = handeye_document(result)
    assert doc["handeye"]["xyz_m"] is None  # never printed as a number
    assert set(handeye_files(result, doc)) == {"results.json"}
    assert "not determined" in handeye_text(doc)


def test_rotations_about_one_axis_are_held_at_the_guess(tmp_path):
    flange = flange_poses(20, seed=9, spread=0.6, axis=np.array([0.0, 0.0, 1.0]))
    poses = camera_poses(flange, seed=10)
    xyz, rpy = tf.to_xyz_rpy(X_TRUE)
    guess = (
        f"handeye: {{xyz: [{xyz[0]:.4f}, {xyz[1]:.4f}, {xyz[2] + 0.004:.4f}], "
        f"rpy: [{np.degrees(rpy[0]):.3f}, {np.degrees(rpy[1]):.3f}, {np.degrees(rpy[2]):.3f}]}}\n"
    )
    folder = write_flange_dataset(tmp_path / "d", flange, poses, extra=guess)
    result = handeye(relcal.load_dataset(folder))
    he = result.delivered[0]
    assert not he.undetermined and he.held
    assert result.exported == "refined"
    # the free direction sits at the guess (4 mm off the truth), with the guess's std
    assert result.handeye[2, 3] == pytest.approx(X_TRUE[2, 3] + 0.004, abs=5e-4)
    assert he.xyz_std[2] == pytest.approx(0.010, rel=0.2)
    assert result.verdict.code == "collect more samples"


def test_tiny_rotations_are_named_and_never_a_confident_number(tmp_path):
    flange = flange_poses(20, seed=11, spread=np.radians(0.15))  # a few tenths of a degree
    poses = camera_poses(flange, seed=12)
    result = handeye(relcal.load_dataset(write_flange_dataset(tmp_path / "d", flange, poses)))
    assert any("rotations too small" in f for f in result.findings)
    he = result.delivered[0]
    assert he.undetermined
    assert result.exported is None and result.verdict.code == "do not deploy"


def test_noisy_poses_give_a_weak_transform_delivered_with_its_std(tmp_path):
    """Motions that turn about every axis, measured with 15 mm and 1.5 deg of noise per pose: X's
    standard deviations pass the 5 mm and 1 deg limits, yet the motions determine every
    direction. Weak, not undetermined: the transform is delivered with its (honest) standard
    deviations, the weak directions are named, the files are written and the verdict asks for
    more samples."""
    flange = flange_poses(20, seed=13)
    cov = np.diag(np.r_[np.full(3, 0.015**2), np.full(3, np.radians(1.5) ** 2)])
    poses = camera_poses(flange, cov=cov, seed=14)
    result = handeye(relcal.load_dataset(write_flange_dataset(tmp_path / "d", flange, poses)))
    he = result.delivered[0]
    assert he.weak and not he.undetermined and not he.held
    assert all("the motions determine it" in w for w in he.weak)
    assert result.exported == "refined" and result.verdict.code == "collect more samples"
    assert "known only roughly" in result.verdict.warnings[0]
    error = _frame_error(result.handeye, X_TRUE)
    assert np.all(np.abs(error[:3]) < 4 * he.xyz_std)  # the std is the estimate's
    from relcal.reporting.handeye_report import handeye_document, handeye_files, handeye_text

    doc = handeye_document(result)
    assert doc["handeye"]["xyz_m"] is not None and doc["handeye"]["weak"] == list(he.weak)
    assert {"handeye.yaml", "handeye.launch.py", "handeye.urdf"} <= set(handeye_files(result, doc))
    assert "weak: translation" in handeye_text(doc)


def test_frames_covariance_tells_free_directions_from_weak_ones():
    """What the motions alone determine, at 1 mm and 0.1 deg per pose: rotations about one axis
    leave X's translation along it free (infinite variance); rotations of 0.15 deg leave it
    beyond 5 mm; motions about every axis determine it to well under a millimetre."""
    from relcal.calibration.handeye_job import frames_covariance

    z = np.array([0.0, 0.0, 1.0])
    for spread, axis, lo, hi in (
        (0.6, z, 1.0, np.inf),  # along z: free
        (np.radians(0.15), None, 5e-3, np.inf),
        (0.45, None, 0.0, 5e-4),
    ):
        flange = flange_poses(20, seed=9, spread=spread, axis=axis)
        cov = frames_covariance(flange, camera_poses(flange, cov=None), X_TRUE, W_TRUE)
        worst = np.sqrt(np.max(np.linalg.eigvalsh(cov[:3, :3])))
        assert lo <= worst <= hi


def test_real_image_sets_deliver_weak_transforms_no_worse_than_opencv(tmp_path):
    """robot_cal_tools' circle grid (eye-in-hand) and ChArUco (eye-to-hand) sets: each image's
    pose is off the wrist's by centimetres, so X is weak (named, delivered with its std, the
    verdict asks for more samples), never refused. On the same held-out samples the refined
    estimate reprojects better than every closed form beyond doubt, and is not worse than the
    best in position beyond doubt."""
    from conftest import DATA

    from relcal.data.imaging import measure
    from relcal.data.importers import import_rct_images

    for name, max_rms in (("rct_circle_grid_eye_in_hand", 1.0), ("rct_charuco_eye_to_hand", 1.5)):
        folder = tmp_path / name
        import_rct_images(DATA / name, folder)
        dataset = relcal.load_dataset(folder)
        result = handeye(dataset, measure(dataset, max_rms=max_rms))
        assert result.exported == "refined" and result.verdict.code == "collect more samples"
        assert any(d.weak for d in result.delivered)
        assert not any(d.undetermined for d in result.delivered)
        val = result.validation
        closed = [m for m in METHODS if np.isfinite(val.rms(m))]
        assert all(val.ratio(m)["px"]["ci95"][1] < 1.0 for m in closed)
        best = min(closed, key=lambda m: val.summary(m)["position_mm"]["rms"])
        assert val.ratio(best)["position_mm"]["ci95"][0] <= 1.0


# --- exports that load ---------------------------------------------------------------------------


def _launch_transforms(text: str) -> dict[tuple[str, str], np.ndarray]:
    """The transforms a launch file's static_transform_publisher nodes publish (parsed, not
    run: ROS is not installed in the tests)."""
    import ast

    from scipy.spatial.transform import Rotation

    out = {}
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "Node":
            kw = {k.arg: ast.literal_eval(k.value) for k in node.keywords}
            assert kw["package"] == "tf2_ros"
            assert kw["executable"] == "static_transform_publisher"
            args = kw["arguments"]
            value = dict(zip(args[::2], args[1::2], strict=True))
            t = np.eye(4)
            t[:3, 3] = [float(value[f"--{c}"]) for c in "xyz"]
            q = [float(value[f"--q{c}"]) for c in "xyzw"]
            t[:3, :3] = Rotation.from_quat(q).as_matrix()
            out[(value["--frame-id"], value["--child-frame-id"])] = t
    return out


def _urdf_transforms(text: str) -> dict[tuple[str, str], np.ndarray]:
    import xml.etree.ElementTree as ET

    out = {}
    for joint in ET.fromstring(text).iter("joint"):
        origin = joint.find("origin")
        xyz = np.array([float(v) for v in origin.get("xyz").split()])
        rpy = np.array([float(v) for v in origin.get("rpy").split()])
        key = (joint.find("parent").get("link"), joint.find("child").get("link"))
        out[key] = tf.from_xyz_rpy(xyz, rpy)
    return out


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand", "robot_world"])
def test_exports_load_back_to_the_same_transforms(tmp_path, mode):
    import yaml
    from yourdfpy import URDF

    from relcal.cli import main

    flange = flange_poses(12, seed=13)
    folder = write_flange_dataset(tmp_path / "d", flange, camera_poses(flange, seed=14), mode=mode)
    out = tmp_path / "out"
    assert main(["handeye", str(folder), "--out", str(out), "--quiet", "--folds", "3"]) == 0
    result = handeye(relcal.load_dataset(folder), folds=3)
    want = {(d.parent, d.child): d.transform for d in result.delivered}
    assert len(want) == (2 if mode == "robot_world" else 1)
    launch = _launch_transforms((out / "handeye.launch.py").read_text())
    urdf = _urdf_transforms((out / "handeye.urdf").read_text())
    loaded = URDF.load(str(out / "handeye.urdf"))
    data = yaml.safe_load((out / "handeye.yaml").read_text())
    from scipy.spatial.transform import Rotation

    for (parent, child), t in want.items():
        assert np.abs(launch[(parent, child)] - t).max() < 1e-12
        assert np.abs(urdf[(parent, child)] - t).max() < 1e-12
        assert np.abs(loaded.get_transform(child, parent) - t).max() < 1e-12
        entry = next(v for v in data.values() if isinstance(v, dict) and v.get("child") == child)
        assert entry["parent"] == parent
        rot = Rotation.from_quat(entry["quaternion"]).as_matrix()
        assert np.abs(rot - t[:3, :3]).max() < 1e-12
        assert (
            np.abs(tf.from_xyz_rpy(np.array(entry["xyz"]), np.array(entry["rpy"])) - t).max()
            < 1e-12
        )
    calib = yaml.safe_load((out / "handeye.calib").read_text())
    first = result.delivered[0].transform
    tr, rq = calib["transform"]["translation"], calib["transform"]["rotation"]
    assert np.allclose([tr["x"], tr["y"], tr["z"]], first[:3, 3], atol=1e-12)
    assert np.allclose(Rotation.from_quat([rq["x"], rq["y"], rq["z"], rq["w"]]).as_matrix(),
                       first[:3, :3], atol=1e-12)  # fmt: skip
    expected = "eye_on_base" if mode == "eye_to_hand" else "eye_in_hand"
    assert calib["parameters"]["calibration_type"] == expected
    doc = yaml.safe_load((out / "results.json").read_text())
    assert doc["handeye"]["xyz_m"] == pytest.approx(list(tf.to_xyz_rpy(first)[0]), abs=1e-12)
    assert ("world" in doc) and ((doc["world"] is not None) == (mode == "robot_world"))


def test_command_refuses_bad_input_with_exit_2(tmp_path, capsys):
    from relcal.cli import main

    flange = flange_poses(8, seed=15)
    folder = write_flange_dataset(tmp_path / "d", flange, camera_poses(flange, cov=None))
    text = (folder / "samples.csv").read_text().splitlines()
    cells = text[3].split(",")
    cells[4] = "2.0"  # fqx: not a unit quaternion any more
    text[3] = ",".join(cells)
    (folder / "samples.csv").write_text("\n".join(text) + "\n")
    assert main(["handeye", str(folder), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "line 4: fqx, fqy, fqz, fqw: expected a unit quaternion" in err
    assert not (folder / "handeye").exists()


def _rewrite_columns(folder, change) -> None:
    """``change(header, rows)`` applied to the samples table of ``folder`` (lists of cells)."""
    lines = [line.split(",") for line in (folder / "samples.csv").read_text().splitlines()]
    change(lines[0], lines[1:])
    (folder / "samples.csv").write_text("\n".join(",".join(c) for c in lines) + "\n")


def _w_first(columns):
    def change(header, rows):
        at = [header.index(c) for c in columns]
        for row in rows:
            values = [row[k] for k in at]
            for k, v in zip(at, values[-1:] + values[:-1], strict=True):
                row[k] = v  # x, y, z, w written as w, x, y, z under the same header

    return change


def _name_w_first(columns):
    def change(header, rows):
        at = [header.index(c) for c in columns]
        for k, name in zip(at, columns[-1:] + columns[:-1], strict=True):
            header[k] = name

    return change


def _shifted(header, rows):
    """Each row's flange pose paired with the next row's measured pose."""
    flange = [header.index(c) for c in ("fx", "fy", "fz", "fqx", "fqy", "fqz", "fqw")]
    first = [rows[0][k] for k in flange]
    for a, b in zip(rows, rows[1:], strict=False):
        for k in flange:
            a[k] = b[k]
    for k, v in zip(flange, first, strict=True):
        rows[-1][k] = v


FLANGE_Q = ["fqx", "fqy", "fqz", "fqw"]
POSE_Q = ["qx", "qy", "qz", "qw"]


@pytest.mark.parametrize(
    "case, expected, fix",
    [
        ("flange w-first", "flange quaternions look w-first", _name_w_first(FLANGE_Q)),
        ("measured w-first", "quaternions look w-first", _name_w_first(POSE_Q)),
        ("flange inverted", "flange poses look inverted", None),
        ("measured inverted", "poses look inverted (board in camera given", None),
        ("measured in mm", "poses look like millimetres", None),
        ("rows shifted", "recorded together", None),
    ],
)
def test_flange_pose_mix_ups_are_refused_naming_the_cause(tmp_path, capsys, case, expected, fix):
    """Logged flange poses beside camera poses that cannot be what they say (a column order, a
    pose direction, a unit, rows out of step): refused before anything is written, exit 2,
    naming the reading that fits; following the fix it names gives the right transform."""
    from relcal.cli import main

    flange = flange_poses(20, seed=21)
    poses = camera_poses(flange, seed=21)
    if case == "flange inverted":
        flange = tf.invert(flange)
    elif case == "measured inverted":
        poses = tf.invert(poses)
    elif case == "measured in mm":
        poses = poses.copy()
        poses[:, :3, 3] *= 1000
    folder = write_flange_dataset(tmp_path / "d", flange, poses)
    if case == "flange w-first":
        _rewrite_columns(folder, _w_first(FLANGE_Q))
    elif case == "measured w-first":
        _rewrite_columns(folder, _w_first(POSE_Q))
    elif case == "rows shifted":
        _rewrite_columns(folder, _shifted)
    out = tmp_path / "he"
    assert main(["handeye", str(folder), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert expected in err and err.count("\n") == 1, err
    assert not out.exists()
    if fix is not None:
        _rewrite_columns(folder, fix)
        assert main(["handeye", str(folder), "--out", str(out), "--quiet"]) == 0
        result = relcal.handeye(relcal.load_dataset(folder))
        error = _frame_error(result.transform("handeye"), X_TRUE)
        assert np.abs(error[:3]).max() < 2e-3 and np.abs(error[3:]).max() < np.radians(0.3)


@pytest.mark.parametrize(("rendered", "declared"), [("eye_to_hand", "eye_in_hand"),
                                                   ("eye_to_hand", "robot_world")])  # fmt: skip
def test_images_of_a_fixed_camera_declared_on_the_flange_are_refused(tmp_path, rendered, declared):
    """Images of a fixed camera looking at the board on the flange, declared as a camera on the
    flange: the camera poses the images give are inverted against the flange's motions, so the
    job is refused naming mode: eye_to_hand; declared right, it runs."""
    folder = render_dataset(tmp_path / "d", rendered, n=10, seed=3)[0]
    spec = folder / "dataset.yaml"
    spec.write_text(spec.read_text().replace(f"mode: {rendered}", f"mode: {declared}"))
    with pytest.raises(RelcalError, match="mode: eye_to_hand"):
        handeye(relcal.load_dataset(folder))
    spec.write_text(spec.read_text().replace(f"mode: {declared}", f"mode: {rendered}"))
    assert handeye(relcal.load_dataset(folder)).verdict.code == "deploy"


def test_a_board_moved_mid_session_is_refused_with_logged_flange_poses(tmp_path, capsys):
    """Flange poses logged by the controller: the board moved by 20 mm and 1 deg after half the
    samples is named (the samples, the step), exit 2, nothing written; sessions of a robot whose
    true geometry is off its controller's by 1 mm and 0.1 deg per parameter raise no alarm."""
    from relcal.calibration.plausibility import check_flange_inputs
    from relcal.cli import main
    from relcal.robot.kinematics import apply_errors, fk, make_layout

    flange = flange_poses(30, seed=5)
    poses = camera_poses(flange, seed=5)
    step = tf.from_xyz_rpy(np.array([0.02, 0.0, 0.0]), np.radians([0.0, 0.0, 1.0]))
    poses[15:] = camera_poses(flange[15:], w=step @ W_TRUE, seed=6)
    folder = write_flange_dataset(tmp_path / "moved", flange, poses)
    assert main(["handeye", str(folder), "--out", str(tmp_path / "he"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "(15 of 30) see the board" in err and "it moved during the session" in err, err
    assert not (tmp_path / "he").exists()
    model = relcal.get_robot("ur5e")
    layout = make_layout(model)
    angles = np.array([n.split("[")[0] in ("theta_off", "alpha", "beta") for n in layout.names])
    for seed in range(10):
        rng = np.random.default_rng(seed)
        q = np.radians([0, -90, 90, -90, -90, 0]) + rng.normal(0, 0.5, (25, 6))
        errors = rng.normal(size=layout.size) * np.where(angles, np.radians(0.1), 1e-3)
        true = fk(apply_errors(model, layout, errors * layout.is_geometric()), q)
        measured = camera_poses(true, seed=seed)
        check_flange_inputs(fk(model, q), measured, [str(k) for k in range(25)], "samples")


def test_joint_mix_ups_are_refused_as_calibrate_refuses_them(tmp_path):
    """With joints and a robot model, the hand-eye job runs calibrate's checks: two joint
    columns swapped are named, and so is a robot-world session whose poses are inverted."""
    model = relcal.get_robot("ur5e")
    rng = np.random.default_rng(3)
    q = np.radians([0, -90, 90, -90, -90, 0]) + rng.normal(0, 0.4, (20, 6))
    poses = W_TRUE @ relcal.fk(model, q) @ X_TRUE
    with pytest.raises(RelcalError, match="joint columns q2 and q3 look swapped"):
        handeye(relcal.Dataset.from_arrays(model, q[:, [0, 2, 1, 3, 4, 5]], poses))
    inverted = relcal.Dataset.from_arrays(model, q, tf.invert(poses), mode="robot_world")
    with pytest.raises(RelcalError, match="poses look inverted"):
        handeye(inverted)


# --- real data -----------------------------------------------------------------------------------


def test_real_robot_world_laser_tracker_set():
    """The IPA UR10's 25 flange poses and tracker poses (read as exported): the refined estimate
    is not worse than the best closed form beyond doubt, and the probe sits about 93 mm along
    the flange's z axis (the data set's description)."""
    import pathlib

    folder = pathlib.Path(__file__).parent.parent / "examples" / "ipa-ur10-handeye"
    result = handeye(relcal.load_dataset(folder))
    assert result.mode == "robot_world" and len(result.delivered) == 2
    x = result.transform("handeye")
    # along the x axis of the flange frame (ROS-Industrial's flange frame points x out of the
    # flange, where tool0 points z)
    assert x[:3, 3] == pytest.approx([0.093, 0.0, 0.0], abs=0.002)
    val = result.validation
    best = min((m for m in METHODS if np.isfinite(val.rms(m))), key=val.rms)
    ratio = val.ratio(best)["position_mm"]
    assert ratio["ci95"][0] <= 1.0


@pytest.mark.parametrize(
    ("change", "named"),
    [
        (("euler: XYZ", "euler: xyz"), "look like the rotation sequence XYZ, not xyz"),
        (("euler: XYZ", "euler: ZYX"), "look like the rotation sequence XYZ, not ZYX"),
        (("position_unit: mm", "position_unit: m"), "poses look like millimetres"),
    ],
)
def test_real_tracker_export_read_another_way_is_refused_naming_the_field(tmp_path, change, named):
    """The IPA UR10 tracker export with its ``dataset.yaml`` declaring the wrong rotation
    sequence or position unit (the rotations then agree to 5 deg: no check of the rotations
    alone would see it; the translations disagree by 190 mm): refused, naming the field and the
    value that fits."""
    import pathlib

    example = pathlib.Path(__file__).parent.parent / "examples" / "ipa-ur10-handeye"
    spec = (example / "dataset.yaml").read_text()
    samples = (example / "../../../shared/data/ipa_ur10/calibration_handeye.csv").resolve()
    spec = spec.replace("../../../shared/data/ipa_ur10/calibration_handeye.csv", str(samples))
    assert change[0] in spec
    (tmp_path / "dataset.yaml").write_text(spec.replace(*change))
    with pytest.raises(RelcalError, match=named):
        handeye(relcal.load_dataset(tmp_path))


def test_image_fit_covariance_counts_each_images_pose_error():
    """Board points seen from flange poses that carry their own errors (a settling arm, the
    robot's repeatability: 30 um and 0.02 deg per image, unseen by the fit) beside 0.05 px of
    pixel noise: over 25 data sets the refined X's errors have the spread the fit's covariance
    predicts (Mahalanobis mean 1 per component; the pixels' noise alone: 41); the per-image
    pose noise is found."""
    from relcal.calibration.handeye_fit import Corners, fit_images
    from relcal.vision.camera import Camera

    rng = np.random.default_rng(21)
    n = 12
    grid = np.stack(np.meshgrid(np.arange(9), np.arange(7), indexing="ij"), -1).reshape(-1, 2)
    points = np.c_[grid * 0.02, np.zeros(len(grid))]
    camera = Camera(320.0, 320.0, 199.5, 149.5, (), 400, 300)
    x = tf.from_xyz_rpy(np.array([0.03, 0.05, 0.10]), np.radians([3.0, -4.0, 110.0]))
    base_board = tf.homogeneous(tf.rot_x(np.pi), np.array([0.45, -0.05, 0.0]))
    w = tf.invert(base_board)
    turns = Rotation.from_rotvec(rng.normal(size=(n, 3)) * [0.25, 0.25, 0.6]).as_matrix()
    cam_rot = tf.rot_x(np.pi) @ turns
    target = base_board[:3, :3] @ np.array([0.08, 0.06, 0.0]) + base_board[:3, 3]
    pos = target - 0.35 * cam_rot[:, :, 2] + rng.normal(size=(n, 3)) * 0.02
    flange = tf.homogeneous(cam_rot, pos) @ tf.invert(x)
    sd = np.r_[np.full(3, 30e-6), np.full(3, np.radians(0.02))]
    d2, pose_std = [], []
    for seed in range(25):
        r = np.random.default_rng(100 + seed)
        moved = flange @ tf.from_vector(r.normal(size=(n, 6)) * sd)  # where the arm really was
        board_in_camera = tf.invert(w @ moved @ x)
        corners = []
        for t in board_in_camera:
            cam_pts = points @ t[:3, :3].T + t[:3, 3]
            uv = cam_pts[:, :2] / cam_pts[:, 2:] * 320.0 + [199.5, 149.5]
            corners.append(Corners(points, uv + r.normal(size=uv.shape) * 0.05))
        start = x @ tf.from_vector(np.r_[0.001, -0.001, 0.002, 0.01, 0.01, -0.01])
        fit = fit_images(flange, corners, camera, start, w, "eye_in_hand", reject=False)
        err = _frame_error(fit.handeye, x)
        d2.append(err @ np.linalg.solve(fit.covariance[:6, :6], err))
        pose_std.append(np.sqrt(np.diag(fit.noise))[3:].mean())
    spread = np.mean(d2) / 6  # 1 for a covariance that predicts the errors (sampling +-12 %)
    assert 0.7 < spread < 1.35, spread
    assert fit.pixel_sigma == pytest.approx(0.05, rel=0.1)
    assert np.median(pose_std) > np.radians(0.01)  # the pose noise is found


def test_logged_flange_poses_are_used_beside_a_robot_model():
    """Joints with a robot model and the controller's flange poses (its calibrated kinematics:
    the nominal model with planted errors), as ``relcal capture`` records them: the hand-eye uses
    the logged poses and recovers X from noise-free data exactly, where the nominal model's
    forward kinematics would not; the same with no model at all (``Dataset.from_arrays(None,
    None, poses, flange=...)``)."""
    from relcal.robot.kinematics import apply_errors, fk, make_layout
    from relcal.sim.scenario import random_errors

    model = relcal.get_robot("ur5e")
    rng = np.random.default_rng(5)
    q = np.radians([0, -90, 90, -90, -90, 0]) + rng.normal(0, 0.5, (16, 6))
    layout = make_layout(model)
    controller = apply_errors(model, layout, random_errors(layout, rng))
    flange = fk(controller, q)
    poses = W_TRUE @ flange @ X_TRUE
    logged = handeye(relcal.Dataset.from_arrays(model, q, poses, flange=flange), folds=3)
    assert logged.source == "the logged flange poses"
    assert np.abs(logged.handeye - X_TRUE).max() < 1e-8
    nominal = handeye(relcal.Dataset.from_arrays(model, q, poses), folds=3)
    assert np.abs(nominal.handeye[:3, 3] - X_TRUE[:3, 3]).max() > 1e-4
    alone = handeye(relcal.Dataset.from_arrays(None, None, poses, flange=flange), folds=3)
    assert np.abs(alone.handeye - logged.handeye).max() < 1e-9


@pytest.mark.parametrize(
    "args, match",
    [
        ((None, None), "give both"),
        (("ur5e", None), "give both"),
    ],
)
def test_from_arrays_flange_is_checked(args, match):
    from relcal.errors import ArgumentError

    flange = flange_poses(6, seed=1)
    poses = camera_poses(flange, cov=None)
    with pytest.raises(ArgumentError, match=match):
        relcal.Dataset.from_arrays(*args, poses)
    mm = flange.copy()
    mm[:, :3, 3] *= 1000.0
    with pytest.raises(ArgumentError, match="millimetres given"):
        relcal.Dataset.from_arrays(None, None, poses, flange=mm)
    with pytest.raises(ArgumentError, match=r"flange: shape \(5, 4, 4\), expected \(6, 4, 4\)"):
        q = np.zeros((6, 6)) + np.arange(6)[:, None] * 0.1
        relcal.Dataset.from_arrays("ur5e", q, poses, flange=flange[:5])


def test_images_about_one_axis_are_held_at_the_guess(tmp_path):
    """Rendered images turning only about the camera's optical axis leave X's translation along
    it free: refused without a guess, held at the ``handeye:`` guess of dataset.yaml (5 mm off
    the truth along that axis) with the guess's standard deviation when one is given, as for
    poses."""
    folder, x, _ = render_dataset(tmp_path / "free", "eye_in_hand", spread=(0.0, 0.0, 0.6))
    free = handeye(relcal.load_dataset(folder), folds=3)
    assert free.exported is None and free.delivered[0].undetermined
    axis = x[:3, 2]  # the optical axis in the flange frame
    xyz, rpy = tf.to_xyz_rpy(x)
    off = xyz + 0.005 * axis
    guess = (
        f"handeye: {{xyz: [{off[0]:.6f}, {off[1]:.6f}, {off[2]:.6f}], "
        f"rpy: [{np.degrees(rpy[0]):.4f}, {np.degrees(rpy[1]):.4f}, {np.degrees(rpy[2]):.4f}]}}\n"
    )
    folder, x, _ = render_dataset(tmp_path / "held", "eye_in_hand", spread=(0.0, 0.0, 0.6),
                                  extra=guess)  # fmt: skip
    held = handeye(relcal.load_dataset(folder), folds=3)
    he = held.delivered[0]
    assert not he.undetermined and he.held and held.exported == "refined"
    along = (held.handeye[:3, 3] - x[:3, 3]) @ axis
    assert along == pytest.approx(0.005, abs=5e-4)  # the free direction sits at the guess
    across = held.handeye[:3, 3] - x[:3, 3] - along * axis
    assert np.linalg.norm(across) < 1e-3  # the determined ones stay the images'
    std_along = np.sqrt(axis @ np.diag(he.xyz_std**2) @ axis)
    assert std_along == pytest.approx(0.010, rel=0.3)
    assert held.verdict.code == "collect more samples"


def test_one_static_transform_writer_for_both_launch_files():
    """relcal handeye's launch file and relcal calibrate's overlay write their static transform
    with the same function, whose node gives back the transform to round-off."""
    import inspect

    from relcal.reporting import handeye_report, ros2
    from relcal.reporting.ros2 import static_transform_node

    t = tf.from_xyz_rpy(np.array([0.012, -0.34, 0.5]), np.radians([-170.0, 89.9, 33.0]))
    text = static_transform_node(t, '"tool0"', '"camera"', "relcal_test", indent=4)
    found = _launch_transforms(text.strip())
    assert np.abs(found[("tool0", "camera")] - t).max() < 1e-15
    for module in (handeye_report, ros2):  # neither spells the node out itself
        source = inspect.getsource(module).replace(inspect.getsource(static_transform_node), "")
        assert "static_transform_node(" in source
        assert 'executable="static_transform_publisher"' not in source


class _Tables:
    """The tables of an HTML page, by the id of the section they are in: lists of rows of cell
    texts (header row first)."""

    def __init__(self, text: str) -> None:
        from html.parser import HTMLParser

        self.by_section: dict[str, list[list[list[str]]]] = {}
        self.text = []
        tables = self.by_section
        owner = self

        class Parser(HTMLParser):
            section, row, cell = None, None, None

            def handle_starttag(self, tag, attrs):
                if tag == "section":
                    self.section = dict(attrs).get("id")
                elif tag == "table":
                    tables.setdefault(self.section, []).append([])
                elif tag == "tr":
                    self.row = []
                    tables[self.section][-1].append(self.row)
                elif tag in ("td", "th"):
                    self.cell = ""

            def handle_endtag(self, tag):
                if tag in ("td", "th"):
                    self.row.append(self.cell.strip())
                    self.cell = None

            def handle_data(self, data):
                owner.text.append(data)
                if self.cell is not None:
                    self.cell += data

        Parser().feed(text)
        self.text = " ".join(self.text)


def test_report_shows_the_verdict_and_every_methods_held_out_errors(tmp_path):
    import json

    from relcal.cli import main

    flange = flange_poses(14, seed=16)
    folder = write_flange_dataset(tmp_path / "d", flange, camera_poses(flange, seed=17))
    report, doc_path = tmp_path / "he.html", tmp_path / "he.json"
    assert main(["handeye", str(folder), "--out", str(tmp_path / "out"), "--quiet",
                 "--report", str(report), "--json", str(doc_path)]) in (0, 1)  # fmt: skip
    doc = json.loads(doc_path.read_text())
    page = _Tables(report.read_text())
    assert doc["verdict"]["text"] in page.text
    methods = page.by_section["held-out"][0]
    assert methods[0][:3] == ["method", "position mm", "orientation deg"]
    rows = {r[0].replace(" (favoured)", ""): r for r in methods[1:]}
    val = doc["validation"]
    assert len(rows) == len(val["methods"]) == 1 + len(METHODS)
    for m in val["methods"]:
        row = rows[m["title"]]
        rms, (lo, hi) = m["position_mm"]["rms"], m["position_mm"]["ci95"]
        assert row[1] == f"{rms:.3f} [{lo:.3f}, {hi:.3f}]"
        if m["method"] != "refined":
            ratio = m["refined_over_it"]["position_mm"]["after_over_before"]
            assert row[3].startswith(f"{ratio:.3f} [")
    favoured = next(r for r in methods[1:] if r[0].endswith("(favoured)"))
    assert favoured[0].startswith(title(val["favoured"]))
    samples = page.by_section["samples"][0]
    assert len(samples) - 1 == val["n_samples"] == 14
    assert {r[0] for r in samples[1:]} == {s["id"] for s in val["samples"]}
    closed = page.by_section["closed-forms"][0]
    assert len(closed) - 1 == len(METHODS)


def test_pose_fit_std_is_honest_with_few_samples():
    """12 noisy poses, the noise learned from them (a full 6x6 matrix): the delivered camera pose
    of eye-to-hand (W^-1) and X of eye-in-hand have the spread their standard deviations say
    over 100 data sets (RMS of error over std per component; 1.7 to 2.1 without the small-sample
    inflation of the learned weights, :func:`weight_inflation`)."""
    from relcal.calibration.handeye_job import _frames_default, deliver

    for mode, truth in (("eye_to_hand", tf.invert(W_TRUE)), ("eye_in_hand", X_TRUE)):
        z = []
        for seed in range(100):
            flange = flange_poses(12, seed=1000 + seed)
            model, q = flange_chain(flange)
            fit = fit_poses(model, q, camera_poses(flange, seed=seed), X_TRUE, W_TRUE, reject=False)
            d = deliver(mode, fit, _frames_default(mode))[0]
            moved = d.transform[:3, 3] - truth[:3, 3]
            turned = tf.log_rotation(d.transform[:3, :3] @ truth[:3, :3].T)
            z.append(np.r_[moved / d.xyz_std, turned / d.rotation_std])
        rms = np.sqrt(np.mean(np.square(z), axis=0))
        assert np.all(rms < 1.35) and np.all(rms > 0.5), (mode, rms)
