"""Command-line gaps a user hits: measure --max-rms, intrinsics calibrated from the images saved
with the outputs, the robot_cal_tools image sets imported, identified parameters and rejected
frames printed, a k-fold progress bar, and compensate's summary, singularity warning and joint
limits."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import DATA
from helpers_dataset import synthetic_dataset

from relcal.cli import main
from relcal.data.dataset import load_dataset
from relcal.robot.kinematics import apply_errors, fk, make_layout
from relcal.robot.loading import get_robot
from relcal.robot.model import dump_model
from relcal.vision.camera import load_camera

CHARUCO = DATA / "rct_charuco_eye_to_hand"


@pytest.fixture(scope="module")
def charuco(tmp_path_factory):
    out = tmp_path_factory.mktemp("rct") / "charuco"
    assert main(["import", "rct-images", str(CHARUCO), "--out", str(out), "--quiet"]) == 0
    return out


def test_imported_image_set_reproduces_the_recorded_poses(charuco):
    import yaml
    from scipy.spatial.transform import Rotation

    dataset = load_dataset(charuco)
    assert dataset.mode == "eye_to_hand" and len(dataset.ids) == 16
    entries = yaml.safe_load((CHARUCO / "cal_data.yaml").read_text())
    for k in (0, 7, 15):
        pose = yaml.safe_load((CHARUCO / entries[k]["pose"]).read_text())
        reached = fk(dataset.model, dataset.q[k][None])[0]
        quat = Rotation.from_matrix(reached[:3, :3]).as_quat()
        want = np.array([pose["qx"], pose["qy"], pose["qz"], pose["qw"]])
        assert np.allclose(reached[:3, 3], [pose["x"], pose["y"], pose["z"]], atol=1e-9)
        assert min(np.abs(quat - want).max(), np.abs(quat + want).max()) < 1e-9
        # a copy of the image inside the dataset folder (it still loads when moved)
        assert dataset.images[k].is_relative_to(charuco.resolve())
        assert dataset.images[k].read_bytes() == (CHARUCO / entries[k]["image"]).read_bytes()


def test_measure_max_rms_decides_which_charuco_frames_are_posed(charuco, tmp_path, capsys):
    assert main(["measure", str(charuco), "--out", str(tmp_path / "m1")]) == 0
    strict = json.loads((tmp_path / "m1/measurements.json").read_text())
    printed = capsys.readouterr().out
    assert main(["measure", str(charuco), "--out", str(tmp_path / "m2"), "--max-rms", "1.5"]) == 0
    loose = json.loads((tmp_path / "m2/measurements.json").read_text())
    assert loose["n_posed"] == 16 and loose["rejected"] == []
    assert 12 <= strict["n_posed"] < 16  # 1.02 and 1.06 px frames above the default 1 px
    for r in strict["rejected"]:
        assert "above the 1.000 px limit" in r["reason"]
        assert f"rejected {r['id']}" in printed


def test_calibrated_intrinsics_saved_and_parameters_printed(tmp_path, capsys):
    ds = tmp_path / "charuco"
    argv = ["import", "rct-images", str(CHARUCO), "--out", str(ds), "--intrinsics", "calibrate"]
    assert main([*argv, "--quiet"]) == 0
    out = tmp_path / "cal"
    code = main(["calibrate", str(ds), "--out", str(out), "--max-rms", "1.5"])
    printed = capsys.readouterr().out
    assert code == 0
    camera = load_camera(out / "camera.yaml")
    results = json.loads((out / "results.json").read_text())
    assert results["run_id"] in (out / ".relcal-set.json").read_text()
    assert camera.width == 1600 and camera.height == 1200 and 1000 < camera.fx < 2000
    assert abs(camera.fx - 1400.0) > 1.0  # computed from the images, not the 1400 px guess
    shown = [r for r in results["parameters"] if r["status"] in ("estimated", "combination")]
    assert all(f"  {r['name']:<14} {r['error']:+.4g} +- " in printed for r in shown)


def test_kfold_shows_a_progress_bar(tmp_path, capsys):
    syn = synthetic_dataset(tmp_path / "d", n=16)
    argv = ["calibrate", str(syn.root), "--out", str(tmp_path / "o"), "--kfold", "3"]
    assert main(argv) == 0
    assert "cross-validation" in capsys.readouterr().err
    assert main([*argv, "--quiet"]) == 0
    assert capsys.readouterr().err == ""


@pytest.fixture
def calibrated(tmp_path):
    """A perturbed A465 written as a calibrated model."""
    nominal = get_robot("a465")
    layout = make_layout(nominal)
    errors = np.random.default_rng(4).normal(0, 1e-3, layout.size)
    path = tmp_path / "cal.yaml"
    path.write_text(dump_model(apply_errors(nominal, layout, errors)))
    return path


def test_compensate_summary_and_singularity_warning(calibrated, tmp_path, capsys):
    targets = tmp_path / "t.csv"
    targets.write_text("id,q1,q2,q3,q4,q5,q6\nfine,10,20,30,40,50,60\nwrist,10,20,30,40,1,60\n")
    argv = ["compensate", "--model", str(calibrated), "--targets", str(targets)]
    assert main([*argv, "--nominal", "a465", "--out", str(tmp_path / "j.csv")]) == 0
    err = capsys.readouterr().err
    assert "2 target(s) compensated, largest correction" in err and "j.csv" in err
    assert "target wrist is near a singularity" in err and "target fine" not in err
    assert main([*argv, "--nominal", "a465", "--out", str(tmp_path / "k.csv"), "--quiet"]) == 0
    assert capsys.readouterr().err == ""
