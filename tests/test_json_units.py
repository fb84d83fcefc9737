"""One unit per quantity across the JSON documents: results.json (``calibrate``), the verify
document and the history and compare documents give a transform as ``{"xyz_m", "rpy_deg"}``, a
point in metres under ``*_xyz_m``, a parameter in the unit results.json gives it (mm, deg, ...,
named in ``unit``), held-out errors in mm and deg (verify's hand-eye was in radians where
results.json has degrees; history gave parameters in SI where results.json gives mm and deg).

A simulated A465 with a wrist camera, calibrated on Monday and verified on Tuesday."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers_fleet import make_robot, write_session
from helpers_sim import HANDEYE

from relcal import geometry as tf
from relcal.cli import main
from relcal.reporting.quantities import TRANSFORM_KEYS, parameter_json, transform_json


def _walk(doc, path=""):
    """Every ``(path, key, value)`` of a JSON document."""
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield path, k, v
            yield from _walk(v, f"{path}.{k}")
    elif isinstance(doc, list):
        for k, v in enumerate(doc):
            yield from _walk(v, f"{path}[{k}]")


def _transforms(doc) -> list[tuple[str, dict]]:
    return [
        (f"{p}.{k}", v)
        for p, k, v in _walk(doc)
        if isinstance(v, dict) and ("xyz_m" in v or "rpy_deg" in v or "rpy_rad" in v)
    ]


@pytest.fixture(scope="module")
def documents(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("units")
    robot = make_robot("a465", "arm3", 7)
    monday = write_session(tmp / "monday", robot, 1)
    tuesday = write_session(tmp / "tuesday", robot, 2)
    db = tmp / "history.sqlite"
    argv = ["calibrate", str(monday), "--out", str(tmp / "cal"), "--quiet", "--registry", str(db)]
    assert main([*argv, "--json", str(tmp / "results.json")]) == 0
    argv = ["calibrate", str(tuesday), "--out", str(tmp / "cal2"), "--quiet", "--registry", str(db)]
    assert main(argv) == 0
    argv = ["verify", str(tmp / "cal"), str(tuesday), "--quiet", "--json", str(tmp / "v.json")]
    assert main(argv) in (0, 1)
    argv = ["history", "arm3", "--registry", str(db), "--json", str(tmp / "h.json")]
    assert main(argv) == 0
    argv = ["compare", "1", "2", "--registry", str(db), "--json", str(tmp / "c.json")]
    assert main(argv) == 0
    names = ("results.json", "v.json", "h.json", "c.json")
    return robot, {n: json.loads((tmp / n).read_text()) for n in names}


def test_every_transform_is_one_shape_in_metres_and_degrees(documents):
    robot, docs = documents
    seen = 0
    for name, doc in docs.items():
        for where, value in _transforms(doc):
            assert tuple(value) == TRANSFORM_KEYS, (name, where, value)
            seen += 1
        radians = [(p, k) for p, k, _ in _walk(doc) if k.endswith(("_rad", "_radians"))]
        assert not radians, (name, radians)
    assert seen >= 4  # results: hand-eye and each file's; verify: both models' hand-eyes
    # the same hand-eye, calibrated on Monday and refitted on Tuesday: the same numbers
    calibrated = docs["results.json"]["handeye"]
    refitted = docs["v.json"]["nuisance"]["fitted_to_all_samples"]["calibrated"]["values"]
    refitted = refitted["handeye"]
    np.testing.assert_allclose(refitted["rpy_deg"], calibrated["rpy_deg"], atol=0.05)
    np.testing.assert_allclose(refitted["xyz_m"], calibrated["xyz_m"], atol=5e-4)
    truth = transform_json(robot.handeye)  # near it (the hand-eye absorbs what cancels)
    np.testing.assert_allclose(calibrated["rpy_deg"], truth["rpy_deg"], atol=2.0)
    assert np.abs(transform_json(HANDEYE)["rpy_deg"]).max() > 5  # degrees, not radians, count
    back = tf.from_xyz_rpy(np.array(calibrated["xyz_m"]), np.radians(calibrated["rpy_deg"]))
    files = docs["results.json"]["artifacts"]["files"]
    for entry in files:  # each file's own hand-eye: the calibration's (one fit)
        assert entry["frames"]["handeye"] == calibrated, entry["file"]
    assert np.allclose(back[:3, :3] @ back[:3, :3].T, np.eye(3))


def test_parameters_and_errors_carry_one_unit_in_every_document(documents):
    _, docs = documents
    results, history, compare = docs["results.json"], docs["h.json"], docs["c.json"]
    run = history["runs"][0]
    assert run["id"] == 1 and run["session"] == "monday"
    ours = {p["name"]: p for p in results["parameters"]}
    theirs = {p["name"]: p for p in run["parameters"]}
    compared = 0
    for name, p in theirs.items():
        mine = ours[name]
        assert p["unit"] == mine["unit"], name  # mm, deg, ppm ... in both
        assert p["label"] == mine["label"], name
        if p["value"] is not None and mine["error"] is not None:
            assert p["value"] == pytest.approx(mine["error"], rel=1e-9, abs=1e-12), name
            assert p["std"] == pytest.approx(mine["std"], rel=1e-9), name
            compared += 1
    assert compared >= 15
    for c in compare["parameters"]:
        mine = ours[c["name"]]
        assert c["unit"] == mine["unit"] and c["a"] == pytest.approx(mine["error"], rel=1e-9)
    # the held-out errors: mm, the same number
    assert run["errors"]["calibrated_position_rms_mm"] == pytest.approx(
        results["validation"]["calibrated"]["position_mm"]["rms"], rel=1e-12
    )
    assert run["held_out_metric"] == results["held_out_metric"] == "poses"
    verify = docs["v.json"]
    assert set(verify["calibrated"]) == {"position_mm", "orientation_deg"}
    assert verify["calibrated"]["position_mm"]["rms"] < 1.0  # mm: sub-millimetre


def test_parameter_json_is_the_unit_results_json_shows():
    assert parameter_json(1e-3, "m") == (1.0, "mm")
    assert parameter_json(np.radians(2.0), "rad")[0] == pytest.approx(2.0)
    assert parameter_json(5e-4, "1") == (pytest.approx(500.0), "ppm")
    assert parameter_json(None, "rad") == (None, "deg")
