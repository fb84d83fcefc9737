"""Synthetic images end to end: a perturbed A465 photographs a chessboard; the rendered images go
through detection, pose, identification and validation, and the result is checked against the
truth with the predicted standard deviations."""

import numpy as np
import pytest

from relcal.calibration.pipeline import calibrate
from relcal.data.dataset import load_dataset
from relcal.data.imaging import measure
from relcal.reporting.documents import validation_document
from relcal.robot.loading import get_robot
from relcal.robot.model import auto_hayati
from relcal.sim.synth import write_image_dataset
from relcal.vision.camera import Camera

# Half the linear resolution of the default 2448 x 2048 / 8 mm camera, same field of view, to keep
# the test fast; `relcal simulate --images` uses the full-size camera.
CAMERA = Camera(
    fx=1159.5,
    fy=1159.5,
    cx=611.5,
    cy=511.5,
    distortion=(-0.08, 0.05, 0.0, 0.0, 0.0),
    width=1224,
    height=1024,
)


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    root = tmp_path_factory.mktemp("images")
    model = auto_hayati(get_robot("a465"))
    truth = write_image_dataset(root, model, n_images=40, seed=2, camera=CAMERA, progress=False)
    dataset = load_dataset(root)
    measured = measure(dataset, progress=False)
    return truth, measured, calibrate(dataset, measured, holdout=0.25, seed=0)


def test_images_are_posed_and_held_out_error_drops_fivefold(calibration):
    truth, measured, cal = calibration
    assert measured.ok.sum() >= 30
    assert np.nanmax(measured.rms_px) < 0.5
    val = validation_document(cal.validation)
    base, cal = val["baseline"], val["calibrated"]
    assert base["position_mm"]["rms"] > 5 * cal["position_mm"]["rms"]
    assert base["orientation_deg"]["rms"] > 5 * cal["orientation_deg"]["rms"]


def test_identified_parameters_within_three_predicted_std(calibration):
    truth, _, cal = calibration
    n = truth.layout.size
    ok = cal.result.identifiable[:n]
    assert ok.sum() >= 15
    err = cal.result.params[:n][ok] - truth.errors[ok]
    std = cal.std[:n][ok]
    assert np.all(np.isfinite(std)) and np.all(std > 0)
    assert np.all(np.abs(err) < 3 * std), list(
        zip(np.array(truth.layout.names)[ok], err / std, strict=True)
    )


def test_truth_table_on_the_calibration_layout(calibration):
    """The calibration's layout adds model selection's non-geometric candidates to the truth's
    (``relcal simulate --images`` once ended in an IndexError indexing the truth with it): the
    truth maps by name, terms it does not have were not planted (0)."""
    from relcal.reporting.documents import parameter_status
    from relcal.reporting.text import format_truth

    truth, _, cal = calibration
    layout = cal.problem.layout
    assert layout.size > truth.layout.size  # the candidates' scale and harmonic terms
    true = truth.errors_on(layout)
    assert true.shape == (layout.size,)
    for name, value in zip(truth.layout.names, truth.errors, strict=True):
        assert true[layout.names.index(name)] == value
    assert not true[~layout.is_geometric()].any()
    estimated = np.array([s == "estimated" for s in parameter_status(cal)[: layout.size]])
    table = format_truth(layout, true, cal.result, estimated)
    assert len(table.splitlines()) == 2 + estimated.sum()
    shown = format_truth(layout, true, cal.result)  # default: every identifiable parameter
    assert (
        "scale[" in shown
        or not cal.result.identifiable[: layout.size][~layout.is_geometric()].any()
    )
    with pytest.raises(ValueError, match="shape"):
        format_truth(layout, truth.errors, cal.result)


def test_camera_scaled_keeps_the_field_of_view():
    from relcal.sim.synth import DEFAULT_CAMERA

    half = DEFAULT_CAMERA.scaled(0.5)
    assert half == CAMERA
    assert DEFAULT_CAMERA.scaled(1) is DEFAULT_CAMERA


def test_image_files_carry_the_validated_number(calibration, tmp_path):
    """Camera poses measured from the rendered images: model.yaml, which holds the validated
    model, carries the validated number, and recomputed from the file read back and the
    hand-eye beside it, the relative pose errors of the validation's pairs give it again."""
    from helpers_artifacts import files_carry_the_validated_number, model_file, relative_rms

    from relcal.calibration.artifacts import read_back
    from relcal.calibration.measurement import world_of

    _, _, cal = calibration
    assert cal.dataset.images is not None
    files_carry_the_validated_number(cal)
    model = model_file(cal)
    loaded = read_back("model.yaml", model.content, cal.dataset.model, tmp_path)
    world = world_of(cal.problem, cal.result.params)
    assert relative_rms(cal, loaded, cal.handeye, world) == pytest.approx(model.rms(), rel=1e-9)
