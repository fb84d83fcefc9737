"""Every public function (relcal.__all__) checks its arguments by type and range before any
work: each argument given a value of the wrong kind (an int for a name, a string for a number,
an array for a choice, a seed of 2**70 or -1, NaN, an empty path ...) ends in a RelcalError that
names the argument, never a TypeError, a NumPy error or an IndexError from deep inside; and
the internal errors of the issue (a device read as samples, a plan with a zero-width limit, an
interrupt while a cluster starts) end in a clear refusal or a clean interrupt."""

from __future__ import annotations

import inspect
import os
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest
from helpers_dataset import synthetic_dataset

import relcal
from relcal.cli import main
from relcal.errors import RelcalError

WRONG = [
    1,
    -1,
    2**70,
    1.5,
    float("nan"),
    "x",
    "",
    None,
    True,
    object(),
    [1, 2],
    np.zeros((2, 2)),
]
TIAGO = ("base_footprint", "gripper_right_pal_atc_base_link")
SKIP = {"progress", "client", "registry", "journal"}  # callbacks and handles: not arguments


@pytest.fixture(scope="module")
def calls(tmp_path_factory):
    """Each public function with arguments that work."""
    root = synthetic_dataset(tmp_path_factory.mktemp("args") / "d", n=12).root
    model = relcal.get_robot("a465")
    layout = relcal.make_layout(model)
    q = np.random.default_rng(0).uniform(-1, 1, (8, 6))
    poses = relcal.fk(model, q)
    dataset = relcal.load_dataset(root)
    pairs = relcal.make_pairs(8, "all")
    problem = relcal.Problem(model, layout, q, poses, pairs=pairs)
    tiago = Path(__file__).resolve().parents[2] / "shared/data/tiago_pro/tiago_pro.urdf"
    zeros = np.zeros(layout.size)
    return {
        "analyse_problem": (relcal.analyse_problem, dict(problem=problem)),
        "apply_errors": (relcal.apply_errors, dict(model=model, layout=layout, errors=zeros)),
        "calibrate": (relcal.calibrate, dict(dataset=dataset, nongeometric="none")),
        "calibrated_model": (
            relcal.calibrated_model,
            dict(model=model, layout=layout, params=zeros),
        ),
        "fk": (relcal.fk, dict(model=model, q=q)),
        "get_robot": (relcal.get_robot, dict(name_or_path="a465")),
        "identify": (relcal.identify, dict(problem=problem)),
        "load_dataset": (relcal.load_dataset, dict(folder=root)),
        "load_model": (relcal.load_model, dict(path=root / "robot.yaml")),
        "make_layout": (relcal.make_layout, dict(model=model)),
        "make_pairs": (relcal.make_pairs, dict(n_poses=8)),
        "measure": (relcal.measure, dict(dataset=dataset, progress=False)),
        "simulate": (relcal.simulate, dict(model=model, n_poses=10)),
        "SolverOptions": (relcal.SolverOptions, {}),
        "Noise": (relcal.Noise, {}),
        "Problem": (
            relcal.Problem,
            dict(model=model, layout=layout, q=q, poses=poses, pairs=pairs),
        ),
        "Dataset.from_arrays": (relcal.Dataset.from_arrays, dict(model=model, q=q, poses=poses)),
        "load_urdf": (relcal.load_urdf, dict(path=tiago, root=TIAGO[0], tip=TIAGO[1])),
    }


FUNCTIONS = [
    "analyse_problem",
    "apply_errors",
    "calibrate",
    "calibrated_model",
    "fk",
    "get_robot",
    "identify",
    "load_dataset",
    "load_model",
    "make_layout",
    "make_pairs",
    "measure",
    "simulate",
    "SolverOptions",
    "Noise",
    "Problem",
    "Dataset.from_arrays",
    "load_urdf",
]


@pytest.mark.parametrize("name", FUNCTIONS)
def test_every_argument_of_the_wrong_kind_is_refused_by_name(calls, name):
    fn, base = calls[name]
    if name == "load_urdf" and not Path(base["path"]).is_file():
        pytest.skip("the shared TIAGo Pro URDF is not here")
    failures = []
    for param in inspect.signature(fn).parameters:
        if param in SKIP or param in ("self", "args", "kwargs"):
            continue
        for wrong in WRONG:
            kwargs = {**base, param: wrong}
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    fn(**kwargs)
            except RelcalError as exc:
                named = param in str(exc) or (param == "strategy" and "pairing" in str(exc))
                # a path that names no file is refused naming the file itself
                named = named or (isinstance(wrong, str) and f"{wrong}: " in str(exc))
                named = named or (isinstance(wrong, str) and repr(wrong) in str(exc))
                if not named:
                    failures.append(f"{param}={wrong!r:.20}: does not name it: {exc}")
            except Exception as exc:  # noqa: BLE001 - what the test is about
                failures.append(f"{param}={wrong!r:.20}: {type(exc).__name__}: {exc}"[:200])
    assert not failures, "\n".join(failures)


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"seed": 2**70}, ("seed", "2**63 - 1")),
        ({"seed": -1}, ("seed", "[0, inf)")),
        ({"holdout": 0.99}, ("holdout", "leaving 0 to train on", "give holdout at most")),
        ("all-held-out", ("holdout_ids", "holds out 12 of the 12 samples", "hold out at most")),
    ],
)
def test_the_issues_calibrate_arguments_and_the_suggested_fix(calls, change, words):
    _, base = calls["calibrate"]
    dataset = base["dataset"]
    if change == "all-held-out":
        change = {"holdout_ids": list(dataset.ids)}
    with pytest.raises(RelcalError) as info:
        relcal.calibrate(**{**base, **change})
    for word in words:
        assert word in str(info.value), info.value
    import re

    found = re.search(r"at most ([0-9.]+)", str(info.value))
    most = found.group(1) if found else None
    if "holdout" in change:  # the suggestion, followed: the largest share that leaves enough
        cal = relcal.calibrate(**{**base, "holdout": float(most)})
        assert len(cal.test) >= 2 and len(cal.train) + len(cal.test) == 12
    if "holdout_ids" in change:  # hold out at most that many
        cal = relcal.calibrate(**{**base, "holdout_ids": list(dataset.ids[: int(most)])})
        assert len(cal.test) == int(most)


def test_an_empty_path_is_never_the_working_folder(calls):
    for call in (
        lambda: relcal.load_dataset(""),
        lambda: relcal.load_model(""),
        lambda: relcal.get_robot(""),
        lambda: relcal.load_urdf(""),
    ):
        with pytest.raises(RelcalError, match="expected"):
            call()


def test_unknown_or_negative_tolerances_are_refused_as_arguments(calls):
    """Refused where given, naming the key (a close match suggested), not later blamed on the
    data; following the suggestion works."""
    _, base = calls["Dataset.from_arrays"]
    with pytest.raises(RelcalError, match=r"tolerances: unknown str 'length_m'.*'length_mm'"):
        relcal.Dataset.from_arrays(**base, tolerances={"length_m": 5})
    with pytest.raises(RelcalError, match=r"tolerances\['angle_deg'\]: expected a number"):
        relcal.Dataset.from_arrays(**base, tolerances={"angle_deg": -1})
    data = relcal.Dataset.from_arrays(**base, tolerances={"length_mm": 5})
    assert data.tolerances == {"length_mm": 5.0}


# ------------------------------------------------------------------ devices are not files


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/urandom"])
def test_samples_read_from_a_device_are_refused_before_reading(tmp_path, capsys, device):
    if not Path(device).exists():
        pytest.skip(f"no {device} here")
    ds = synthetic_dataset(tmp_path / "d", n=8).root
    spec = (ds / "dataset.yaml").read_text()
    lines = [line for line in spec.splitlines() if not line.startswith("samples:")]
    (ds / "dataset.yaml").write_text("\n".join([*lines, f"samples: {device}"]) + "\n")
    assert main(["calibrate", str(ds), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"{device}: a device, not a file" in err and err.count("\n") == 1, err


def test_a_pipe_is_read_only_up_to_the_cap(tmp_path, monkeypatch):
    from relcal.limits import read_input

    fifo = tmp_path / "samples.csv"
    os.mkfifo(fifo)
    writer = subprocess.Popen(
        [sys.executable, "-c", f"open({str(fifo)!r}, 'wb').write(b'0' * 3_000_000)"]
    )
    monkeypatch.setenv("RELCAL_MAX_CSV_MB", "1")
    try:
        with pytest.raises(RelcalError, match="more than the 1.0 MB limit"):
            read_input(fifo, "csv")
    finally:
        writer.kill()
        writer.wait()


# --------------------------------------------------------------------- planning, clusters


def test_a_zero_width_joint_limit_is_a_refusal_naming_the_joint():
    """The robot's own limits narrowed to almost nothing: every IK solution of a batch falls
    outside them (the checks take zero rows), and the search ends naming the joint."""
    from dataclasses import replace

    from relcal.design.feasibility import Constraints, candidates, check

    model = relcal.get_robot("ur5e")
    lower, upper = model.lower.copy(), model.upper.copy()
    lower[2], upper[2] = 0.3, 0.3 + 1e-9
    narrow = replace(model, lower=lower, upper=upper)
    cell = relcal.Cell()
    assert all(len(m) == 0 for m in check(narrow, cell, np.zeros((0, 6)), Constraints()).values())
    with pytest.raises(RelcalError, match=r"elbow \(5\.73e-08 deg\)"):
        candidates(narrow, cell, Constraints(), 5, batch=20, max_rounds=2)


def test_a_zero_width_limit_option_says_so_in_the_unit_given(capsys, tmp_path):
    code = main(["plan", "--robot", "ur5e", "--limits", "elbow=10:10", "--out", f"{tmp_path}/p"])
    err = capsys.readouterr().err
    assert code == 2 and "lower 10 deg must be below upper 10 deg" in err, err


DEFERRED = textwrap.dedent(
    """
    import os, signal, sys, time
    from relcal import cluster
    signal.signal(signal.SIGINT, signal.default_int_handler)
    order = []
    class Slow:
        def __init__(self):
            os.kill(os.getpid(), signal.SIGINT)  # arrives while the workers start
            time.sleep(0.2)
            order.append("started")
        def close(self):
            order.append("closed")
    cluster.local_cluster = lambda workers: Slow()
    import distributed
    class FakeClient:
        def __init__(self, c):
            order.append("client")
        def close(self):
            order.append("client closed")
    distributed.Client = FakeClient
    try:
        cluster.connect(None, 2)
    except KeyboardInterrupt:
        order.append("interrupted")
    print(",".join(order))
    """
)


def test_an_interrupt_while_a_local_cluster_starts_arrives_once_it_is_up_and_closes_it():
    done = subprocess.run(
        [sys.executable, "-c", DEFERRED],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "started,client,client closed,closed,interrupted", done.stdout
    assert "Traceback" not in done.stderr, done.stderr
