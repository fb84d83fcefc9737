"""A refactor keeps every number: the calibration skeleton on every real set and on synthetic sets.

``regression.json`` holds what :func:`relcal.calibrate` returned when it was recorded: on every
real set of ``../shared/data`` (positioner, ChArUco and circle-grid images, TIAGo Pro poses and
positions) and on synthetic pose and point sets, under the options that exercise each branch
(outliers, losses, weightings, model selection rules, the published solver, k-fold
cross-validation). Per run: the chosen candidate and why, outliers, held-out errors of the
baseline and of the calibrated model, every candidate's cross-validated score, the parameters
with their standard deviations, the baseline's parameters, the learned noise and the settings;
a refused run records its message. A run of the published solver is, besides, the
Levenberg-Marquardt run of the same options (:func:`same_as_lm`).

Recorded with ``python tests/test_regression.py`` after issue 28 changed the numbers on purpose
(the samples in their content's order, pairing ``auto`` the board formulation, each held-out
pose in the world frame, repeated configurations held out whole, the priors' noise level
measured at the fit itself); the first recording (commit 665f6d6) guarded the skeleton that
replaced the two pipelines. The test asserts the same numbers to 1e-6 relative (1e-4 for the
image sets). A change that moves them on purpose records again and says why in its commit.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from conftest import DATA  # noqa: E402

RECORD = Path(__file__).resolve().parent / "regression.json"
# Relative tolerance: far below any digit shown, above the round-off that differs between CPUs
# (OpenBLAS picks its kernels by instruction set): iterative fits and the bootstrap carry such
# differences up to about 1e-7 (seen: bootstrap std 6.5e-8 apart on another machine).
RTOL = 1e-6
# The image sets' poses come from OpenCV's corner detection and PnP, whose releases differ in
# the last digits (opencv-python-headless 5.0.0.93 and 5.1.0.95: learned noise 5e-6, std 2.4e-5
# relative): compared to 1e-4 relative (of an array's largest entry, for entries that nearly
# cancel, such as a covariance's), still far below anything shown.
RTOL_IMAGES = 1e-4
IMAGE_SETS = ("charuco", "circle grid")
# Absolute floor per quantity, far below anything shown: parameters and their std (SI units),
# costs and RMS values (their own units). Values that are round-off around zero compare to it.
ATOL = 1e-13
# Parameters (m, rad) and their std: 10 nm / 10 nrad, where a robust loss's solver stops (a
# baseline marker position 1.2 nm apart between two CPUs under the Cauchy loss).
ATOL_PARAMETERS = 1e-8
PARAMETER_KEYS = ("params", "baseline_params", "std", "bootstrap_std")

TIAGO = (
    "robot: {{urdf: {d}/tiago_pro.urdf, root: base_footprint,"
    " tip: gripper_right_pal_atc_base_link}}\n"
    "joint_unit: rad\ncolumns: {{x: x1, y: y1, z: z1{angles}}}\nsamples: {d}/{f}\n"
)
PLAIN = {"nongeometric": "none", "keep_outliers": True}
CONSERVATIVE = {"selection": "conservative"}

# (name, dataset builder key, options) of every run; the builders are below.
RUNS = [
    ("positioner plain", "positioner", PLAIN),
    ("positioner default", "positioner", {}),
    ("positioner both weightings", "positioner", {"weightings": ("plain", "noise model")}),
    ("tiago poses plain", "tiago poses", PLAIN),
    ("tiago poses default", "tiago poses", {}),
    ("tiago poses conservative", "tiago poses", {"selection": "conservative"}),
    ("tiago positions plain conservative", "tiago positions", {**PLAIN, **CONSERVATIVE}),
    ("tiago positions conservative", "tiago positions", {"selection": "conservative"}),
    ("tiago positions default", "tiago positions", {}),
    ("tiago positions huber", "tiago positions", {"selection": "conservative", "loss": "huber"}),
    ("charuco plain", "charuco", PLAIN),
    ("charuco default", "charuco", {}),
    ("circle grid plain", "circle grid", PLAIN),
    ("circle grid default", "circle grid", {}),
    ("synthetic poses default", "synthetic poses", {}),
    ("synthetic poses huber", "synthetic poses", {"loss": "huber"}),
    ("synthetic poses all", "synthetic poses", {"selection": "all"}),
    ("synthetic poses conservative", "synthetic poses", {"selection": "conservative"}),
    ("synthetic poses both", "synthetic poses", {"weightings": ("plain", "noise model")}),
    ("synthetic poses published", "synthetic poses", {**PLAIN, "method": "published"}),
    ("positioner published", "positioner", {**PLAIN, "method": "published"}),
    ("large errors poses published", "large poses", {**PLAIN, "method": "published"}),
    ("synthetic poses consecutive", "synthetic poses", {"pairing": "consecutive"}),
    ("synthetic poses ids", "synthetic poses", {"holdout_ids": [f"s{k:03d}" for k in range(8)]}),
    ("synthetic poses nongeometric", "synthetic nongeometric", {}),
    ("large errors poses", "large poses", {}),
    ("large errors points", "large points", {}),
    ("large errors points plain", "large points", PLAIN),
    ("synthetic points default", "synthetic points", {}),
    ("synthetic points all", "synthetic points", {"selection": "all"}),
    ("synthetic points conservative", "synthetic points", {"selection": "conservative"}),
    ("synthetic points huber", "synthetic points", {"loss": "huber"}),
    ("synthetic points published", "synthetic points", {**PLAIN, "method": "published"}),
    ("synthetic points cauchy kept", "synthetic points", {**PLAIN, "loss": "cauchy"}),
]  # fmt: skip
CROSS = [  # k-fold cross-validation
    ("synthetic poses kfold", "synthetic poses", {"k": 3}),
    ("synthetic points kfold", "synthetic points", {"k": 3}),
]


def build(key: str, root: Path):
    """The dataset and its measurements of a builder key, in ``root``."""
    from helpers_dataset import synthetic_dataset

    from relcal.cli import main
    from relcal.data.dataset import load_dataset
    from relcal.data.imaging import measure

    folder = root / key.replace(" ", "_")
    if key == "positioner":
        source = DATA / "rct_positioner" / "positioner_kinematic_measurements.yaml"
        assert main(["import", "rct-positioner", str(source), "--out", str(folder), "--quiet"]) == 0
    elif key.startswith("tiago"):
        folder.mkdir(parents=True)
        f = "mocap_pose_20260805.csv" if key == "tiago poses" else "mocap_position_20260702.csv"
        angles = ", roll: phix1, pitch: phiy1, yaw: phiz1" if key == "tiago poses" else ""
        (folder / "dataset.yaml").write_text(TIAGO.format(d=DATA / "tiago_pro", f=f, angles=angles))
    elif key in ("charuco", "circle grid"):
        name = "rct_charuco_eye_to_hand" if key == "charuco" else "rct_circle_grid_eye_in_hand"
        argv = ["import", "rct-images", str(DATA / name), "--out", str(folder), "--quiet"]
        assert main(argv) == 0
    elif key == "synthetic poses":
        synthetic_dataset(folder, n=40, outliers=2, seed=3)
    elif key == "synthetic nongeometric":
        synthetic_dataset(folder, n=60, seed=5, nongeometric=("scale",))
    elif key in ("large poses", "large points"):
        from test_optimum import _large_error_dataset

        _large_error_dataset(folder, 0, position_only=key == "large points")
    elif key == "synthetic points":
        from test_tracker_selection import point_dataset

        point_dataset(folder, 60, 11, ("scale",))
    else:
        raise KeyError(key)
    dataset = load_dataset(folder)
    return dataset, measure(dataset, progress=False, max_rms=1.5)


def _floats(values) -> list:
    return [None if not np.isfinite(v) else float(v) for v in np.asarray(values, float).ravel()]


def fingerprint(cal) -> dict:
    """The numbers of a calibration that the refactor must keep."""
    from relcal.reporting.documents import validation_document

    out = {
        "chosen": cal.selection[cal.chosen].candidate.name if cal.selection else None,
        "weighting": cal.selection[cal.chosen].candidate.weighting if cal.selection else None,
        "reason": cal.reason,
        "exported": cal.exported,
        "outliers": list(cal.outliers),
        "n_train": len(cal.train),
        "n_test": len(cal.test),
        "names": list(cal.problem.full_layout.names),
        "params": _floats(cal.result.params),
        "std": _floats(cal.std),
        "converged": bool(cal.result.converged),
        "residual_norm": float(cal.result.residual_norm),
        "baseline_params": _floats(cal.baseline.params),
        "baseline_residual_norm": float(cal.baseline.residual_norm),
        "scores": [
            {
                "name": s.candidate.name,
                "weighting": s.candidate.weighting,
                "columns": [int(c) for c in s.candidate.columns],
                "mse": float(np.mean(s.per_sample)),
                "position_rms": s.position_rms,
            }
            for s in cal.selection
        ],
        "bootstrap_std": None if cal.bootstrap_std is None else _floats(cal.bootstrap_std),
        "noise_std": None if cal.noise is None else _floats(cal.noise.std),
        "noise_covariance": None if cal.noise is None else _floats(cal.noise.covariance),
        "settings": {k: v for k, v in cal.settings.items() if k != "plausibility"},
        "plausibility": cal.settings.get("plausibility"),
        "model_nongeometric": [list(f) for f in cal.model.nongeometric],
    }
    if cal.validation is not None:
        doc = validation_document(cal.validation)
        out["validation"] = {
            which: {
                key: {stat: doc[which][key][stat] for stat in ("rms", "max", "mean")}
                for key in doc[which]
            }
            for which in ("baseline", "baseline_handeye_guess", "calibrated")
            if which in doc
        }
        out["ratio"] = doc["ratio_to_baseline"]
    return out


def run(name: str, key: str, options: dict, datasets: dict, root: Path) -> dict:
    from relcal.calibration.pipeline import calibrate, cross_validate
    from relcal.errors import RelcalError

    if key not in datasets:
        datasets[key] = build(key, root)
    dataset, measurements = datasets[key]
    # The recorded numbers are those of the plain least squares: priors (issue 18, maximum a
    # posteriori fits) came later, and ``priors="none"`` must give exactly the old cost.
    options = {"priors": "none", **options}
    try:
        if "k" in options:
            rest = {k: v for k, v in options.items() if k != "k"}
            folds = cross_validate(dataset, measurements, k=options["k"], **rest)
            return {"folds": [fingerprint(f) for f in folds]}
        return fingerprint(calibrate(dataset, measurements, **options))
    except RelcalError as exc:
        return {"refused": str(exc).replace(str(root), "ROOT")}


def _rtol(where: str) -> float:
    return RTOL_IMAGES if where.startswith(IMAGE_SETS) else RTOL


def _atol(where: str) -> float:
    return ATOL_PARAMETERS if where.rsplit(".", 1)[-1] in PARAMETER_KEYS else ATOL


def compare(got, want, where: str = "") -> None:
    """``got`` equals ``want``: numbers to :data:`RTOL`, everything else exactly."""
    if isinstance(want, dict):
        assert isinstance(got, dict) and set(got) == set(want), (where, set(got) ^ set(want))
        for k in want:
            compare(got[k], want[k], f"{where}.{k}")
    elif isinstance(want, list):
        assert isinstance(got, list) and len(got) == len(want), (where, got, want)
        if want and all(isinstance(v, (int, float)) or v is None for v in want + got):
            a = np.array([np.nan if v is None else v for v in got], float)
            b = np.array([np.nan if v is None else v for v in want], float)
            atol = _atol(where)
            if where.startswith(IMAGE_SETS) and np.isfinite(b).any():  # relative to the largest
                atol = max(atol, RTOL_IMAGES * float(np.nanmax(np.abs(b))))
            np.testing.assert_allclose(
                a, b, rtol=_rtol(where), atol=atol, equal_nan=True, err_msg=where
            )
        else:
            for k, (g, w) in enumerate(zip(got, want, strict=True)):
                compare(g, w, f"{where}[{k}]")
    elif isinstance(want, float) and not isinstance(want, bool):
        np.testing.assert_allclose(got, want, rtol=_rtol(where), atol=ATOL, err_msg=where)
    else:
        assert got == want, (where, got, want)


def _json(value):
    return json.loads(json.dumps(value))


def without_scale(doc: dict) -> dict:
    """``doc`` (a run, or a cross-validation of runs) without what the plausibility check
    derives from its translation scale: the scale, its standard deviation and the board spacing
    the data imply, nor what the checks measure (:data:`MEASURED_BY_THE_CHECKS`): diagnostics of
    the inputs that no calibration number depends on)."""
    if "folds" in doc:
        return {**doc, "folds": [without_scale(f) for f in doc["folds"]]}
    doc = dict(doc)
    if isinstance(doc.get("plausibility"), dict):
        derived = ("translation_scale", "board_spacing_from_data_m", *MEASURED_BY_THE_CHECKS)
        doc["plausibility"] = {
            k: v for k, v in doc["plausibility"].items() if not k.startswith(derived)
        } or None
    return doc


# What the input checks measure (issue 28, checks that understand structured recordings; issue
# 29, one gate for every kind): the rotation misfit is the median over the pairs that turn
# enough to show one (not over every pair), and points report their misfit at the nominal model
# (the recording had no check of points): diagnostics of the inputs, no calibration number
# depends on them.
MEASURED_BY_THE_CHECKS = ("rotation_misfit_deg", "point_misfit_mm")


def same_as_lm(name: str, got: dict, lm: dict) -> None:
    """A published run is the lm run of the same options: the same choices and samples, the
    parameters within a hundredth of their standard deviations (the solvers stop within their
    tolerances), costs and held-out errors to 1e-4 relative."""
    for key in ("chosen", "weighting", "reason", "exported", "outliers", "n_train", "n_test"):
        assert got[key] == lm[key], (name, key, got[key], lm[key])
    assert got["names"] == lm["names"] and got["converged"] and lm["converged"]
    assert {**got["settings"], "method": "lm"} == lm["settings"], name
    p, q = (np.array(d["params"], float) for d in (got, lm))
    std = np.array(lm["std"], float)
    assert np.array_equal(np.isnan(std), np.isnan(np.array(got["std"], float))), name
    est = np.isfinite(std)
    assert np.all(np.abs(p - q)[est] <= 0.01 * std[est]), (name, np.abs(p - q)[est] / std[est])
    assert not np.any(p[~est]), name  # held at nominal
    close = {"rtol": 1e-4, "atol": 1e-12}
    np.testing.assert_allclose(got["residual_norm"], lm["residual_norm"], **close)
    np.testing.assert_allclose(got["baseline_residual_norm"], lm["baseline_residual_norm"], **close)
    for a, b in zip(got["scores"], lm["scores"], strict=True):
        assert all(a[k] == b[k] for k in ("name", "weighting", "columns")), (name, a, b)
        np.testing.assert_allclose(a["mse"], b["mse"], err_msg=name, **close)
    for which in lm.get("validation", {}):
        for key, stats in lm["validation"][which].items():
            for stat, value in stats.items():
                got_value = got["validation"][which][key][stat]
                np.testing.assert_allclose(got_value, value, err_msg=f"{name} {which}", **close)


REAL = {"positioner", "tiago poses", "tiago positions", "charuco", "circle grid"}


@pytest.fixture(scope="module")
def recorded():
    return json.loads(RECORD.read_text())


@pytest.fixture(scope="module")
def datasets():
    return {}


@pytest.mark.parametrize(("name", "key", "options"), RUNS + CROSS, ids=[r[0] for r in RUNS + CROSS])
def test_same_numbers_as_recorded(name, key, options, recorded, datasets, tmp_path_factory):
    if key in REAL and not DATA.is_dir():
        pytest.skip("real data not available")
    root = tmp_path_factory.getbasetemp() / "regression"
    root.mkdir(exist_ok=True)
    got = without_scale(_json(run(name, key, options, datasets, root)))
    compare(got, without_scale(recorded[name]), name)
    if options.get("method") == "published" and "refused" not in got:
        lm_options = {k: v for k, v in options.items() if k != "method"}
        same_as_lm(name, got, without_scale(_json(run(name, key, lm_options, datasets, root))))


if __name__ == "__main__":  # record
    import tempfile

    out, cache = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, key, options in RUNS + CROSS:
            print(name, flush=True)
            out[name] = _json(run(name, key, options, cache, Path(tmp)))
    RECORD.write_text(json.dumps(out, indent=1) + "\n")
