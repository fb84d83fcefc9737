"""The identifiability report: indices by hand, named combinations checked against constructed
cases (each named direction really leaves the measurements unchanged), parallel axes exploding
without Hayati's beta and resolved with it, and the command line."""

import json
from dataclasses import replace

import numpy as np
import pytest
from conftest import random_q
from helpers_sim import make_problem

from relcal.calibration.identifiability import (
    analyse_problem,
    observability_indices,
    parallel_pairs,
)
from relcal.calibration.measurement import residuals
from relcal.calibration.noise import Noise
from relcal.cli import main
from relcal.design.observability import report
from relcal.geometry import DEG, MM
from relcal.reporting.text import format_observability
from relcal.robot.kinematics import make_layout
from relcal.robot.model import auto_hayati, model_from_dict
from relcal.sim.scenario import make_scenario
from relcal.sim.study import study

NOISE = Noise(0.05 * MM, 0.01 * DEG, 0.001 * DEG)


def reasons(rep) -> dict[frozenset, str]:
    return {frozenset(c.names): c.reason for c in rep.identifiability.combinations}


def test_indices_by_hand():
    s = np.array([4.0, 2.0, 1.0, 0.5])
    ind = observability_indices(s[::-1], n_measurements=9)  # any order
    assert ind.O1 == pytest.approx((4 * 2 * 1 * 0.5) ** 0.25 / 3)
    assert ind.O2 == pytest.approx(0.5 / 4)
    assert ind.O3 == pytest.approx(0.5)
    assert ind.O4 == pytest.approx(0.25 / 4)
    assert ind.O5 == pytest.approx(1 / (0.25 + 0.5 + 1 + 2))
    assert ind.condition_number == pytest.approx(8)
    assert observability_indices(np.array([1.0, 0.0]), 3).O1 == 0.0


def test_a465_names_base_parallel_pair_and_handeye_combinations(a465, rng):
    problem, _ = make_problem(a465, "invariant", "pose", rng, n_poses=30)
    rep = report(problem, noise=NOISE)
    found = reasons(rep)
    assert "rigid motion of the robot base" in found[frozenset({"d[1]"})]
    assert "rigid motion of the robot base" in found[frozenset({"theta_off[1]"})]
    assert "parallel axes of joints 2, 3" in found[frozenset({"d[2]", "d[3]"})]
    absorbed = [n for n, r in found.items() if "hand-eye transform X" in r]
    assert len(absorbed) == 4 and all(any(x.startswith("handeye.") for x in n) for n in absorbed)
    assert rep.identifiability.rank == 30 - 7
    # The parallel pair is shown, and what a realistic misalignment would do to the d's.
    (pair,) = rep.parallel
    assert pair.joints == (2, 3) and not pair.hayati
    median = np.nanmedian(rep.uncertainty.std)
    assert min(pair.std_d) > 1e4 * median
    text = format_observability(rep)
    for expected in ("O1 Borm-Menq", "O4 noise amplification", "QR with column pivoting"):
        assert expected in text
    assert "d[2] +1 mm with d[3] -1 mm together" in text or "d[2] -1 mm with d[3] +1 mm" in text
    assert "--hayati auto" in text

    # Hayati's beta resolves the pair: one more identifiable parameter, no parallel combination.
    model = auto_hayati(a465)
    cured = report(replace(problem, model=model, layout=make_layout(model)), noise=NOISE)
    assert cured.identifiability.rank == rep.identifiability.rank + 1
    assert not any("parallel" in r for r in reasons(cured).values())
    assert cured.parallel[0].hayati and "resolved" in format_observability(cured)

    # A known hand-eye transform absorbs nothing: only the base combinations remain.
    known = report(problem, handeye="known")
    assert set(reasons(known)) == {
        frozenset({"d[1]"}),
        frozenset({"theta_off[1]"}),
        frozenset({"d[2]", "d[3]"}),
    }
    assert known.identifiability.rank == 24 - 3


@pytest.mark.parametrize(
    ("formulation", "measure", "handeye"),
    [
        ("invariant", "pose", "estimated"),
        ("invariant", "position", "estimated"),
        ("invariant", "pose", "known"),
        ("published", "pose", "known"),
        ("published", "position", "known"),
    ],
)
def test_every_named_combination_leaves_the_measurements_unchanged(
    a465, rng, formulation, measure, handeye
):
    problem, _ = make_problem(a465, formulation, measure, rng, n_poses=25)
    ident = analyse_problem(problem, handeye=handeye)  # at the nominal parameters
    n = problem.full_layout.size
    nominal = np.zeros(n)
    base = residuals(problem, nominal, jacobian=False)
    eps = 1e-6
    for c, v in zip(ident.combinations, ident.null_space.T, strict=True):
        step = np.zeros(n)
        step[: len(v)] = eps * v / np.abs(v).max()
        change = np.abs(residuals(problem, nominal + step, jacobian=False) - base).max()
        assert change < 1e-10, (c.describe(), change)  # second order: eps^2 scale
    # ... while every parameter in the identifiable subset moves them at first order.
    for k in ident.subset:
        step = np.zeros(n)
        step[k] = eps
        assert np.abs(residuals(problem, nominal + step, jacobian=False) - base).max() > 1e-9


def test_offsets_along_axes_parallel_to_the_first_are_base_motions(rng):
    # A SCARA-like arm: axes 1, 2 and 3 vertical, then a wrist. Each d along a vertical axis
    # only lifts the whole arm, which relative measurements cannot see.
    spec = {
        "name": "scara6",
        "convention": "dh",
        "joints": [
            {"d": 0.3, "a": 0.25, "alpha": 0},
            {"d": 0.05, "a": 0.2, "alpha": 0},
            {"d": 0.02, "a": 0.0, "alpha": 90},
            {"d": 0.2, "alpha": -90},
            {"alpha": 90},
            {"d": 0.08},
        ],
    }
    model = model_from_dict(spec)
    assert [p.joints for p in parallel_pairs(model)] == [(1, 2), (2, 3)]
    problem, _ = make_problem(model, "invariant", "pose", rng, n_poses=30)
    found = reasons(report(problem))
    for name in ("d[1]", "d[2]", "d[3]", "theta_off[1]"):
        assert "rigid motion of the robot base" in found[frozenset({name})]


def test_three_parallel_axes_give_two_named_pairs(rng):
    from relcal.robot.loading import get_robot

    ur5e = get_robot("ur5e")  # joints 2, 3 and 4 parallel
    assert [p.joints for p in parallel_pairs(ur5e)] == [(2, 3), (3, 4)]
    problem, _ = make_problem(ur5e, "invariant", "pose", rng, n_poses=30)
    rep = report(problem)
    parallel = [c for c in rep.identifiability.combinations if "parallel axes" in c.reason]
    assert len(parallel) == 2
    assert set().union(*(c.names for c in parallel)) == {"d[2]", "d[3]", "d[4]"}
    hay = auto_hayati(ur5e)
    assert hay.hayati.tolist() == [False, True, True, False, False, False]
    cured = report(replace(problem, model=hay, layout=make_layout(hay)))
    assert not any("parallel" in c.reason for c in cured.identifiability.combinations)
    assert cured.identifiability.rank == rep.identifiability.rank + 2


def test_nearly_parallel_axes_explode_without_beta_and_not_with_it(a465):
    # A real A465: axes 2 and 3 half a degree off parallel. The relative rank test counts both
    # d's as identifiable, and noise makes their estimates explode; Hayati's beta cures it.
    alpha = a465.alpha.copy()
    alpha[1] += np.radians(0.5)
    tilted = a465.with_values(alpha=alpha)
    q = random_q(tilted, 16, np.random.default_rng(3))
    noise = Noise(0.005 * MM, 0.001 * DEG, 0.0)
    runs = {}
    for label, model in (("dh", tilted), ("hayati", auto_hayati(tilted))):
        scenario = make_scenario(model, q, noise, seed=2)
        runs[label] = study(
            scenario, trials=40, workers=2, estimator="least_squares", progress=False
        )
    plain, cured = runs["dh"], runs["hayati"]
    names = [plain.names[k] for k in plain.subset]
    assert "d[2]" in names and "d[3]" in names  # both estimated
    d2 = names.index("d[2]")
    others = np.median(plain.predicted_std)
    assert plain.predicted_std[d2] > 1e3 * others  # predicted: explodes
    assert plain.empirical_std[d2] > 1e3 * others  # and it does, under noise
    assert 0.6 < plain.ratio[d2] < 1.5
    cured_names = [cured.names[k] for k in cured.subset]
    assert "d[2]" not in cured_names and "beta[2]" in cured_names
    for name in ("d[3]", "beta[2]"):
        k = cured_names.index(name)
        assert cured.empirical_std[k] < 5 * np.median(cured.empirical_std)
        assert cured.empirical_std[k] * 1e3 < plain.empirical_std[d2]


def test_command_line_report(tmp_path, a465, capsys):
    q = np.degrees(random_q(a465, 25, np.random.default_rng(5)))
    lines = ["id,q1,q2,q3,q4,q5,q6,image"] + [
        ",".join([f"s{k}", *[f"{v:.6f}" for v in row], f"img{k}.png"]) for k, row in enumerate(q)
    ]
    poses = tmp_path / "poses.csv"
    poses.write_text("\n".join(lines) + "\n")
    out = tmp_path / "report.json"
    code = main(
        ["observability", "--robot", "a465", "--poses", str(poses), "--json", str(out)]
        + ["--validation", "0"]
    )
    assert code == 0
    text = capsys.readouterr().out
    assert "parallel axes 2 and 3" in text and "not estimated" in text
    doc = json.loads(out.read_text())
    # 23 of the geometry and hand-eye, and the board transform's 6 (pairing auto: each pose
    # against the board, as calibrate fits)
    assert doc["n_poses"] == 25 and doc["rank"] == 29
    assert any("d[2]" in c["names"] and "d[3]" in c["names"] for c in doc["unidentifiable"])
    assert {p["name"] for p in doc["parameters"]} == set(doc["identifiable_subset"])
    assert set(doc["indices"]) == {"O1", "O2", "O3", "O4", "O5", "condition_number"}

    bad = tmp_path / "bad.csv"
    bad.write_text("id,q1,q2,q3\n1,0,0,0\n")
    assert main(["observability", "--robot", "a465", "--poses", str(bad)]) == 2
    assert "missing q4, q5, q6" in capsys.readouterr().err
