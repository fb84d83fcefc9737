"""No internal error for misuse: the Python API checks its arguments where it is entered (a
RelcalError naming the argument, what it got and the likely cause, never an AttributeError,
IndexError or a NumPy broadcast error), every command-line option is checked by argparse
(exit 2 naming it), and sizes are checked before anything is allocated or read (a 3000-sample
CSV with all pairs, files above their cap)."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import pytest
from helpers_dataset import synthetic_dataset

import relcal
from relcal.cli import build_parser, main
from relcal.errors import ArgumentError, RelcalError


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    return synthetic_dataset(tmp_path_factory.mktemp("misuse") / "d", n=12).root


@pytest.fixture(scope="module")
def api(small):
    model = relcal.get_robot("a465")
    layout = relcal.make_layout(model)
    q = np.random.default_rng(0).uniform(-1, 1, (8, 6))
    poses = relcal.fk(model, q)
    dataset = relcal.load_dataset(small)
    other = relcal.load_dataset(synthetic_dataset(small.parent / "other", n=8).root)
    return {
        "model": model,
        "layout": layout,
        "q": q,
        "poses": poses,
        "dataset": dataset,
        "other": other,
        "pairs": relcal.make_pairs(8, "all"),
    }


def problem(a, **changes):
    args = dict(
        model=a["model"],
        layout=a["layout"],
        q=a["q"],
        poses=a["poses"],
        formulation="invariant",
        measure="pose",
        pairs=a["pairs"],
    )
    args.update(changes)
    return lambda: relcal.Problem(**args)


MISUSE = {
    # name: (call given the fixture dict, words the message must hold)
    "calibrate-a-path-string": (lambda a: relcal.calibrate("/data/ds"), ("dataset", "str")),
    "calibrate-a-Path": (lambda a: relcal.calibrate(Path("/data/ds")), ("load_dataset",)),
    "calibrate-holdout-1.5": (
        lambda a: relcal.calibrate(a["dataset"], holdout=1.5),
        ("holdout", "1.5"),
    ),
    "calibrate-pairing-unknown": (
        lambda a: relcal.calibrate(a["dataset"], pairing="ring"),
        ("pairing", "ring"),
    ),
    "calibrate-holdout-ids-a-string": (
        lambda a: relcal.calibrate(a["dataset"], holdout_ids="s001"),
        ("holdout_ids", "['s1']"),
    ),
    "calibrate-measurements-of-another-dataset": (
        lambda a: relcal.calibrate(a["dataset"], relcal.measure(a["other"], progress=False)),
        ("measurements", "another dataset"),
    ),
    "calibrate-seed-negative-float": (
        lambda a: relcal.calibrate(a["dataset"], seed=1.5),
        ("seed",),
    ),
    "measure-a-path": (lambda a: relcal.measure("/data/ds"), ("dataset", "load_dataset")),
    "measure-workers-zero": (lambda a: relcal.measure(a["dataset"], workers=0), ("workers",)),
    "apply-errors-3-of-24": (
        lambda a: relcal.apply_errors(a["model"], a["layout"], [1e-3, 0, 0]),
        ("errors", "(24,)", "theta_off[1]"),
    ),
    "apply-errors-nan": (
        lambda a: relcal.apply_errors(a["model"], a["layout"], np.full(24, np.nan)),
        ("errors", "not finite"),
    ),
    "apply-errors-layout-a-list": (
        lambda a: relcal.apply_errors(a["model"], ["a[1]"], [0.0]),
        ("layout", "make_layout"),
    ),
    "fk-wrong-joint-count": (lambda a: relcal.fk(a["model"], np.zeros((3, 5))), ("q", "(N, 6)")),
    "fk-nan-joints": (lambda a: relcal.fk(a["model"], [np.nan] * 6), ("q", "not finite")),
    "fk-a-robot-name": (lambda a: relcal.fk("a465", np.zeros(6)), ("model", "get_robot")),
    "fk-text-joints": (lambda a: relcal.fk(a["model"], "0,0,0,0,0,0"), ("q",)),
    "make-layout-a-name": (lambda a: relcal.make_layout("a465"), ("model",)),
    "make-pairs-negative": (lambda a: relcal.make_pairs(-3), ("n_poses",)),
    "make-pairs-unknown": (lambda a: relcal.make_pairs(5, "ring"), ("pairing", "ring")),
    "make-pairs-star-reference": (
        lambda a: relcal.make_pairs(5, "star", reference=9),
        ("reference",),
    ),
    "solver-options-method": (lambda a: relcal.SolverOptions(method="gauss"), ("method",)),
    "solver-options-nan-scale": (lambda a: relcal.SolverOptions(f_scale=np.nan), ("f_scale",)),
    "identify-not-a-problem": (lambda a: relcal.identify("problem"), ("problem",)),
    "identify-options-a-dict": (
        lambda a: relcal.identify(problem(a)(), {"method": "lm"}),
        ("options",),
    ),
    "analyse-problem-rcond-2": (
        lambda a: relcal.analyse_problem(problem(a)(), rcond=2.0),
        ("rcond",),
    ),
    "load-dataset-a-number": (lambda a: relcal.load_dataset(42), ("folder",)),
    "get-robot-none": (lambda a: relcal.get_robot(None), ("name_or_path",)),
    "simulate-two-poses": (lambda a: relcal.simulate(a["model"], n_poses=2), ("n_poses",)),
    "simulate-formulation": (
        lambda a: relcal.simulate(a["model"], formulation="nonsense"),
        ("formulation",),
    ),
}
MISUSE.update(
    {
        "problem-formulation-nonsense": (
            lambda a: problem(a, formulation="nonsense")(),
            ("formulation", "nonsense"),
        ),
        "problem-all-nan-poses": (
            lambda a: problem(a, poses=np.full((8, 4, 4), np.nan))(),
            ("poses", "8 of 8", "not finite"),
        ),
        "identify-a-nan-pose-in-a-pair": (
            lambda a: relcal.identify(
                problem(a, poses=np.where(np.arange(8)[:, None, None] == 5, np.nan, a["poses"]))()
            ),
            ("poses[5]", "not finite"),
        ),
        "problem-a-partly-nan-pose": (
            lambda a: problem(
                a, poses=np.where(np.arange(16).reshape(4, 4) == 3, np.nan, a["poses"])
            )(),  # noqa: E501
            ("poses", "8 of 8", "not finite"),
        ),
        "problem-pair-out-of-range": (
            lambda a: problem(a, pairs=np.array([[0, 1], [2, 8]]))(),
            ("pairs[1]", "(2, 8)", "out of range"),
        ),
        "problem-pair-with-itself": (
            lambda a: problem(a, pairs=np.array([[3, 3]]))(),
            ("pairs[0]", "itself"),
        ),
        "problem-q-wrong-shape": (lambda a: problem(a, q=a["q"][:, :4])(), ("q", "(N, 6)")),
        "problem-poses-fewer-than-q": (
            lambda a: problem(a, poses=a["poses"][:5])(),
            ("poses", "(8, 4, 4)"),
        ),
        "problem-handeye-3x3": (lambda a: problem(a, handeye=np.eye(3))(), ("handeye", "4x4")),
        "problem-weights-3": (lambda a: problem(a, weights=np.ones(3))(), ("weights", "(6,)")),
        "problem-model-a-string": (lambda a: problem(a, model="a465")(), ("model", "get_robot")),
        "problem-measure-unknown": (lambda a: problem(a, measure="angle")(), ("measure",)),
        "problem-coincidence-without-groups": (
            lambda a: problem(a, formulation="coincidence", measure="position", pairs=None)(),
            ("coincidence", "coincidence_problem"),
        ),
    }
)
# the sweep of relcal.__all__ (issue 20/22): every public function refuses a wrong argument by
# name before any work (a path for a Dataset, an unknown choice, a wrong type, shape or value)
MISUSE.update(
    {
        "verify-session-dataset-a-path": (
            lambda a: relcal.verify_session("/no/calibration", str(a["dataset"].root)),
            ("dataset", "load_dataset"),
        ),
        "verify-session-calibration-a-number": (
            lambda a: relcal.verify_session(3, a["dataset"]),
            ("calibration", "int 3", "load_calibration"),
        ),
        "verify-session-folds-1": (
            lambda a: relcal.verify_session("/no/calibration", a["dataset"], folds=1),
            ("folds", "[2, inf)"),
        ),
        "verify-session-measurements-of-another-dataset": (
            lambda a: relcal.verify_session(
                "/no/calibration", a["dataset"], relcal.measure(a["other"], progress=False)
            ),
            ("measurements", "another dataset"),
        ),
        "verify-session-progress-a-string": (
            lambda a: relcal.verify_session("/no/calibration", a["dataset"], progress="yes"),
            ("progress", "True or False"),
        ),
        "plan-algorithm-unknown": (
            lambda a: relcal.plan(a["model"], relcal.Cell(), algorithm="annealing"),
            ("algorithm", "annealing", "'greedy', 'exchange'"),
        ),
        "plan-a-robot-name": (lambda a: relcal.plan("a465", relcal.Cell()), ("model", "get_robot")),
        "plan-no-cell": (lambda a: relcal.plan(a["model"], None), ("cell", "relcal.Cell()")),
        "plan-criterion-unknown": (
            lambda a: relcal.plan(a["model"], relcal.Cell(), criterion="D"),
            ("criterion", "'worst'"),
        ),
        "plan-one-pose-relative": (
            lambda a: relcal.plan(a["model"], relcal.Cell(), n_poses=1),
            ("n_poses", "[2, inf)"),
        ),
        "plan-coincidence": (
            lambda a: relcal.plan(a["model"], relcal.Cell(), formulation="coincidence"),
            ("formulation", "'tracker'"),
        ),
        "plan-noise-a-number": (
            lambda a: relcal.plan(a["model"], relcal.Cell(), noise=1e-4),
            ("noise", "Noise"),
        ),
        "plan-negative-random-sets": (
            lambda a: relcal.plan(a["model"], relcal.Cell(), random_sets=-1),
            ("random_sets",),
        ),
        "calibrate-weightings-a-string": (
            lambda a: relcal.calibrate(a["dataset"], weightings="plain"),
            ("weightings", "['plain']"),
        ),
        "calibrate-weightings-unknown": (
            lambda a: relcal.calibrate(a["dataset"], weightings=["plain", "robust"]),
            ("weightings[1]", "robust"),
        ),
        "calibrate-nongeometric-unknown": (
            lambda a: relcal.calibrate(a["dataset"], nongeometric="gravity"),
            ("nongeometric", "gravity", "['scale']"),
        ),
        "calibrate-nongeometric-unknown-family": (
            lambda a: relcal.calibrate(a["dataset"], nongeometric=["scale", "backlash"]),
            ("nongeometric[1]", "backlash"),
        ),
        "calibrated-model-a-name": (
            lambda a: relcal.calibrated_model("a465", a["layout"], np.zeros(24)),
            ("model", "get_robot"),
        ),
        "calibrated-model-no-layout": (
            lambda a: relcal.calibrated_model(a["model"], None, np.zeros(24)),
            ("layout", "make_layout"),
        ),
        "calibrated-model-too-few-params": (
            lambda a: relcal.calibrated_model(a["model"], a["layout"], np.zeros(20)),
            ("params", "20 values", "24 parameters"),
        ),
        "calibrated-urdf-a-name": (lambda a: relcal.calibrated_urdf("a465"), ("model",)),
        "robot-files-a-path": (lambda a: relcal.robot_files(Path("arm.urdf")), ("model",)),
        "write-calibration-a-dataset": (
            lambda a: relcal.write_calibration(a["dataset"], "/tmp/never-written"),
            ("cal", "Calibration"),
        ),
        "import-rosbag-bag-a-number": (
            lambda a: relcal.import_rosbag(5, "/tmp/never-written", "/joint_states"),
            ("bag", "int 5"),
        ),
        "import-rosbag-joints-a-list": (
            lambda a: relcal.import_rosbag("x.bag", "/tmp/never-written", ["/joint_states"]),
            ("joints", "JointState"),
        ),
        "load-model-a-number": (lambda a: relcal.load_model(5), ("path", "int 5")),
        "load-urdf-none": (lambda a: relcal.load_urdf(None), ("path", "None")),
        "noise-negative": (lambda a: relcal.Noise(position=-1e-4), ("Noise.position",)),
        "noise-text": (lambda a: relcal.Noise(position="0.05mm"), ("Noise.position", "parse")),
        "noise-covariance-3x3": (
            lambda a: relcal.Noise(covariance=np.eye(3)),
            ("Noise.covariance", "(6, 6)"),
        ),
        "cell-center-2d": (lambda a: relcal.Cell(center=[0.4, 0.0]), ("Cell.center", "(3,)")),
        "cell-handeye-nan": (
            lambda a: relcal.Cell(handeye=np.full((4, 4), np.nan)),
            ("Cell.handeye", "not finite"),
        ),
        "problem-layout-of-a-7-joint-robot": (
            lambda a: problem(a, layout=relcal.make_layout(relcal.get_robot("franka_fr3")))(),
            ("Problem.layout", "theta_off[7]", "6 joints", "another model"),
        ),
        "apply-errors-layout-of-a-7-joint-robot": (
            lambda a: relcal.apply_errors(
                a["model"], relcal.make_layout(relcal.get_robot("franka_fr3")), np.zeros(28)
            ),
            ("layout", "theta_off[7]", "another model"),
        ),
        "identify-identifiability-an-array": (
            lambda a: relcal.identify(problem(a)(), None, np.zeros(3)),
            ("identifiability", "analyse_problem"),
        ),
        "make-layout-base-a-string": (
            lambda a: relcal.make_layout(a["model"], base="yes"),
            ("base", "True or False"),
        ),
        "measure-progress-a-string": (
            lambda a: relcal.measure(a["dataset"], progress="no"),
            ("progress", "True or False"),
        ),
        "calibrate-priors-unknown": (
            lambda a: relcal.calibrate(a["dataset"], priors="flat"),
            ("priors", "flat", "'model', 'none'"),
        ),
        "calibrate-keep-outliers-a-string": (
            lambda a: relcal.calibrate(a["dataset"], keep_outliers="no"),
            ("keep_outliers", "True or False"),
        ),
        "from-arrays-mode-unknown": (
            lambda a: relcal.Dataset.from_arrays(a["model"], a["q"], a["poses"], mode="weird"),
            ("mode", "eye_in_hand"),
        ),
        "from-arrays-handeye-3x3": (
            lambda a: relcal.Dataset.from_arrays(a["model"], a["q"], a["poses"], handeye=np.eye(3)),
            ("handeye", "(4, 4)"),
        ),
        "simulate-seed-a-string": (lambda a: relcal.simulate(a["model"], seed="x"), ("seed",)),
        "simulate-noise-a-number": (
            lambda a: relcal.simulate(a["model"], noise=1e-4),
            ("noise", "Noise"),
        ),
    }
)


@pytest.mark.parametrize("name", list(MISUSE))
def test_api_misuse_is_a_named_error(api, name):
    call, words = MISUSE[name]
    with pytest.raises(RelcalError) as info:
        call(api)
    assert isinstance(info.value, ValueError)  # an argument error is a ValueError too
    assert isinstance(info.value, ArgumentError) or "dataset" in str(info.value)
    text = str(info.value)
    for word in words:
        assert word in text, text


def test_the_right_calls_still_work(api):
    """The checks refuse nothing right: a problem identifies, fk takes one configuration
    (one 4x4 pose) or several (a stack)."""
    result = relcal.identify(problem(api)(), relcal.SolverOptions())
    assert result.converged
    assert relcal.fk(api["model"], np.zeros(6)).shape == (4, 4)
    assert relcal.fk(api["model"], [[0.0] * 6] * 3).shape == (3, 4, 4)


def test_plan_and_verify_session_check_before_any_work(api, monkeypatch):
    """An unknown algorithm is refused before the candidate pool is drawn, and a bad
    ``verify_session`` argument before the calibration folder is read or an image measured."""
    from relcal.calibration import verify
    from relcal.design import plan

    def no_work(*args, **kwargs):
        raise AssertionError("work started before the arguments were checked")

    monkeypatch.setattr(plan, "candidates", no_work)
    monkeypatch.setattr(verify, "load_calibration", no_work)
    with pytest.raises(ArgumentError, match="algorithm"):
        relcal.plan(api["model"], relcal.Cell(), algorithm="annealing")
    with pytest.raises(ArgumentError, match="dataset"):
        relcal.verify_session("/no/calibration", str(api["dataset"].root))


def test_checked_values_are_kept_converted():
    """The checks convert, they do not change: NumPy scalars and lists come out as floats and
    arrays with the same values."""
    noise = relcal.Noise(np.float32(5e-5), np.float64(1e-4), 0)
    assert (noise.position, noise.orientation, noise.joints) == (
        float(np.float32(5e-5)),
        1e-4,
        0.0,
    )
    cell = relcal.Cell(center=[0.5, 0.1, 0.0])
    assert isinstance(cell.center, np.ndarray) and cell.center.tolist() == [0.5, 0.1, 0.0]
    assert relcal.Noise() == relcal.Noise(0.0, 0.0, 0.0)


# ------------------------------------------------------------ every option checked by argparse


def _options():
    """``(command path, option, type)`` of every option with a converter, over all commands."""
    found = []

    def walk(parser: argparse.ArgumentParser, path: tuple[str, ...]) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, (*path, name))
            elif action.option_strings and action.type is not None:
                found.append((path, action.option_strings[-1], action.type))

    walk(build_parser(), ())
    return found


def test_no_option_takes_an_unchecked_number():
    """A bare ``int`` or ``float`` converter accepts nan, inf and any sign: every numeric
    option goes through a checked type of ``relcal.cli.common``."""
    raw = [(p, o) for p, o, t in _options() if t in (int, float)]
    assert raw == []


BASE = {
    ("calibrate",): ["calibrate", "{ds}"],
    ("measure",): ["measure", "{ds}"],
    ("fleet", "calibrate"): ["fleet", "calibrate", "{tmp}", "--out", "{tmp}-fleet-out"],
    ("history",): ["history", "arm1"],
    ("compare",): ["compare", "1", "2"],
    ("import",): ["import", "rct-positioner", "{tmp}/none.yaml", "--out", "{tmp}/new"],
    ("board",): ["board", "--out", "{tmp}/b.pdf"],
    ("compensate",): ["compensate"],
}
BAD = ["nan", "-1", "0", "1e400", "abc", "0.4,0.25", "", "-0"]


def _id(value) -> str:
    """A stable test id (a converter's name, not its address): pytest-xdist's workers must
    collect the same ids."""
    return getattr(value, "__name__", None) or str(value)


@pytest.mark.parametrize(("path", "option", "kind"), _options(), ids=_id)
def test_every_option_refuses_bad_values_at_parse_time(path, option, kind, small, tmp_path, capsys):
    base = [a.format(ds=small, tmp=tmp_path) for a in BASE.get(path, list(path))]
    parser = build_parser()
    for value in BAD:
        argv = [*base, option, value]
        try:
            parser.parse_args(argv)
        except SystemExit:
            pass
        else:
            continue  # a valid value for this option
        capsys.readouterr()
        assert main(argv) == 2, (argv, capsys.readouterr().err)
        err = capsys.readouterr().err
        assert option in err and "Traceback" not in err and "internal error" not in err, err


def test_plan_distance_reversed(capsys):
    assert main(["plan", "--distance", "0.4,0.25"]) == 2
    err = capsys.readouterr().err
    assert "--distance" in err and "low end must be below the high end" in err and "0.25,0.4" in err


# ------------------------------------------------------------------- sizes before allocation


@pytest.fixture(scope="module")
def big(tmp_path_factory):
    return synthetic_dataset(tmp_path_factory.mktemp("big") / "d", n=3000).root


def test_a_3000_sample_csv_with_all_pairs_is_refused_before_allocating(big, tmp_path, capsys):
    started = time.perf_counter()
    out = str(tmp_path / "o")
    assert main(["calibrate", str(big), "--out", out, "--quiet", "--pairs", "all"]) == 2
    err = capsys.readouterr().err
    assert time.perf_counter() - started < 60
    assert "3,000 samples" in err and "GiB" in err and "--pairing board or auto" in err, err
    assert "RELCAL_MAX_MEMORY_MB" in err and not (tmp_path / "o").exists()
    with pytest.raises(RelcalError, match="3,000 samples"):  # the Python API too
        relcal.calibrate(relcal.load_dataset(big), pairing="all")


def test_a_3000_sample_csv_calibrates_with_the_default_pairing(big, tmp_path, capsys):
    """``--pairs auto`` (the default) uses the board formulation above 300 samples: linear in
    the samples, so the set that all pairs would need GiB for calibrates in seconds."""
    out = tmp_path / "o"
    assert main(["calibrate", str(big), "--out", str(out), "--quiet"]) == 0, capsys.readouterr()
    doc = json.loads((out / "results.json").read_text())
    assert doc["settings"]["pairing"] == "board" and doc["identification"]["converged"]
    val = doc["validation"]
    assert val["n_pairs"] <= 10_000 and val["n_samples"] >= 700  # capped pairs, every sample
    # the planted errors (centimetres before) are taken out down to the noise: the median pair
    # (the RMS carries the one planted outlier among the held-out samples)
    after, before = val["calibrated"]["position_mm"], val["baseline"]["position_mm"]
    assert after["median"] < 0.1 < 5 < before["median"], (after, before)


def test_the_memory_limit_is_configurable(small, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("RELCAL_MAX_MEMORY_MB", "1")
    assert main(["calibrate", str(small), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert "12 samples" in capsys.readouterr().err
    monkeypatch.setenv("RELCAL_MAX_MEMORY_MB", "lots")
    assert main(["calibrate", str(small), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert "RELCAL_MAX_MEMORY_MB='lots': expected a number" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("kind", "argv", "target"),
    [
        ("csv", ["calibrate", "{ds}"], "{ds}/samples.csv"),
        ("yaml", ["calibrate", "{ds}"], "{ds}/dataset.yaml"),
        ("text", ["calibrate", "{ds}", "--holdout-ids", "@{tmp}/ids.txt"], "{tmp}/ids.txt"),
        ("yaml", ["simulate", "--robot", "{tmp}/arm.yaml"], "{tmp}/arm.yaml"),
        ("urdf", ["simulate", "--robot", "{tmp}/arm.urdf"], "{tmp}/arm.urdf"),
        ("csv", ["observability", "--poses", "{tmp}/p.csv"], "{tmp}/p.csv"),
    ],
)
def test_inputs_above_their_cap_are_refused_unread(
    kind, argv, target, small, tmp_path, capsys, monkeypatch
):
    (tmp_path / "ids.txt").write_text("s001\n" * 2000)
    (tmp_path / "arm.yaml").write_text("name: x\n" + "# padding\n" * 2000)
    (tmp_path / "arm.urdf").write_text("<robot name='x'>" + " " * 20000 + "</robot>")
    (tmp_path / "p.csv").write_text("id,q1,q2,q3,q4,q5,q6\n" + "a,1,2,3,4,5,6\n" * 2000)
    monkeypatch.setenv(f"RELCAL_MAX_{kind.upper()}_MB", "0.00005")  # 50 bytes
    argv = [a.format(ds=small, tmp=tmp_path) for a in argv]
    if argv[0] == "calibrate":
        argv += ["--out", str(tmp_path / "o")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    path = target.format(ds=small, tmp=tmp_path)
    assert path in err and f"limit for {kind} input files" in err, err
    assert f"RELCAL_MAX_{kind.upper()}_MB" in err, err


def test_an_image_above_its_cap_is_refused_before_measuring(tmp_path, capsys, monkeypatch):
    root = tmp_path / "d"
    root.mkdir()
    (root / "dataset.yaml").write_text(
        "robot: a465\nboard: {type: chessboard, rows: 7, columns: 10, square: 0.02}\n"
        "camera: {fx: 1000, fy: 1000, cx: 500, cy: 400}\n"
    )
    rows = ["id,q1,q2,q3,q4,q5,q6,image"]
    for k in range(6):
        (root / f"{k}.png").write_bytes(b"\x89PNG" + bytes(5000))
        rows.append(f"s{k},{k},2,3,4,5,6,{k}.png")
    (root / "samples.csv").write_text("\n".join(rows) + "\n")
    monkeypatch.setenv("RELCAL_MAX_IMAGE_MB", "0.001")
    assert main(["calibrate", str(root), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "0.png" in err and "RELCAL_MAX_IMAGE_MB" in err, err
