"""Each exported file's own held-out number, for every measurement kind: the file that holds the
validated model gets the validated number (to round-off), and a number recomputed here from the
file read back, by plain NumPy, agrees with it.

The kinds: relative poses (a synthetic A465), tracker points (TIAGo Pro, real) and coincidences
(MUKCa Panda, real: its tool point was counted twice, 1.078 mm printed for the model file of a
0.527 mm validation); rendered board images in tests/test_images_end_to_end.py (its images).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import DATA
from helpers_artifacts import files_carry_the_validated_number, model_file, relative_rms
from helpers_dataset import synthetic_dataset

from relcal.calibration.artifacts import HOLD_THE_TOOL, read_back
from relcal.calibration.measurement import world_of
from relcal.calibration.pipeline import calibrate
from relcal.data.dataset import load_dataset
from relcal.data.imaging import measure
from relcal.data.importers import import_mukca
from relcal.robot.kinematics import fk

MUKCA = DATA / "mukca"
TIAGO_POSITIONS = Path(__file__).resolve().parents[1] / "examples" / "tiago-pro-positions"


def _calibrate(root, **options):
    dataset = load_dataset(root)
    measured = measure(dataset, workers=1, progress=False)  # images: no pool to start
    return calibrate(dataset, measured, seed=0, **options)


# --- relative poses and images ------------------------------------------------------------------


def test_pose_files_carry_the_validated_number(tmp_path):
    syn = synthetic_dataset(tmp_path / "poses", n=40, noise=(5e-5, 1e-4), seed=3)
    cal = _calibrate(syn.root, nongeometric="none")
    assert cal.problem.formulation == "board" and cal.geometry is None
    files_carry_the_validated_number(cal)
    model = model_file(cal)
    loaded = read_back("model.yaml", model.content, cal.dataset.model, tmp_path)
    rms = relative_rms(cal, loaded, cal.handeye, world_of(cal.problem, cal.result.params))
    assert rms == pytest.approx(model.rms(), rel=1e-9)


def test_pose_model_file_with_nongeometric_terms_carries_the_validated_number(tmp_path):
    """A refit for the geometry-only files: model.yaml still holds the validated model."""
    syn = synthetic_dataset(tmp_path / "scale", n=40, seed=4, nongeometric=("scale",))
    cal = _calibrate(syn.root, selection="all")
    assert cal.geometry is not None  # the URDF holds a geometry-only refit
    files_carry_the_validated_number(cal)


# --- tracker points ------------------------------------------------------------------------------


@pytest.mark.skipif(not (DATA / "tiago_pro").is_dir(), reason="real data not available")
def test_point_files_carry_the_validated_number(tmp_path):
    from relcal.calibration.measurement import tracker_frames

    cal = _calibrate(TIAGO_POSITIONS, nongeometric="none")
    assert cal.problem.formulation == "tracker"
    files_carry_the_validated_number(cal)
    model = model_file(cal)
    loaded = read_back("model.yaml", model.content, cal.dataset.model, tmp_path)
    instrument, marker = tracker_frames(cal.problem, cal.result.params)
    samples = cal.validation.pairs[:, 0]
    tip = fk(loaded, cal.dataset.q[samples])
    predicted = (instrument @ tip @ np.r_[marker, 1.0])[:, :3]
    measured = cal.measurements.poses[samples, :3, 3]
    rms = np.sqrt(np.mean(np.sum((predicted - measured) ** 2, axis=1))) * 1e3
    assert rms == pytest.approx(model.rms(), rel=1e-9)


# --- coincidences --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def panda(tmp_path_factory):
    if not MUKCA.is_dir():
        pytest.skip("real data not available")
    root = tmp_path_factory.mktemp("mukca") / "panda_1"
    import_mukca(
        MUKCA / "data" / "panda_1",
        root,
        urdf=MUKCA / "urdf" / "panda.urdf",
        tip="ball_link",
        distance=0.050,
    )
    return root


def _spread_rms(cal, loaded, tool_point) -> float:
    """The held-out spread (mm) recomputed from a file's forward kinematics: each held-out
    sample's ball centre from its group's mean centre."""
    val = cal.validation
    samples = val.samples
    tip = fk(loaded, cal.dataset.q[samples])
    ball = (tip @ np.r_[tool_point, 1.0])[:, :3]
    groups = np.array([cal.dataset.groups[k] for k in samples])
    spread = np.empty(len(samples))
    for g in np.unique(groups):
        mine = groups == g
        spread[mine] = np.linalg.norm(ball[mine] - ball[mine].mean(axis=0), axis=1)
    return float(np.sqrt(np.mean(spread**2))) * 1e3


def test_coincidence_model_file_carries_the_validated_spread(panda, tmp_path):
    """Defaults (joint scales chosen): model.yaml holds the validated model and the tool
    point; its number is the validated spread, and recomputed from the file alone (the ball
    centre at its tip) it is the same."""
    cal = _calibrate(panda)
    assert cal.problem.formulation == "coincidence" and cal.geometry is not None
    files_carry_the_validated_number(cal)
    model = model_file(cal)
    loaded = read_back("model.yaml", model.content, cal.dataset.model, tmp_path)
    assert _spread_rms(cal, loaded, np.zeros(3)) == pytest.approx(model.rms(), rel=1e-9)


def test_coincidence_files_hold_the_tool_point_or_are_given_it(panda, tmp_path):
    """Geometry only: every file carries the validated spread. model.yaml, the URDF and the
    origin corrections end at the ball (zero tool point beside them); Franka's kinematics file
    holds the joints only, so the fitted tool point accompanies it, as its frames say."""
    cal = _calibrate(panda, nongeometric="none")
    assert cal.geometry is None
    files_carry_the_validated_number(cal)
    from relcal.reporting.documents import results_document

    doc = results_document(cal)
    fitted = np.array(doc["tool_point_xyz_m"])
    assert np.linalg.norm(fitted) > 1e-3  # a tool point to count twice
    for art, entry in zip(cal.artifacts, doc["artifacts"]["files"], strict=True):
        folder = tmp_path / art.name.replace(".", "_")
        folder.mkdir()
        loaded = read_back(art.name, art.content, cal.dataset.model, folder)
        tool = np.array(entry["frames"]["tool_point_xyz_m"])
        if art.name in HOLD_THE_TOOL:
            np.testing.assert_allclose(tool, 0.0, atol=1e-15)
        else:
            np.testing.assert_allclose(tool, fitted, atol=1e-15)
        assert _spread_rms(cal, loaded, tool) == pytest.approx(art.rms(), rel=1e-9), art.name
