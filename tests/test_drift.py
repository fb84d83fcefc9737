"""Drift between two calibrations: the test's arithmetic on hand-made runs, and its behaviour on
repeated synthetic sessions of one robot (noise only: at most 5 % flagged; a planted 0.3 mm change
of one link: flagged, on that link; the recorded standard deviations against the known truth)."""

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
from relcal.fleet.text import comparison_document, comparison_text
from relcal.reporting.documents import results_document
from relcal.robot.kinematics import make_layout
from relcal.robot.loading import get_robot
from relcal.robot.model import auto_hayati


def hand_made(values, cov, names, robot="r1", model="M", handeye=None, held=(), chosen=None, id=0):
    """A run with the given values and covariance (SI), every parameter estimated but the
    ``held`` names (at nominal: not in the covariance); ``chosen`` names its model."""
    params = [
        {"name": n, "unit": "m", "value": float(v), "std": float(np.sqrt(cov[k, k])),
         "identifiable": True, "estimated": True}
        for k, (n, v) in enumerate(zip(names, values, strict=True))
    ]  # fmt: skip
    params += [
        {"name": n, "unit": "m", "value": None, "std": None, "identifiable": True,
         "estimated": False}
        for n in held
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
        "settings": {} if chosen is None else {"chosen_model": chosen},
        "input_hashes": {},
        "converged": True,
        "rank": len(names),
        "parameters": params,
        "covariance": {"names": list(names), "matrix": np.asarray(cov).tolist()},
        "validation": None,
    }
    return run_from_record(record, id)


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


def test_runs_that_chose_different_models_compare_what_both_estimated():
    """One run chose a joint scale on top of the geometry: the scale is left out and named, the
    geometry is compared on the marginal covariance of each run's own model."""
    cov_a = np.array([[4.0, 1.0, 2.0], [1.0, 3.0, 0.5], [2.0, 0.5, 5.0]]) * 1e-10
    names = ["a[1]", "a[2]", "scale[2]"]
    a = hand_made([0.0, 0.0, 7e-5], cov_a, names, chosen="geometric + scale", id=1)
    b = hand_made([1e-5, 2e-5], np.eye(2) * 1e-10, names[:2], held=["scale[2]"], id=2)
    # hand-made runs have no dataset to be refitted on the common model from: said so first
    fallback = compare(a, b)
    assert "could not be refitted on a common one" in fallback.notes[0]
    assert fallback.common_model is None
    c = compare(a, b, common=False)
    assert [p.name for p in c.parameters] == ["a[1]", "a[2]"]
    assert c.one_sided == ("scale[2]",) and "scale[2]" in c.left_out
    d = np.array([1e-5, 2e-5])
    total = cov_a[:2, :2] + np.eye(2) * 1e-10
    assert c.chi2 == pytest.approx(d @ np.linalg.solve(total, d), rel=1e-9)
    (note,) = c.notes
    assert "run 1 (geometric + scale) only: scale[2]" in note
    assert "only the 2 parameters both estimated are compared" in note
    text = comparison_text(c)
    assert "note: the runs estimated different parameters" in text
    assert "not compared" not in text  # scale[2] is named in the note, not as unidentifiable
    assert comparison_document(c)["one_sided"] == ["scale[2]"]
    # the other way round, and a parameter estimated in both but identifiable in one only
    b.parameters[0]["identifiable"] = False
    c = compare(b, a, common=False)
    assert [p.name for p in c.parameters] == ["a[2]"] and c.one_sided == ("scale[2]",)
    assert "run 1 (geometric + scale) only: scale[2]" in c.notes[0]
    assert compare(a, a).one_sided == () and not compare(a, a).notes


def _run(root, robot, seed, change=None, scale=None, nongeometric="auto", id=0):
    dataset = load_dataset(write_session(root, robot, seed, change=change, scale=scale))
    cal = calibrate(dataset, measure(dataset, progress=False), nongeometric=nongeometric)
    return run_from_record(calibration_record(cal, results_document(cal)), id)


def test_runs_of_different_models_are_compared_on_the_common_one(tmp_path):
    """Two sessions of one robot whose joints 2 and 3 have a real gear ratio error (1000 ppm):
    one run chose geometry + scale, the other was calibrated with the geometry alone. Compared
    as recorded, the geometry of the two models differs (flagged on theta_off[3]); on the common
    model (the first run refitted with the geometry alone, from its dataset and settings) the
    sessions agree. (Over 12 such pairs: 5 flagged as recorded, none on the common model.)"""
    robot = make_robot("a465", "r0", 300)
    scale = {2: 1e-3, 3: -1e-3}
    a = _run(tmp_path / "s0", robot, 400, scale=scale, id=1)
    b = _run(tmp_path / "s1", robot, 401, scale=scale, nongeometric="none", id=2)
    assert a.settings["chosen_model"] == "geometric + scale"
    assert b.settings["chosen_model"] == "geometric"
    recorded = compare(a, b, common=False)
    assert recorded.drift and "theta_off[3]" in recorded.flagged
    c = compare(a, b)
    assert c.common_model == "geometric" and not c.drift and c.p_value > 0.1, c.notes
    assert "both compared on the common model geometric (run 1 refitted" in c.notes[0]
    assert c.one_sided == ()  # the refitted run estimates no scale any more
    assert comparison_document(c)["common_model"] == "geometric"
    assert [r.id for r in (c.run_a, c.run_b)] == [1, 2]
    # the dataset changed since: compared as recorded, and said so
    (tmp_path / "s0" / "samples.csv").write_text(
        (tmp_path / "s0" / "samples.csv").read_text() + "\n"
    )
    c = compare(a, b)
    assert c.common_model is None and "changed since it was calibrated" in c.notes[0]


SEEDS = 40


@pytest.fixture(scope="module")
def repeated(tmp_path_factory):
    """Two sessions (new poses, new noise) of each of ``SEEDS`` robots, and a third session of
    the first robots with a[2] 0.3 mm longer."""
    tmp = tmp_path_factory.mktemp("drift")
    pairs, planted, robots = [], [], []
    for s in range(SEEDS):
        model = ("a465", "ur5e")[s % 2]
        robot = make_robot(model, f"r{s}", 500 + s)
        robots.append(robot)
        first = _run(tmp / f"{s}-1", robot, 10_000 + s)
        pairs.append((first, _run(tmp / f"{s}-2", robot, 20_000 + s)))
        if s < 4:
            planted.append((first, _run(tmp / f"{s}-3", robot, 30_000 + s, {"a[2]": 3e-4})))
    return pairs, planted, robots


def test_noise_alone_is_rarely_called_drift(repeated):
    pairs, _, _ = repeated
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
    _, planted, _ = repeated
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


def test_recorded_standard_deviations_are_those_of_the_estimation_error(repeated):
    """Each session's identified errors against the robot's true ones, in units of the recorded
    standard deviations (identifiable link parameters): a standard deviation within 10 % of 1.
    (Before the noise learning counted what the fit absorbs of each component it was 1.07 on
    these sessions: the position noise level came out about 15 % low.)"""
    pairs, _, robots = repeated
    z = []
    for (first, second), robot in zip(pairs, robots, strict=True):
        layout = make_layout(auto_hayati(get_robot(robot.model)))
        truth = dict(zip(layout.names, robot.truth, strict=True))
        for run in (first, second):
            for p in run.parameters:
                if p["estimated"] and p["identifiable"] and p["name"] in truth:
                    if not p["name"].startswith("handeye."):
                        z.append((p["value"] - truth[p["name"]]) / p["std"])
    assert len(z) > 20 * len(pairs)
    assert abs(np.mean(z)) < 0.1
    assert 0.9 < np.std(z) < 1.1, np.std(z)
