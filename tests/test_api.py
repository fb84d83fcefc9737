"""The public Python API: the names of ``relcal.__all__`` and the covariance that
:class:`relcal.Result` reports, checked against repeated noisy calibrations."""

from dataclasses import replace
from pathlib import Path

import numpy as np
from helpers_sim import make_problem

import relcal
from relcal import geometry as tf
from relcal.calibration.identify import least_squares_covariance
from relcal.calibration.measurement import residuals
from relcal.robot.model import auto_hayati


def test_api_names_are_importable():
    needed = {"get_robot", "load_dataset", "calibrate", "simulate", "Problem", "identify", "Result"}
    assert needed <= set(relcal.__all__)
    for name in relcal.__all__:
        assert getattr(relcal, name) is not None


def test_result_covariance_matches_repeated_calibrations(a465, rng):
    """All pairs of 25 poses share each pose 24 times: the residuals correlate, and the naive
    ``s^2 (A^T A)^-1`` would be 3 to 5 times too small. The reported standard deviations must
    match the spread of estimates over repeated noisy measurements."""
    model = auto_hayati(a465)
    problem, _ = make_problem(model, "invariant", "pose", rng, n_poses=25)
    problem = replace(problem, pairs=relcal.make_pairs(25, "all"))
    estimates, predicted, naive = [], [], []
    for _ in range(40):
        noise = np.c_[rng.normal(0, 1e-4, (25, 3)), rng.normal(0, 2e-4, (25, 3))]
        noisy = replace(problem, poses=problem.poses @ tf.from_vector(noise))
        res = relcal.identify(noisy)
        estimates.append(res.params)
        predicted.append(res.std)
        r, a = residuals(noisy, res.params)
        naive.append(np.sqrt(np.diag(least_squares_covariance(a, r, res.identifiability.subset))))
    sub = res.identifiability.subset
    empirical = np.std(estimates, axis=0, ddof=1)[sub]
    ratio = np.mean(predicted, axis=0)[sub] / empirical
    assert 0.85 < np.median(ratio) < 1.15, ratio
    assert np.all((ratio > 0.6) & (ratio < 1.5)), ratio  # 40 trials: a sample std scatters ~11 %
    assert np.median(np.mean(naive, axis=0)[sub] / empirical) < 0.6  # what the test guards against
    # Labelled: names, symmetric, correlations within [-1, 1].
    cov = res.labelled_covariance()
    assert set(cov) == {res.names[k] for k in sub}
    rho = res.correlation[np.ix_(sub, sub)]
    assert np.allclose(rho, rho.T) and np.all(np.abs(rho) <= 1 + 1e-12)
    assert res.final_cost_per_observation < res.initial_cost_per_observation


def test_importing_relcal_is_light():
    """``import relcal`` (and so the command line's start) loads no SciPy, OpenCV or
    Matplotlib; the public names load on first use."""
    import subprocess
    import sys

    code = (
        "import sys, relcal; heavy = [m for m in ('scipy', 'cv2', 'matplotlib') if m in "
        "sys.modules]; print(heavy); relcal.calibrate; print('scipy' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split("\n")[:2] == ["[]", "True"]
    assert set(relcal.__all__) <= set(dir(relcal))


def test_version_py_typed_and_new_exports(capsys):
    """``relcal --version`` is the package's version (pyproject's); ``py.typed`` ships with the
    package so type checkers read the annotations; ``plan`` and ``write_calibration`` are
    top-level names."""
    import tomllib

    from relcal.cli import main

    root = Path(__file__).resolve().parents[1]
    project = tomllib.loads((root / "pyproject.toml").read_text())
    assert relcal.__version__ == project["project"]["version"]
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"relcal {relcal.__version__}"
    assert (Path(relcal.__file__).parent / "py.typed").is_file()
    assert "py.typed" in project["tool"]["setuptools"]["package-data"]["relcal"]
    from relcal.design.plan import plan
    from relcal.reporting.outputs import write_calibration

    assert relcal.plan is plan and relcal.write_calibration is write_calibration
