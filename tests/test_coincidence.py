"""The coincidence kind: a tool point seated again and again at unknown points (a ball in the
sockets of a plate), with known distances between the points; simulated with planted errors on
the MUKCa Panda URDF, then the real MUKCa sets held out placement by placement (the calibration
skeleton, :func:`relcal.calibration.pipeline.cross_validate` over placements) against a plain
SciPy Levenberg-Marquardt of the same parameters, and through ``relcal calibrate``."""

import json
from dataclasses import replace

import numpy as np
import pytest
import yaml
from conftest import DATA
from helpers_sim import numeric_jacobian
from scipy.optimize import least_squares

from relcal.calibration.coincidence import (
    coincidence_problem,
    consistent,
    initial_guess,
    make_coincidence,
    placement_of,
    restricted,
    sample_errors,
)
from relcal.calibration.identifiability import analyse_problem
from relcal.calibration.measurement import residuals
from relcal.calibration.pipeline import calibrate, cross_validate
from relcal.calibration.validate import pooled, pooled_spread, spread_of
from relcal.cli import main
from relcal.data.dataset import load_dataset
from relcal.data.importers import import_mukca
from relcal.errors import RelcalError
from relcal.geometry import MM
from relcal.robot.kinematics import apply_errors, fk, make_layout
from relcal.robot.urdf import load_urdf
from relcal.sim.coincidence import SOCKETS, dataset_files, robot_entry, simulate_coincidence

MUKCA = DATA / "mukca"
URDF = {"panda": MUKCA / "urdf" / "panda.urdf", "iiwa14": MUKCA / "urdf" / "iiwa14.urdf"}
ROBOTS = {"panda_1": "panda", "panda_2": "panda", "kuka_14": "iiwa14"}
# The setup of the kind's own fit before the skeleton: the geometry, the tool point and the group
# points, no outlier left out, no non-geometric candidate, the largest candidate.
PLAIN = {"nongeometric": "none", "keep_outliers": True, "selection": "all"}


def placements_out(ds, **options):
    """Each placement held out in turn through the skeleton; the pooled validation and folds."""
    n = len(dict.fromkeys(placement_of(g) for g in ds.groups))
    folds = cross_validate(ds, k=n, **options)
    return pooled([f.validation for f in folds]), folds


def simulated_dataset(folder, truth, std=0.05 * MM):
    """The dataset folder of simulated coincidences (``relcal simulate --coincidence``)."""
    folder.mkdir()
    robot = robot_entry(str(URDF["panda"]), None, "ball_link")
    for name, text in dataset_files(truth, robot, std).items():
        (folder / name).write_text(text)
    return load_dataset(folder)


@pytest.fixture(scope="module")
def panda():
    return load_urdf(URDF["panda"], None, "ball_link")


def distances_of(truth, std=0.05 * MM):
    places = dict.fromkeys(placement_of(g) for g in truth.groups)
    return [(f"{p}/{SOCKETS[0]}", f"{p}/{SOCKETS[1]}", truth.spacing, std) for p in places]


def truth_vector(problem, truth):
    """The planted parameters on ``problem.full_layout``."""
    c = problem.coincidence
    points = np.array([truth.points[g] for g in c.names])
    return np.concatenate(
        [truth.errors, truth.tool_point - c.tool_point, (points - c.points).ravel()]
    )


@pytest.fixture(scope="module")
def exact(panda):
    """Noise-free samples of three placements."""
    return simulate_coincidence(panda, placements=3, per_socket=10, seating=0.0, seed=1)


def test_jacobian_matches_central_differences_at_a_nonzero_estimate(panda, exact):
    c = make_coincidence(panda, exact.q, exact.groups, distances_of(exact))
    problem = coincidence_problem(panda, exact.q, c)
    params = truth_vector(problem, exact) + np.random.default_rng(0).normal(
        0, 1e-3, problem.full_layout.size
    )
    for weighted in (problem, replace(problem, weights=np.full(6, 1 / (0.1 * MM)))):
        r, jac = residuals(weighted, params)
        assert jac.shape == (weighted.n_residuals(), len(params)) == (len(r), len(params))
        scale = np.abs(jac).max()
        np.testing.assert_allclose(jac, numeric_jacobian(weighted, params), atol=1e-7 * scale)


def test_residuals_vanish_at_the_planted_truth(panda, exact):
    c = make_coincidence(panda, exact.q, exact.groups, distances_of(exact))
    problem = coincidence_problem(panda, exact.q, c)
    r = residuals(problem, truth_vector(problem, exact), jacobian=False)
    assert r.shape == (3 * len(exact.q) + 3,)
    assert np.abs(r).max() < 1e-11


def test_linear_guess_finds_the_tool_point_and_the_points(panda, exact):
    """At the true geometry, ``R_k t - p_g = -o_k`` is solved exactly from the joints alone."""
    index = np.unique(exact.groups, return_inverse=True)[1]
    tool, points = initial_guess(exact.true_model, exact.q, index, len(exact.points))
    np.testing.assert_allclose(tool, exact.tool_point, atol=1e-9)
    names = sorted(exact.points)
    np.testing.assert_allclose(points, [exact.points[g] for g in names], atol=1e-9)


def test_a_group_seen_at_one_orientation_cannot_guess_the_tool_point(panda, exact):
    q = np.repeat(exact.q[:1], 4, axis=0)
    with pytest.raises(RelcalError, match="different orientations"):
        initial_guess(panda, q, np.zeros(4, int), 1)


def reasons(problem):
    return [c.describe() for c in analyse_problem(problem).combinations]


def test_what_coincidences_cannot_see_is_named(panda, exact):
    c = make_coincidence(panda, exact.q, exact.groups, distances_of(exact))
    named = reasons(coincidence_problem(panda, exact.q, c))
    rigid = [t for t in named if "rigid motion of the robot base" in t]
    # the four base-like parameters of the minimal Panda chain, each with every group point
    assert sorted(t.split()[0] for t in rigid) == ["a[1]", "alpha[1]", "d[1]", "theta_off[1]"]
    assert all("the points of 6 groups" in t for t in rigid)
    assert any(t.startswith("d[7]") and "tool point absorbs it" in t for t in named)
    assert not any("scales every length" in t for t in named)


def test_without_a_distance_the_scale_is_named_unidentifiable(panda, exact):
    c = make_coincidence(panda, exact.q, exact.groups)  # no distances
    named = reasons(coincidence_problem(panda, exact.q, c))
    scale = [t for t in named if "scales every length together" in t]
    assert len(scale) == 1 and "no known distance" in scale[0]
    with_distance = make_coincidence(panda, exact.q, exact.groups, distances_of(exact))
    ident = analyse_problem(coincidence_problem(panda, exact.q, with_distance))
    assert ident.rank == analyse_problem(coincidence_problem(panda, exact.q, c)).rank + 1


def test_one_placement_names_the_line_through_its_two_points(panda):
    truth = simulate_coincidence(panda, placements=1, per_socket=12, seating=0.0, seed=2)
    c = make_coincidence(panda, truth.q, truth.groups, distances_of(truth))
    named = reasons(coincidence_problem(panda, truth.q, c))
    assert any("rotation about the line through p0/hole_0 and p0/hole_1" in t for t in named)


def test_a_ball_on_the_last_axis_couples_joint_6_with_the_last_link(panda, exact):
    """The MUKCa ball sits 0.09 mm from joint 7's axis: turning joint 7 does not move it, so its
    place in link 6 is described by joint 6's offsets and the last link's together."""
    c = make_coincidence(panda, exact.q, exact.groups, distances_of(exact), np.zeros(3))
    named = reasons(coincidence_problem(panda, exact.q, c))
    axis = [t for t in named if "lies on joint 7's axis (its guess 0.088 mm from it)" in t]
    assert axis and all({"d[6]", "alpha[7]"} & set(t.split()) for t in axis)


def test_consistent_samples_sit_on_their_points(panda):
    truth = simulate_coincidence(panda, placements=2, per_socket=8, seating=0.3 * MM, seed=4)
    c = make_coincidence(panda, truth.q, truth.groups)
    nudged = consistent(coincidence_problem(panda, truth.q, c))
    assert np.abs(sample_errors(nudged, np.zeros(nudged.full_layout.size))).max() < 1e-10
    assert np.abs(nudged.q - truth.q).max() < np.radians(5)


# --- planted truth -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def planted(panda, tmp_path_factory):
    """Four placements, 30 samples per socket, 0.08 mm seating scatter, the spacing known; the
    dataset and its calibration on every sample."""
    truth = simulate_coincidence(panda, placements=4, per_socket=30, seating=0.08 * MM, seed=7)
    ds = simulated_dataset(tmp_path_factory.mktemp("planted") / "d", truth)
    return truth, ds, calibrate(ds, holdout=0, **PLAIN)


def equivalent_truth(problem, ident, truth_params):
    """The planted parameters moved along the unidentifiable directions until those held at
    nominal are zero: what an estimate of the identifiable subset should recover (the base
    motion and the tool absorption are straight lines in the geometric and tool columns)."""
    held = np.setdiff1d(np.arange(len(truth_params)), ident.subset)
    null = ident.null_space
    shift = np.linalg.lstsq(null[held], truth_params[held], rcond=None)[0]
    return truth_params - null @ shift


def test_planted_errors_are_recovered_within_3_predicted_std(planted):
    truth, _, result = planted
    problem, cal = result.problem, result.result
    assert cal.converged and result.selection[result.chosen].candidate.name == "geometric"
    ident = cal.identifiability
    target = equivalent_truth(problem, ident, truth_vector(problem, truth))
    cols = ident.subset[ident.subset < problem.layout.size + 3]  # geometry and tool point
    z = (cal.params[cols] - target[cols]) / cal.std[cols]
    assert np.all(np.isfinite(z))
    assert np.abs(z).max() < 3.0, dict(zip(np.array(cal.names)[cols], np.round(z, 2), strict=True))
    # the noise learned from the residuals is the planted seating scatter
    assert result.settings["point_sigma_m"] == pytest.approx(0.08 * MM, rel=0.15)


def test_held_out_placements_show_the_seating_scatter_after_calibration(planted):
    truth, ds, _ = planted
    check, folds = placements_out(ds, **PLAIN)
    assert sorted(f.validation.placements for f in folds) == [(f"p{k}",) for k in range(4)]
    cal, base = check.calibrated.summary(), check.baseline.summary()
    seating_3d = 0.08 * np.sqrt(3)  # mm, RMS distance from the socket centre
    assert cal["spread_mm"]["rms"] == pytest.approx(seating_3d, rel=0.2)
    assert base["spread_mm"]["rms"] > 5 * cal["spread_mm"]["rms"]
    assert cal["distance_error_mm"]["rms"] < 0.05
    assert len(check.calibrated.spread) == len(truth.q)


# --- datasets, the importer and the simulator's folder -------------------------------------------


def test_simulate_writes_a_dataset_that_loads(tmp_path, capsys):
    out = tmp_path / "balls"
    argv = [
        "simulate", "--robot", str(URDF["panda"]), "--tip", "ball_link", "--coincidence",
        str(out), "--placements", "2", "--per-socket", "8", "--seed", "3",
    ]  # fmt: skip
    assert main(argv) == 0
    assert "calibrated spread RMS" in capsys.readouterr().out
    ds = load_dataset(out)
    assert ds.measured == "coincidence" and len(ds.q) == 32
    assert ds.groups[0] == "p0/hole_0" and set(ds.groups) == {
        f"p{j}/{s}" for j in range(2) for s in SOCKETS
    }
    assert ds.distances[0] == ("p0/hole_0", "p0/hole_1", 0.05, 0.05 * MM)
    np.testing.assert_array_equal(ds.tool_point, np.zeros(3))
    truth = yaml.safe_load((out / "truth.yaml").read_text())
    assert set(truth["errors"]) == set(make_layout(ds.model).names)


def write_dataset(folder, samples: str, **spec):
    folder.mkdir()
    base = {"robot": {"urdf": str(URDF["panda"]), "tip": "ball_link"}, "joint_unit": "rad"}
    (folder / "dataset.yaml").write_text(yaml.safe_dump({**base, **spec}))
    (folder / "samples.csv").write_text(samples)
    return folder


Q = "0.1,-0.5,0.2,-2.0,0.1,1.6,0.3"  # + a digit per row: a repeated row is refused


def test_a_placement_column_prefixes_the_group(tmp_path):
    pairs = [("a", "h0"), ("a", "h0"), ("b", "h0"), ("b", "h0")]  # two samples per group
    rows = "\n".join(f"{k},{p},{g},{Q}{k}" for k, (p, g) in enumerate(pairs))
    folder = write_dataset(
        tmp_path / "d", f"id,placement,group,{','.join(f'q{i}' for i in range(1, 8))}\n{rows}\n"
    )
    assert load_dataset(folder).groups == ("a/h0", "a/h0", "b/h0", "b/h0")


def test_a_group_with_a_single_sample_is_named_and_removing_it_works(tmp_path):
    """One sample in a group whose point is unknown tells nothing (a misspelt group name, or
    a socket visited once): refused naming the group, the sample and the likely misspelling;
    doing what the message says (remove the row) loads."""
    groups = ["a/h0", "a/h0", "a/h1", "a/h1", "a/h_1"]
    rows = [f"{k},{g},{Q}{k}" for k, g in enumerate(groups)]
    header = f"id,group,{','.join(f'q{i}' for i in range(1, 8))}"
    folder = write_dataset(tmp_path / "d", header + "\n" + "\n".join(rows) + "\n")
    with pytest.raises(RelcalError) as info:
        load_dataset(folder)
    message = str(info.value)
    assert "group 'a/h_1' has a single sample (id 4)" in message, message
    assert "a misspelt 'a/h1'?" in message and "remove the row" in message, message
    (folder / "samples.csv").write_text(header + "\n" + "\n".join(rows[:-1]) + "\n")
    assert load_dataset(folder).groups == tuple(groups[:-1])


@pytest.mark.parametrize(
    ("header", "spec", "message"),
    [
        ("id,group,x,y,z", {}, "either one or the other"),
        ("id,x,y,z", {"measurement": "coincidence"}, "has no 'group' column"),
        ("id,group", {"distances": [{"groups": ["a/h0", "a/h9"], "distance": 0.05}]},
         "group 'a/h9' has no samples.*did you mean 'a/h1'"),
        ("id,group", {"distances": [{"groups": ["a/h0", "a/h1"], "distance": 50}]},
         "distances are in metres"),
        ("id,x,y,z", {"tool": {"xyz": [0, 0, 0]}}, "tool: only for coincidence samples"),
    ],
)  # fmt: skip
def test_coincidence_datasets_refuse_what_does_not_fit(tmp_path, header, spec, message):
    joints = ",".join(f"q{i}" for i in range(1, 8))
    cells = {"id": "{k}", "group": "{g}", "x": "0.1{k}", "y": "0.2", "z": "0.3"}  # rows differ
    row = ",".join(cells[h] for h in header.split(","))
    lines = [row.format(k=k, g=g) + f",{Q}{k}" for k, g in enumerate(["a/h0", "a/h1", "a/h1"])]
    folder = write_dataset(tmp_path / "d", f"{header},{joints}\n" + "\n".join(lines) + "\n", **spec)
    with pytest.raises(RelcalError, match=message):
        load_dataset(folder)


def socket_rows(robot: str) -> dict[str, int]:
    """Rows of each joint file of a MUKCa robot folder (``PLACEMENT/hole_k``)."""
    out = {}
    for f in sorted((MUKCA / "data" / robot).glob("*/hole_*.csv")):
        if not f.stem.endswith("_pose"):
            out[f"{f.parent.name}/{f.stem}"] = sum(1 for line in f.open() if line.strip())
    return out


def test_mukca_import_keeps_every_joint_row_and_reads_no_pose_file(tmp_path):
    done = import_mukca(MUKCA / "data" / "panda_2", tmp_path / "p2", URDF["panda"], distance=0.05)
    ds = load_dataset(done.folder)
    rows = socket_rows("panda_2")
    assert done.n_samples == len(ds.q) == sum(rows.values()) == 559
    assert {g: ds.groups.count(g) for g in rows} == rows
    # mid_left/hole_1 has 32 joint rows and 38 pose rows: only the joint file counts
    assert rows["mid_left/hole_1"] == 32
    assert len(ds.distances) == 9 and ds.distances[0][2:] == (0.05, 1e-4)
    assert ds.robot_id == "panda_2" and ds.model.n_joints == 7
    text = (done.folder / "dataset.yaml").read_text()
    assert "urdf: robot.urdf" in text and str(URDF["panda"].parent) not in text  # a copy
    assert (done.folder / "robot.urdf").read_bytes() == URDF["panda"].read_bytes()
    assert {p.name for p in done.folder.iterdir()} - {".relcal-set.json"} == {
        "dataset.yaml",
        "robot.urdf",
        "samples.csv",
    }


def test_mukca_import_refuses_a_full_folder_and_a_wrong_robot(tmp_path):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("")
    with pytest.raises(RelcalError, match="--out"):
        import_mukca(MUKCA / "data" / "panda_1", tmp_path / "full", URDF["panda"])
    bad = tmp_path / "robot" / "front"
    bad.mkdir(parents=True)
    (bad / "hole_0.csv").write_text("0.1,0.2,0.3,0.4,0.5,0.6\n")
    with pytest.raises(RelcalError, match="6 values, expected 7 joint angles"):
        import_mukca(tmp_path / "robot", tmp_path / "out", URDF["panda"])


def test_import_mukca_command_and_what_calibrate_says_of_it(tmp_path, capsys):
    out = tmp_path / "kuka"
    argv = ["import", "mukca", str(MUKCA / "data" / "kuka_14"), "--urdf", str(URDF["iiwa14"])]
    assert main([*argv, "--distance", "0.05", "--out", str(out)]) == 0
    assert "dataset written to" in capsys.readouterr().out
    ds = load_dataset(out)
    assert len(ds.q) == sum(socket_rows("kuka_14").values()) == 180
    assert main(["import", "mukca", str(MUKCA / "data" / "kuka_14"), "--out", str(tmp_path / "x")])
    assert "--urdf FILE is required" in capsys.readouterr().err
    assert main(["measure", str(out)]) != 0
    assert "nothing to measure" in capsys.readouterr().err
    # calibrate: a named placement held out, the report and the registry record
    cal, report, registry = tmp_path / "cal", tmp_path / "r.html", tmp_path / "reg.sqlite"
    argv = ["calibrate", str(out), "--out", str(cal), "--holdout-ids", "front", "--quiet"]
    assert main([*argv, "--report", str(report), "--registry", str(registry)]) == 0
    doc = json.loads((cal / "results.json").read_text())
    val = doc["validation"]
    assert val["placements"] == ["front"] and val["n_samples"] == len(doc["held_out_ids"]) == 62
    for which in ("baseline", "calibrated"):
        assert set(val[which]) == {"spread_mm", "distance_error_mm"}
        assert all(set(val[which][k]) == {"rms", "max"} for k in val[which])
    assert val["calibrated"]["spread_mm"]["rms"] < val["baseline"]["spread_mm"]["rms"]
    assert doc["settings"]["formulation"] == "coincidence" and doc["handeye"] is None
    assert set(doc["group_points_xyz_m"]) == {
        f"{p}/hole_{k}" for p in ("left_back", "raised_left") for k in (0, 1)
    }
    assert {p.name for p in cal.iterdir()} >= {"model.yaml", "robot.urdf", "parameters.csv"}
    assert "Held-out validation" in report.read_text()
    from relcal.fleet.registry import open_registry

    with open_registry(str(registry)) as reg:
        (run,) = reg.runs()
    assert run.errors["calibrated_position_rms_mm"] == val["calibrated"]["spread_mm"]["rms"]
    # placements, not samples, are held out; K within the placements
    assert main([*argv[:3], str(tmp_path / "c2"), "--holdout-ids", "0001"]) != 0
    assert "held out by placement, one of front, left_back, raised_left" in capsys.readouterr().err
    assert main([*argv[:3], str(tmp_path / "c2"), "--kfold", "4"]) != 0
    assert "has 3 placements" in capsys.readouterr().err


# The held-out placements of the kind's own fit before the skeleton (commit 665f6d6), each left
# out in turn, mm: baseline and calibrated spread RMS / max, distance error RMS / max.
BEFORE_SKELETON = {
    "panda_1": ((9.079, 17.088, 2.686, 3.219), (0.857, 1.974, 0.694, 1.048)),
    "panda_2": ((8.361, 18.091, 1.818, 2.730), (0.502, 2.758, 0.228, 0.345)),
    "kuka_14": ((0.750, 1.421, 0.075, 0.094), (0.296, 0.996, 0.098, 0.122)),
}


# (panda_2's nine placements: docs/tutorials/mukca.md runs the same 9-fold command, and the
# README's table quotes its figures, checked by tests/test_docs_commands.py)
@pytest.mark.parametrize("name", [n for n in ROBOTS if n != "panda_2"])
def test_calibrate_command_holds_out_each_placement_as_the_kind_did(mukca_sets, name, tmp_path):
    ds = mukca_sets[name]
    k = len(dict.fromkeys(placement_of(g) for g in ds.groups))
    argv = ["calibrate", str(ds.root), "--out", str(tmp_path / "c"), "--quiet", "--kfold", str(k)]
    # the plain least squares the kind fitted then (priors came later, issue 18)
    argv += ["--nongeometric", "none", "--keep-outliers", "--selection", "all", "--priors", "none"]
    assert main([*argv, "--json", str(tmp_path / "r.json")]) == 0
    pooled_doc = json.loads((tmp_path / "r.json").read_text())["cross_validation"]["pooled"]
    for which, numbers in zip(("baseline", "calibrated"), BEFORE_SKELETON[name], strict=True):
        s, d = pooled_doc[which]["spread_mm"], pooled_doc[which]["distance_error_mm"]
        got = (s["rms"], s["max"], d["rms"], d["max"])
        assert got == pytest.approx(numbers, abs=1.5e-3), (which, got)


# --- real data: each placement held out, against a plain SciPy Levenberg-Marquardt ---------------


def plain_lm(model, q, index, n_groups, distances, geometric, tool0, points0, sigma=None):
    """``scipy.optimize.least_squares(method="lm")`` of the geometric columns ``geometric``
    (indices into ``make_layout(model)``), the tool point and the group points; residuals
    ``p_g - F(q) t`` over ``sigma`` and ``(d - |p_a - p_b|) / std``, written from ``fk`` alone,
    the Jacobian by SciPy's finite differences. Without ``sigma``, a first fit with the
    distance rows at 0.1 mm gives it (1.4826 MAD of the coordinates' errors), then the fit is
    repeated with it. Returns the model, the tool point, the points and ``sigma``."""
    layout = make_layout(model)
    k = len(geometric)
    pairs = np.array([d[:2] for d in distances], dtype=int).reshape(-1, 2)
    lengths = np.array([d[2] for d in distances])
    stds = np.array([d[3] for d in distances])

    def unpack(x):
        errors = np.zeros(layout.size)
        errors[geometric] = x[:k]
        return apply_errors(model, layout, errors), x[k : k + 3], x[k + 3 :].reshape(-1, 3)

    def solve(x0, s):
        def fun(x):
            m, t, p = unpack(x)
            f = fk(m, q)
            r = (p[index] - (f[:, :3, :3] @ t + f[:, :3, 3])) / s
            d = np.linalg.norm(p[pairs[:, 0]] - p[pairs[:, 1]], axis=1)
            return np.concatenate([r.ravel(), (lengths - d) / stds])

        return least_squares(fun, x0, method="lm", x_scale="jac").x

    x = np.concatenate([np.zeros(k), tool0, points0.ravel()])
    if sigma is None:
        x = solve(x, 1e-4)
        m, t, p = unpack(x)
        f = fk(m, q)
        e = (p[index] - (f[:, :3, :3] @ t + f[:, :3, 3])).ravel()
        sigma = 1.4826 * np.median(np.abs(e - np.median(e)))
    return (*unpack(solve(x, sigma)), sigma)


def plain_placements_out(ds, geometric_of):
    """Leave one placement out with :func:`plain_lm` (baseline: no geometric column)."""
    groups = list(ds.groups)
    where = np.array([placement_of(g) for g in groups])
    base, cal = [], []
    for place in dict.fromkeys(where):
        test, train = np.flatnonzero(where == place), np.flatnonzero(where != place)
        c = make_coincidence(
            ds.model, ds.q[train], where_groups(groups, train), ds.distances, ds.tool_point
        )
        dist = [(a, b, d, s) for (a, b), d, s in zip(c.pairs, c.lengths, c.stds, strict=True)]
        args = (ds.model, ds.q[train], c.index, c.n_groups, dist)
        held = make_coincidence(
            ds.model, ds.q[test], where_groups(groups, test), ds.distances, np.zeros(3)
        )
        # as relcal: the noise from a fit of the geometry weighs the baseline's rows too
        m, t, _, sigma = plain_lm(*args, geometric_of(c, train), c.tool_point, c.points)
        cal.append(spread_of(m, ds.q[test], held, t))
        m, t, _, _ = plain_lm(*args, np.zeros(0, int), c.tool_point, c.points, sigma)
        base.append(spread_of(m, ds.q[test], held, t))
    return pooled_spread(base).summary(), pooled_spread(cal).summary()


def where_groups(groups, samples):
    return [groups[k] for k in samples]


@pytest.fixture(scope="module")
def mukca_sets(tmp_path_factory):
    root = tmp_path_factory.mktemp("mukca")
    return {
        name: load_dataset(
            import_mukca(MUKCA / "data" / name, root / name, URDF[urdf], distance=0.05).folder
        )
        for name, urdf in ROBOTS.items()
    }


@pytest.mark.parametrize("name", list(ROBOTS))
def test_real_sets_held_out_placements_match_a_plain_lm(mukca_sets, name):
    ds = mukca_sets[name]
    relcal, _ = placements_out(ds, **PLAIN)

    def geometric_of(c, train):
        """The same geometric columns relcal estimates on these training samples."""
        ident = analyse_problem(coincidence_problem(ds.model, ds.q[train], c))
        return ident.subset[ident.subset < make_layout(ds.model).size]

    plain_base, plain_cal = plain_placements_out(ds, geometric_of)
    ours = relcal.summary()
    print(f"\n{name}: held-out spread and distance error, mm (RMS / max)")
    for label, doc in (
        ("baseline", ours["baseline"]),
        ("calibrated", ours["calibrated"]),
        ("plain LM baseline", plain_base),
        ("plain LM", plain_cal),
    ):
        s, d = doc["spread_mm"], doc["distance_error_mm"]
        print(
            f"  {label:18s} {s['rms']:7.3f} / {s['max']:7.3f}   {d['rms']:7.3f} / {d['max']:7.3f}"
        )
    for key in ("spread_mm", "distance_error_mm"):
        # the same cost, solved by two solvers: the same optimum
        assert ours["calibrated"][key]["rms"] <= plain_cal[key]["rms"] * 1.001 + 1e-4
        assert ours["baseline"][key]["rms"] <= plain_base[key]["rms"] * 1.001 + 1e-4
    assert ours["calibrated"]["spread_mm"]["rms"] < 0.5 * ours["baseline"]["spread_mm"]["rms"]


@pytest.mark.parametrize("priors", ["none", "model"])
def test_real_parameters_outside_the_combinations_are_shown_identified(mukca_sets, priors):
    """The base's motion turns the free points (a curved symmetry) and the Panda's ball sits a
    fraction of a millimetre off joint 7's axis: neither may mark the other link parameters as
    undetermined (a held parameter moving by 1 deg moves them by a few hundredths of their
    standard deviation); with priors too (the data's own refit decides, not the priors' pull)."""
    result = calibrate(mukca_sets["panda_2"], holdout=0, priors=priors, **PLAIN).result
    ident = result.identifiability
    n_geo = result.problem.layout.size
    involved = np.linalg.norm(ident.null_space, axis=1) > 1e-6
    estimated = np.zeros(len(result.params), bool)
    estimated[ident.subset] = True
    geometric = np.arange(len(result.params)) < n_geo
    names = np.array(result.names)
    assert set(names[geometric & estimated & involved]) == {"a[7]", "d[6]"}
    assert result.identifiable[geometric & estimated & ~involved].all()


def test_another_robots_joints_or_a_wrong_distance_are_refused(mukca_sets):
    ds = mukca_sets["panda_1"]
    iiwa = load_urdf(URDF["iiwa14"], None, "ball_link")
    # the Panda's readings beyond the iiwa's joint limits: the gate every kind shares names it
    with pytest.raises(RelcalError, match="is outside the model's limits.*another robot"):
        calibrate(replace(ds, model=iiwa, tool_point=np.zeros(3)), **PLAIN)
    # within the limits (the iiwa's ranges widened), the coincidences themselves tell
    wide = replace(iiwa, lower=np.full(7, -np.pi * 2), upper=np.full(7, np.pi * 2))
    with pytest.raises(RelcalError, match="dataset.yaml: the nominal robot.*mm RMS apart.*joints"):
        calibrate(replace(ds, model=wide, tool_point=np.zeros(3)), **PLAIN)
    wrong = tuple((a, b, 0.1, s) for a, b, _, s in ds.distances)  # another plate's spacing
    with pytest.raises(RelcalError, match="100 mm given, 5[0-9].[0-9] mm between the points"):
        calibrate(replace(ds, distances=wrong), **PLAIN)


def test_a_problem_restricted_to_some_samples_keeps_their_groups_and_distances(panda, exact):
    c = make_coincidence(panda, exact.q, exact.groups, distances_of(exact))
    problem = coincidence_problem(panda, exact.q, c)
    keep = np.flatnonzero(np.isin(np.array(exact.groups), ["p0/hole_1", "p1/hole_0", "p1/hole_1"]))
    first_two = [k for k, g in enumerate(exact.groups) if placement_of(g) in ("p0", "p1")]
    assert c.samples_of(["p0", "p1"]).tolist() == first_two
    sub = restricted(problem, keep)
    assert sub.coincidence.names == ("p0/hole_1", "p1/hole_0", "p1/hole_1")
    assert sub.coincidence.pairs.tolist() == [[1, 2]]  # p0's distance lost its other group
    np.testing.assert_array_equal(sub.coincidence.points, c.points[1:4])
    full = truth_vector(problem, exact)
    part = np.concatenate([full[: problem.layout.size + 3], full[problem.layout.size + 6 : -6]])
    np.testing.assert_allclose(
        residuals(sub, part, jacobian=False),
        np.concatenate(
            [residuals(problem, full, jacobian=False)[:-3].reshape(-1, 3)[keep].ravel(), [0.0]]
        ),
        atol=1e-11,
    )
