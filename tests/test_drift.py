"""Drift between two calibrations: the test's arithmetic on hand-made runs, and its behaviour on
repeated synthetic sessions of one robot (noise only: at most 5 % flagged; a planted 0.3 mm change
of one link: flagged, on that link)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import scipy.stats
from helpers_fleet import make_robot, write_session

from relcal.calibration.pipeline import calibrate
from relcal.data.dataset import load_dataset
from relcal.data.imaging import measure
from relcal.errors import RelcalError
from relcal.fleet.drift import compare, consecutive
from relcal.fleet.records import calibration_record
from relcal.fleet.registry import run_from_record
from relcal.reporting.documents import results_document


def hand_made(values, cov, names, robot="r1", model="M", handeye=None):
    """A run with the given values and covariance (SI), every parameter estimated."""
    params = [
        {"name": n, "unit": "m", "value": float(v), "std": float(np.sqrt(cov[k, k])),
         "identifiable": True, "estimated": True}
        for k, (n, v) in enumerate(zip(names, values, strict=True))
    ]  # fmt: skip
    if handeye is not None:
        params.append(dict(params[0], name="handeye.tx", value=handeye))
        names = [*names, "handeye.tx"]
        cov = np.pad(cov, ((0, 1), (0, 1)))
        cov[-1, -1] = 1.0
    record = {
        "robot_id": robot,
        "session": None,
        "relcal_version": "x",
        "model_name": model,
        "dataset_path": "",
        "outputs_path": None,
        "settings": {},
        "input_hashes": {},
        "converged": True,
        "rank": len(names),
        "parameters": params,
        "covariance": {"names": list(names), "matrix": np.asarray(cov).tolist()},
        "validation": None,
    }
    return run_from_record(record)


def test_chi_square_and_z_by_hand():
    names = ["a[1]", "a[2]", "d[3]"]
    cov_a = np.array([[4.0, 1.0, 0.0], [1.0, 2.0, 0.5], [0.0, 0.5, 1.0]]) * 1e-10
    cov_b = np.diag([1.0, 2.0, 3.0]) * 1e-10
    a = hand_made([0.0, 0.0, 0.0], cov_a, names, handeye=0.0)
    d = np.array([1e-5, -2e-5, 3e-5])
    b = hand_made(d, cov_b, names, handeye=5.0)  # a huge hand-eye change: not the robot
    c = compare(a, b)
    total = cov_a + cov_b
    assert c.chi2 == pytest.approx(d @ np.linalg.solve(total, d), rel=1e-9)
    assert c.dof == 3 and c.p_value == pytest.approx(scipy.stats.chi2.sf(c.chi2, 3), rel=1e-9)
    z = d / np.sqrt(np.diag(total))
    np.testing.assert_allclose([p.z for p in c.parameters], z, rtol=1e-9)
    assert c.z_threshold == pytest.approx(scipy.stats.norm.isf(0.01 / 6))
    assert "handeye.tx" in c.left_out
    assert compare(a, b, include_handeye=True).flagged == ["handeye.tx"]
    assert compare(a, a).verdict == "agree" and compare(a, a).p_value == 1.0


def test_different_models_do_not_compare_and_others_are_noted():
    names = ["a[1]"]
    a = hand_made([0.0], np.eye(1) * 1e-10, names)
    with pytest.raises(RelcalError, match="different robot models"):
        compare(a, hand_made([0.0], np.eye(1) * 1e-10, names, model="N"))
    other = hand_made([1e-6], np.eye(1) * 1e-10, names, robot="r2")
    assert "different robots" in compare(a, other).notes[0]
    assert consecutive([a, hand_made([0.0], np.eye(1), names, model="N"), a])[1] is None
    with pytest.raises(RelcalError, match="alpha"):
        compare(a, a, alpha=1.5)


def test_not_identifiable_in_one_run_is_left_out():
    names = ["a[1]", "a[2]"]
    a = hand_made([0.0, 0.0], np.eye(2) * 1e-10, names)
    b = hand_made([0.0, 1.0], np.eye(2) * 1e-10, names)
    b.parameters[1]["identifiable"] = False
    c = compare(a, b)
    assert [p.name for p in c.parameters] == ["a[1]"] and c.left_out == ("a[2]",)


def _run(root, robot, seed, change=None):
    dataset = load_dataset(write_session(root, robot, seed, change=change))
    cal = calibrate(dataset, measure(dataset, progress=False))
    return run_from_record(calibration_record(cal, results_document(cal)))


SEEDS = 40


@pytest.fixture(scope="module")
def repeated(tmp_path_factory):
    """Two sessions (new poses, new noise) of each of ``SEEDS`` robots, and a third session of
    the first robots with a[2] 0.3 mm longer."""
    tmp = tmp_path_factory.mktemp("drift")
    pairs, planted = [], []
    for s in range(SEEDS):
        model = ("a465", "ur5e")[s % 2]
        robot = make_robot(model, f"r{s}", 500 + s)
        first = _run(tmp / f"{s}-1", robot, 10_000 + s)
        pairs.append((first, _run(tmp / f"{s}-2", robot, 20_000 + s)))
        if s < 4:
            planted.append((first, _run(tmp / f"{s}-3", robot, 30_000 + s, {"a[2]": 3e-4})))
    return pairs, planted


def test_noise_alone_is_rarely_called_drift(repeated):
    pairs, _ = repeated
    comparisons = [compare(a, b) for a, b in pairs]
    flagged = sum(c.drift for c in comparisons)
    assert flagged <= 0.05 * SEEDS, [c.p_value for c in comparisons]
    # the covariances are honest: chi-square p-values of noise-only pairs are not piled up near 0
    p = np.array([c.p_value for c in comparisons])
    assert scipy.stats.kstest(p, "uniform").pvalue > 0.001, np.sort(p)
    # and the standard deviations are those of the repeatability: z of all parameters ~ N(0, 1)
    z = np.concatenate([[q.z for q in c.parameters] for c in comparisons])
    assert 0.7 < np.std(z) < 1.3


def test_a_planted_link_change_is_flagged_on_that_link(repeated):
    _, planted = repeated
    for a, b in planted:
        c = compare(a, b)
        assert c.drift and c.p_value < 1e-6
        assert "a[2]" in c.flagged
        change = next(p for p in c.parameters if p.name == "a[2]")
        assert change.difference == pytest.approx(3e-4, abs=4 * change.std)
    # a robot compared with another robot of its model differs far more than its noise
    first, _ = planted[0]
    other = replace(planted[2][0], robot_id="someone else")
    assert compare(first, other).drift
