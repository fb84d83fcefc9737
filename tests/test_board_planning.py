"""The board formulation before calibrating: ``relcal simulate``, ``relcal study`` and
``relcal observability`` with ``--pairing board`` (and ``auto``) identify the board formulation's
problem (the board transform's 6-vector ``board.*`` estimated with the geometry and the
hand-eye), and their numbers agree with what the board formulation must give: the planted
truth recovered, the rank of all pairs plus the board's six, the same Cramer-Rao bound of the
geometry and hand-eye as all pairs, a Monte Carlo spread equal to the prediction. Also the
noise-weighted estimator's block-diagonal whitening of independent poses (linear in them)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import random_q

from relcal import geometry as tf
from relcal.calibration.identifiability import analyse_problem
from relcal.calibration.identify import identify_weighted
from relcal.calibration.measurement import (
    Problem,
    board_guess,
    camera_problem,
    pair_errors,
    residuals,
)
from relcal.calibration.noise import Noise
from relcal.calibration.uncertainty import (
    eliminate,
    noise_factor,
    parameter_covariance,
    pose_rows,
    pose_whitener,
    whitener,
)
from relcal.cli import main
from relcal.design.cell import Cell
from relcal.design.observability import report
from relcal.errors import ArgumentError, RelcalError
from relcal.geometry import DEG, MM
from relcal.reporting.text import format_observability, format_simulation
from relcal.robot.kinematics import apply_errors, fk, make_layout
from relcal.robot.model import auto_hayati
from relcal.sim.scenario import clean_poses, make_scenario, problem_for, truth_vector
from relcal.sim.simulate import simulate
from relcal.sim.study import study

NOISE = Noise(0.05 * MM, 0.01 * DEG, 0.001 * DEG)
ENTRY = "import sys; from relcal.cli import main; sys.exit(main())"
FRAMES = ("tx", "ty", "tz", "rx", "ry", "rz")


def geometric(subset: np.ndarray, n_geo: int) -> np.ndarray:
    return subset[subset < n_geo]


def same_geometry(ident_a, ident_b, n_geo: int) -> None:
    """The two analyses estimate the same geometric parameters, but where the choice is free:
    of a combination only the sum is identifiable (d[2] and d[3] along parallel axes), and
    which member column pivoting keeps is a tie."""
    geo_a, geo_b = geometric(ident_a.subset, n_geo), geometric(ident_b.subset, n_geo)
    assert len(geo_a) == len(geo_b)
    free = ~ident_a.identifiable[:n_geo] | ~ident_b.identifiable[:n_geo]
    differ = np.setxor1d(geo_a, geo_b)
    assert np.all(free[differ]), differ


# --- the simulated truth ----------------------------------------------------------------------


@pytest.mark.parametrize("measure", ["pose", "position"])
def test_the_scenarios_truth_fits_the_board_formulation_exactly(a465, measure):
    """The truth vector (geometry, hand-eye, board) puts every noise-free residual at zero: the
    board's 6-vector is the cell's board pose seen from the guess the problem starts at."""
    scenario = make_scenario(a465, measure=measure, pairing="board", n_poses=20, seed=2)
    assert scenario.pairing == "board" and scenario.problem_formulation == "board"
    problem = problem_for(scenario, scenario.q, clean_poses(scenario))
    assert problem.formulation == "board" and problem.measure == measure
    names = problem.full_layout.names
    assert names[-6:] == tuple(f"board.{c}" for c in FRAMES)
    truth = truth_vector(scenario)
    assert truth.shape == (len(names),)
    assert np.abs(residuals(problem, truth, jacobian=False)).max() < 1e-12
    # the guess is a calibration's (nominal model, drawing of the hand-eye), millimetres off
    assert 1e-4 < np.abs(truth[-6:]).max() < 0.05
    # and nowhere near zero without it: the board entry is what moves the board
    off = truth.copy()
    off[-6:] = 0.0
    assert np.abs(residuals(problem, off, jacobian=False)).max() > 1e-4


def test_auto_and_board_are_checked_against_the_formulation(a465):
    q = random_q(a465, 12, np.random.default_rng(0))
    handeye = Cell().handeye
    assert camera_problem(a465, q, handeye, "invariant", "pose", "board").formulation == "board"
    # auto: the board formulation for camera poses (as calibrate fits them), whatever the size
    assert camera_problem(a465, q, handeye, "invariant", "pose", "auto").formulation == "board"
    big = np.repeat(q, 26, axis=0)  # 312 poses
    assert camera_problem(a465, big, handeye, "invariant", "pose", "auto").formulation == "board"
    # the published formulation cannot take a board: all pairs up to 300 poses
    published = camera_problem(a465, q, handeye, "published", "pose", "auto")
    assert published.formulation == "published" and len(published.pairs) == 12 * 11 // 2
    for pairing in ("board", "auto"):
        poses = big if pairing == "auto" else q
        with pytest.raises(ArgumentError, match="formulation 'invariant'.*not 'published'"):
            camera_problem(a465, poses, handeye, "published", "pose", pairing)
    with pytest.raises(ArgumentError, match=r"pairing: unknown str 'pairs'"):
        camera_problem(a465, q, handeye, "invariant", "pose", "pairs")
    with pytest.raises(ArgumentError, match="pairing 'board'.*formulation 'invariant'"):
        simulate(a465, pairing="board", n_poses=10)  # the published formulation by default
    with pytest.raises(ArgumentError, match="pairing 'board'"):
        make_scenario(a465, formulation="published", pairing="board", n_poses=10)


# --- simulate ---------------------------------------------------------------------------------


@pytest.mark.parametrize("measure", ["pose", "position"])
def test_simulated_board_formulation_recovers_what_all_pairs_recover(a465, measure):
    """Noise free, the same scenario (seed) identified both ways: every identifiable parameter
    exactly, the same geometric parameters identifiable and estimated, and the rank of all pairs
    plus the board's six (position only: minus the hand-eye's rotation, which turns the camera
    about its own centre and does not move its position)."""
    # Hayati's beta: on the standard-DH A465 the held d of the parallel pair 2-3 is only
    # nearly a symmetry of the planted truth (errors of 1e-8), here every held direction is one
    robot = auto_hayati(a465)
    kw = dict(formulation="invariant", measure=measure, n_poses=25, seed=3)
    board, pairs = simulate(robot, pairing="board", **kw), simulate(robot, pairing="all", **kw)
    assert board.formulation == "board" and board.pairing == "board" and pairs.pairing == "all"
    assert len(board.problem.q) == len(pairs.problem.q)
    for sim in (board, pairs):
        r = sim.result
        ok = r.identifiable
        assert r.converged and ok.sum() >= 14
        np.testing.assert_allclose(r.params[ok], sim.specified[ok], rtol=0, atol=1e-10)
    n_geo = board.problem.layout.size
    np.testing.assert_array_equal(
        board.result.identifiable[:n_geo], pairs.result.identifiable[:n_geo]
    )
    same_geometry(board.result.identifiability, pairs.result.identifiability, n_geo)
    blind = 3 if measure == "position" else 0
    assert board.result.identifiability.rank == pairs.result.identifiability.rank + 6 - blind
    text = "\n".join(board.result.unidentifiable)
    assert "the board transform W absorbs it" in text
    assert "cancels in relative measurements" not in text
    if measure == "position":
        for c in ("rx", "ry", "rz"):
            assert f"handeye.{c}: turns the camera about its own centre" in text
    assert "board.tx" in format_simulation(board)


def test_simulated_board_calibration_recovers_planted_errors_within_their_uncertainty(a465):
    """With pose noise, Levenberg-Marquardt on the board formulation: the planted geometry
    within its predicted standard deviations (and the same as all pairs within them)."""
    noise = Noise(0.05 * MM, 0.01 * DEG)
    kw = dict(formulation="invariant", measure="pose", n_poses=40, seed=5, method="lm")
    board = simulate(a465, pairing="board", noise=noise, **kw)
    pairs = simulate(a465, pairing="all", noise=noise, **kw)
    assert board.result.converged and pairs.result.converged
    n_geo = board.problem.layout.size
    geo = geometric(board.result.identifiability.subset, n_geo)
    ok = geo[board.result.identifiable[geo]]
    assert len(ok) >= 14
    std = board.result.std[ok]
    z = np.abs(board.result.params[ok] - board.specified[ok]) / std
    assert z.max() < 4 and np.sqrt(np.mean(z**2)) < 2, z
    planted = np.abs(board.specified[ok]) / std
    assert np.median(planted) > 5  # the planted errors stand far above the noise
    diff = np.abs(board.result.params[ok] - pairs.result.params[ok]) / std
    assert diff.max() < 3, diff


def test_simulation_json_and_report_name_the_board_formulation(tmp_path, capsys):
    out, page = tmp_path / "sim.json", tmp_path / "sim.html"
    code = main(
        ["simulate", "--pairing", "board", "--n-poses", "15", "--json", str(out)]
        + ["--report", str(page), "--method", "lm", "--noise", "0.05,0.01"]
    )
    assert code == 0
    printed = capsys.readouterr().out
    assert printed.count("board formulation (each pose against the fitted board frame)") == 2
    doc = json.loads(out.read_text())
    for run in doc["runs"]:  # position only, then full pose: both the board formulation
        assert run["formulation"] == "board" and run["pairing"] == "board"
        names = [p["name"] for p in run["parameters"]]
        assert names[-6:] == [f"board.{c}" for c in FRAMES] and run["converged"]
        assert run["n_params"] == len(names) == 36
    assert [run["measure"] for run in doc["runs"]] == ["position", "pose"]
    html = page.read_text()
    assert "camera poses against the board" in html and "board formulation" in html


def test_the_command_line_refuses_the_board_with_the_published_formulation():
    """Run as a user runs it: a separate process, a one-line message, exit status 2."""
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).parents[1] / "src"))
    script = Path(sys.executable).parent / "relcal"  # the installed command
    relcal = [str(script)] if script.exists() else [sys.executable, "-c", ENTRY]
    done = subprocess.run(
        [*relcal, "simulate", "--pairing", "board", "--formulation", "published"]
        + ["--n-poses", "10"],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr
    assert done.stdout == "" and "Traceback" not in done.stderr
    assert done.stderr.startswith("relcal: error: pairing 'board': the board formulation")
    assert "--formulation invariant" in done.stderr
    done = subprocess.run(
        [*relcal, "simulate", "--pairing", "board", "--measure", "pose", "--n-poses", "12"]
        + ["--quiet"],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout == "" and done.stderr == ""


# --- observability ----------------------------------------------------------------------------


def test_observability_of_the_board_formulation_against_all_pairs(a465):
    """What the board formulation identifies: all that all pairs identify and the board's six,
    W taking what pairs cancel (the base's rigid motion); the same information on the geometry
    and hand-eye (the Cramer-Rao bound equal, so the predicted accuracy of relative poses too).
    The least-squares spread and the observability indices are of another Jacobian: not."""
    q = random_q(a465, 30, np.random.default_rng(4))
    handeye = Cell().handeye
    board = camera_problem(a465, q, handeye, "invariant", "pose", "board")
    pairs = camera_problem(a465, q, handeye, "invariant", "pose", "all")
    q_val = random_q(a465, 10, np.random.default_rng(5))
    rep_b = report(board, noise=NOISE, q_validation=q_val)
    rep_p = report(pairs, noise=NOISE, q_validation=q_val)
    assert rep_b.formulation == "board" and rep_b.handeye == "estimated"
    assert rep_b.n_measurements == 30 and rep_b.n_rows == 180 and len(rep_b.names) == 36
    ident_b, ident_p = rep_b.identifiability, rep_p.identifiability
    assert ident_p.rank == 23 and ident_b.rank == ident_p.rank + 6
    assert set(range(24, 36)) <= set(ident_b.subset)  # the hand-eye and the board, whole
    same_geometry(ident_b, ident_p, 24)
    np.testing.assert_array_equal(ident_b.identifiable[:30], ident_p.identifiable)
    # the same null directions of the geometry: base motions now with the board's columns
    combos_b = {frozenset(n for n in c.names if not n.startswith("board.")): c.reason
                for c in ident_b.combinations}  # fmt: skip
    combos_p = {frozenset(c.names): c.reason for c in ident_p.combinations}
    assert combos_b.keys() == combos_p.keys()
    for names, reason in combos_p.items():
        if "cancels in relative measurements" in reason:
            assert combos_b[names].endswith("the board transform W absorbs it")
            (combo,) = [c for c in ident_b.combinations if names < set(c.names)]
            assert any(n.startswith("board.") for n in combo.names)
        else:
            assert combos_b[names] == reason
    # the information on the geometry and hand-eye: W eliminated, the bound of all pairs (on
    # the same subset: the board's six added)
    k = len(ident_p.subset)
    same = np.r_[ident_p.subset, np.arange(30, 36)]
    crb_b = parameter_covariance(board, NOISE, ident_b, subset=same, estimator="weighted").crb
    np.testing.assert_allclose(crb_b[:k, :k], rep_p.uncertainty.crb, rtol=1e-8, atol=1e-20)
    np.testing.assert_allclose(rep_b.accuracy.position, rep_p.accuracy.position, rtol=1e-8)
    np.testing.assert_allclose(rep_b.accuracy.orientation, rep_p.accuracy.orientation, rtol=1e-8)
    assert len(rep_b.accuracy.position) == len(rep_b.accuracy.pairs) == 45  # relative poses
    # a different Jacobian (other rows, the board's columns): other indices, not other data
    assert rep_b.indices.condition_number != pytest.approx(rep_p.indices.condition_number)
    text = format_observability(rep_b)
    assert "board formulation (board transform W estimated), camera pose against the board" in text
    assert "36 parameters" in text and "rank 29 of 36" in text
    with pytest.raises(ArgumentError, match="handeye 'known'.*board formulation estimates"):
        analyse_problem(board, handeye="known")


def test_observability_command_with_the_board_and_auto(tmp_path, capsys):
    out = tmp_path / "board.json"
    common = ["observability", "--robot", "a465", "--n-poses", "20", "--validation", "5"]
    assert main([*common, "--pairing", "board", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "board formulation (each pose against the fitted board frame)" in printed
    doc = json.loads(out.read_text())
    assert doc["formulation"] == "board" and doc["pairing"] == "board"
    assert doc["n_params"] == 36 and doc["rank"] == 29
    assert {f"board.{c}" for c in FRAMES} <= set(doc["identifiable_subset"])
    auto = tmp_path / "auto.json"
    assert main([*common, "--pairing", "auto", "--json", str(auto)]) == 0
    doc = json.loads(auto.read_text())
    assert doc["pairing"] == "board" and doc["formulation"] == "board" and doc["rank"] == 29
    assert main([*common, "--pairing", "board", "--handeye", "known"]) == 2
    assert "the board formulation estimates the hand-eye" in capsys.readouterr().err
    assert main([*common, "--pairing", "board", "--formulation", "published"]) == 2
    assert "needs camera poses in the board frame" in capsys.readouterr().err


def test_planning_commands_pair_the_poses_as_calibrate_does(tmp_path, capsys):
    """Without --pairing, observability, study and simulate (of the frame-invariant data)
    compare the poses as ``relcal calibrate`` compares the same samples (its default, auto:
    each pose against the board), so the identifiability and precision they print are those of
    the calibration to come."""
    from helpers_dataset import synthetic_dataset

    from relcal.cli import build_parser

    for command in ("calibrate DS", "observability", "study", "simulate"):
        assert build_parser().parse_args(command.split()).pairs == "auto", command
    root = synthetic_dataset(tmp_path / "ds", n=16).root
    results = tmp_path / "results.json"
    calibrate = ["calibrate", str(root), "--out", str(tmp_path / "cal"), "--quiet"]
    assert main([*calibrate, "--json", str(results)]) == 0
    used = json.loads(results.read_text())["settings"]["pairing"]
    assert used == "board"
    samples = str(root / "samples.csv")
    common = ["observability", "--robot", "a465", "--hayati", "auto", "--poses", samples]
    common += ["--validation", "5"]
    default, explicit = tmp_path / "default.json", tmp_path / "explicit.json"
    assert main([*common, "--json", str(default)]) == 0
    assert main([*common, "--pairing", used, "--json", str(explicit)]) == 0
    printed = capsys.readouterr().out
    assert printed.count("board formulation (each pose against the fitted board frame)") == 2
    doc = json.loads(default.read_text())
    assert doc["pairing"] == used and doc["n_measurements"] == 16
    assert doc == json.loads(explicit.read_text())  # rank, indices, both standard deviations
    study_doc = tmp_path / "study.json"
    study_argv = ["study", "--robot", "a465", "--hayati", "auto", "--poses", samples]
    assert main([*study_argv, "--trials", "3", "--quiet", "--json", str(study_doc)]) == 0
    assert json.loads(study_doc.read_text())["pairing"] == used
    sim = tmp_path / "sim.json"
    simulate_argv = ["simulate", "--measure", "pose", "--n-poses", "16", "--quiet"]
    simulate_argv += ["--formulation", "invariant"]
    assert main([*simulate_argv, "--json", str(sim)]) == 0
    assert json.loads(sim.read_text())["pairing"] == used


def test_simulate_above_auto_s_limit_simulates_the_board_frame(monkeypatch):
    """auto above 300 poses is the board formulation, which needs the frame-invariant data:
    simulate then simulates those, as it does for --pairing board (published below)."""
    import relcal.sim.simulate

    asked = []

    def recorded(model, **kwargs):
        asked.append((kwargs["formulation"], kwargs["pairing"]))
        raise RelcalError("recorded")

    monkeypatch.setattr(relcal.sim.simulate, "simulate", recorded)
    for n in (300, 301):
        assert main(["simulate", "--measure", "pose", "--n-poses", str(n), "--quiet"]) == 2
    assert asked == [("published", "auto"), ("invariant", "auto")]


# --- study ------------------------------------------------------------------------------------


def test_study_of_the_board_formulation_matches_its_prediction_and_all_pairs(a465):
    """Matched sampling (the linear part's sampling scatter removed): the empirical spread of
    every estimated parameter, the board's included, is its Cramer-Rao bound, and that bound
    on the geometry and hand-eye is all pairs'."""
    model = auto_hayati(a465)
    q = random_q(model, 12, np.random.default_rng(11))
    noise = Noise(0.05 * MM, 0.01 * DEG)
    board = make_scenario(model, q, noise, seed=4, pairing="board")
    pairs = make_scenario(model, q, noise, seed=4, pairing="all")
    res = study(board, trials=150, seed=1, workers=1, sampling="matched", progress=False)
    assert res.converged.all()
    assert [res.names[k] for k in res.subset[-6:]] == [f"board.{c}" for c in FRAMES]
    assert np.all(np.abs(res.ratio - 1) < 0.03), res.ratio
    assert np.abs(res.bias_t).max() < 0.5
    # noise free, every parameter reported identifiable is the truth
    reference = identify_weighted(problem_for(board, board.q, clean_poses(board)), noise)
    np.testing.assert_allclose(reference.params, res.reference, atol=1e-12)
    ok = reference.identifiable
    assert ok.sum() >= 15
    np.testing.assert_allclose(res.reference[ok], res.truth[ok], atol=1e-10)
    other = study(pairs, trials=3, seed=1, workers=1, progress=False)
    k = len(other.subset)
    np.testing.assert_array_equal(res.subset[:k], other.subset)
    np.testing.assert_allclose(res.predicted_std[:k], other.predicted_std, rtol=1e-8)


def test_study_command_with_the_board(tmp_path, capsys):
    out = tmp_path / "study.json"
    code = main(
        ["study", "--robot", "a465", "--hayati", "auto", "--pairing", "board", "--poses", "10"]
        + ["--trials", "8", "--json", str(out)]
    )
    assert code == 0
    printed = capsys.readouterr().out
    assert "board formulation (each pose against the fitted board frame)" in printed
    assert "worst parameter" in printed and "predicted board." not in printed
    doc = json.loads(out.read_text())
    assert doc["formulation"] == "board" and doc["pairing"] == "board" and doc["converged"] == 8
    assert "board.rz" in [p["name"] for p in doc["parameters"]]
    assert main(["study", "--pairing", "board", "--formulation", "published", "--trials", "2"]) == 2
    assert "pairing 'board'" in capsys.readouterr().err


# --- the noise-weighted estimator and the per-pose information --------------------------------


def board_problem(model, n: int, seed: int, measure: str = "pose") -> Problem:
    rng = np.random.default_rng(seed)
    q = random_q(model, n, rng)
    layout = make_layout(model)
    handeye = Cell().handeye
    truth = apply_errors(model, layout, rng.normal(0, 5e-4, layout.size))
    world = tf.from_vector(np.array([0.4, -0.1, 0.2, 2.5, 0.2, -0.3]))
    poses = world @ fk(truth, q) @ handeye @ tf.from_vector(rng.normal(0, 1e-4, (n, 6)))
    return Problem(
        model, layout, q, poses, "board", measure, None, handeye,
        board=board_guess(fk(model, q), poses, handeye),
    )  # fmt: skip


@pytest.mark.parametrize("measure", ["pose", "position"])
def test_block_whitening_is_the_dense_whitening(a465, measure):
    """The board formulation's noise-weighted fit whitened pose by pose (sparse, linear in the
    poses) is the fit whitened by the dense factor of all rows: the same estimate, cost and
    covariance to round-off, with and without joint noise and row weights."""
    problem = board_problem(a465, 30, 7, measure)
    rows = 6 if measure == "pose" else 3
    for noise in (Noise(5e-5, 1e-4), NOISE):
        whiten = pose_whitener(problem, noise)
        assert whiten.shape == (rows * 30, rows * 30) and whiten.nnz == rows * rows * 30
        dense = whitener(noise_factor(problem, noise, measured=True))
        information = (whiten.T @ whiten).toarray()
        np.testing.assert_allclose(information, dense.T @ dense, rtol=1e-9, atol=1e-6)
        fast = identify_weighted(problem, noise)
        slow = identify_weighted(problem, noise, whiten=dense)
        assert fast.converged and slow.converged and fast.method == "lm (noise-weighted)"
        np.testing.assert_allclose(fast.params, slow.params, rtol=0, atol=1e-12)
        assert fast.residual_norm == pytest.approx(slow.residual_norm, rel=1e-9)
        subset = fast.identifiability.subset
        cov_f, cov_s = fast.covariance[np.ix_(subset, subset)], slow.covariance
        np.testing.assert_allclose(cov_f, cov_s[np.ix_(subset, subset)], rtol=1e-7)


def test_the_weighted_fit_of_the_board_stays_linear_in_the_poses(a465):
    """Memory, not time: the whitening holds 36 numbers per pose (the dense one held (6 N)^2,
    about 1 GB at 2000 poses), and the whitened Jacobian keeps the shape of the Jacobian."""
    problem = board_problem(a465, 2000, 3)
    whiten = pose_whitener(problem, NOISE)
    assert whiten.nnz == 36 * 2000
    a = residuals(problem, np.zeros(problem.full_layout.size))[1]
    assert (whiten @ a).shape == a.shape
    fit = identify_weighted(problem, NOISE)
    assert fit.stopped and fit.whiten is not None and fit.whiten.nnz == 36 * 2000


def test_per_pose_information_of_the_board_formulation(a465):
    """pose_rows of the board formulation: the board's columns are parameters (nothing left to
    eliminate), and the summed information is the Fisher information of the problem."""
    problem = board_problem(a465, 20, 9)
    rows, h = pose_rows(problem, NOISE)
    assert h == 0 and rows.shape == (20, 6, problem.full_layout.size)
    info = eliminate(np.einsum("kri,krj->ij", rows, rows), h)
    ident = analyse_problem(problem)
    unc = parameter_covariance(problem, NOISE, ident, estimator="weighted")
    s = unc.subset
    np.testing.assert_allclose(np.linalg.inv(info[np.ix_(s, s)]), unc.crb, rtol=1e-6)
    with pytest.raises(RelcalError, match="full-pose measurements for the board formulation"):
        pose_rows(board_problem(a465, 20, 9, "position"), NOISE)
    # the position rows in the measured camera's frame: the same as pair_errors reports
    position = board_problem(a465, 20, 9, "position")
    r = residuals(position, np.zeros(position.full_layout.size), jacobian=False)
    np.testing.assert_allclose(pair_errors(position, np.zeros(36))[:, :3].ravel(), r)
