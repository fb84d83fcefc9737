"""Pose planning: feasibility checks, fast criteria against direct evaluation, greedy and exchange
selection, the plan against random feasible sets, and the Monte Carlo confirmation."""

import cv2
import numpy as np
import pytest

from relcal import geometry as tf
from relcal.cli import main
from relcal.cli.plan import parse_board, parse_camera
from relcal.data.dataset import read_joints
from relcal.design.cell import Cell
from relcal.design.plan import (
    CRITERIA,
    DEFAULT_NOISE,
    Constraints,
    Scorer,
    _values,
    candidates,
    check,
    criterion,
    exchange,
    greedy,
    information,
    plan,
    selection_problem,
    travel_order,
)
from relcal.errors import RelcalError
from relcal.reporting.documents import accuracy_document
from relcal.robot.kinematics import fk
from relcal.robot.model import auto_hayati
from relcal.sim.scenario import make_scenario
from relcal.sim.study import study, worst
from relcal.vision.boards import pattern_extent

CELL = dict(center=np.array([0.4, 0.0, 0.0]))


@pytest.fixture(scope="module")
def hayati():
    from relcal.robot.loading import get_robot

    return auto_hayati(get_robot("a465"))


@pytest.fixture(scope="module")
def pool(hayati):
    q, rejected = candidates(hayati, Cell(), Constraints(), 250, seed=0)
    return q, rejected


def test_candidates_satisfy_every_constraint(hayati, pool):
    """Each candidate against the constraints computed independently: OpenCV's projection of the
    board's outer corners, distances and angles from the forward kinematics, and the joint
    Jacobian by finite differences."""
    q, rejected = pool
    assert len(q) == 250
    assert rejected["ik"] > 0 and rejected["board in view"] > 0  # the checks do reject
    cell, c = Cell(), Constraints()
    cam = cell.camera
    k_matrix = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1.0]])
    x0, y0, x1, y1 = pattern_extent(cell.board)
    corners = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], dtype=float)
    for qk in q[::10]:
        camera = fk(hayati, qk[None])[0] @ cell.handeye  # base-from-camera
        in_camera = np.linalg.inv(camera) @ cell.board_pose
        rvec, _ = cv2.Rodrigues(np.ascontiguousarray(in_camera[:3, :3]))
        tvec = np.ascontiguousarray(in_camera[:3, 3])
        pix, _ = cv2.projectPoints(corners, rvec, tvec, k_matrix, np.zeros(5))
        pix = pix.reshape(-1, 2)
        depth = (in_camera[:3, :3] @ corners.T).T[:, 2] + in_camera[2, 3]
        assert (depth > 0).all()
        assert (pix >= c.margin_px).all()
        assert (pix[:, 0] <= cam.width - 1 - c.margin_px).all()
        assert (pix[:, 1] <= cam.height - 1 - c.margin_px).all()
        sight = camera[:3, 3] - np.array([0.45, 0.0, 0.0])  # the default board centre
        assert c.distance[0] <= np.linalg.norm(sight) <= c.distance[1]
        angle = np.degrees(np.arccos(sight[2] / np.linalg.norm(sight)))  # board faces up (+z)
        assert angle <= c.max_view_angle_deg
        assert sight[2] >= c.clearance
        assert ((qk >= hayati.lower) & (qk <= hayati.upper)).all()
        # Singularity: the camera's twist per joint by central differences, lengths over 0.5 m.
        cols = []
        for j in range(len(qk)):
            dq = np.zeros(len(qk))
            dq[j] = 1e-6
            cols.append(tf.pose_error(fk(hayati, qk + dq), fk(hayati, qk - dq)) / 2e-6)
        jac = np.array(cols).T
        jac[:3] /= c.length_scale
        s = np.linalg.svd(jac, compute_uv=False)
        assert s[-1] / s[0] >= c.min_inverse_condition


def test_each_constraint_rejects_what_it_should(hayati, pool):
    q = pool[0][:1].copy()
    cell, c = Cell(), Constraints()

    def failing(qq, constraints=c):
        return {name for name, ok in check(hayati, cell, qq, constraints).items() if not ok[0]}

    assert failing(q) == set()
    away = q.copy()
    away[0, 0] += np.pi  # turn the waist: the camera looks elsewhere
    assert "board in view" in failing(away)
    wrist = q.copy()
    wrist[0, 4] = 0.0  # A465 wrist singularity: axes 4 and 6 aligned
    assert "singularity" in failing(wrist)
    beyond = q.copy()
    beyond[0, 1] = hayati.upper[1] + 0.1
    assert "joint limits" in failing(beyond)
    assert "distance" in failing(q, Constraints(distance=(0.01, 0.02)))
    assert "viewing angle" in failing(q, Constraints(max_view_angle_deg=0.01))
    assert "board in view" in failing(q, Constraints(margin_px=1100))
    assert "clearance" in failing(q, Constraints(clearance=5.0))


def test_fast_criteria_match_direct_evaluation(hayati, pool):
    info = information(selection_problem(hayati, Cell(), pool[0]), DEFAULT_NOISE, 0.5)
    rng = np.random.default_rng(2)
    add = np.arange(40)
    for n_set in (0, 3, 29):
        base = info.total(rng.choice(len(pool[0]), n_set, replace=False))
        direct = base[None] + np.einsum("nri,nrj->nij", info.rows[add], info.rows[add])
        for name in CRITERIA:
            fast = _values(info, base, add, name, n_set + 1)
            slow = criterion(info, direct, name, n_set + 1)
            np.testing.assert_allclose(fast, slow, rtol=1e-6)


def test_exchange_improves_on_greedy_which_beats_random(hayati, pool):
    info = information(selection_problem(hayati, Cell(), pool[0]), DEFAULT_NOISE, 0.5)
    rng = np.random.default_rng(3)
    for name in ("worst", "O1", "O3"):
        g = greedy(info, 20, name)
        assert len(set(g)) == 20
        e, _ = exchange(info, g, name)
        value = {
            label: float(criterion(info, info.total(idx), name, 20))
            for label, idx in (("greedy", g), ("exchange", e))
        }
        random = [
            float(criterion(info, info.total(rng.choice(250, 20, replace=False)), name, 20))
            for _ in range(5)
        ]
        assert value["exchange"] >= value["greedy"] > max(random), (name, value, random)


def test_planned_poses_beat_random_feasible_sets_and_the_study_confirms_it(hayati, tmp_path):
    cell = Cell(**CELL)
    res = plan(hayati, cell, n_poses=30, n_candidates=1500, random_sets=20, seed=0)
    assert len(res.q) == 30 and len(res.random) == 20
    assert check(hayati, cell, res.q, Constraints())["board in view"].all()
    assert res.improvement >= 2.0, res.improvement  # worst-parameter std vs median random set
    # Lengths and angles both improve, and so does the predicted accuracy.
    median = res.random[int(np.argsort([r.worst[1] for r in res.random])[10])]
    assert res.plan.worst_length[1] < median.worst_length[1]
    assert res.plan.worst_angle[1] < median.worst_angle[1]
    assert (
        accuracy_document(res.plan.accuracy)["position_mm"]["p95"]
        < accuracy_document(median.accuracy)["position_mm"]["p95"]
    )
    # Monte Carlo: noisy calibrations from the plan and from the median random set.
    spreads = {}
    for label, q in (("plan", res.q), ("random", res.random_q)):
        scenario = make_scenario(hayati, q, DEFAULT_NOISE, seed=6)
        mc = study(scenario, trials=100, seed=1, workers=2, progress=False)
        _, predicted, _, empirical = worst(mc, 0.5)
        assert empirical == pytest.approx(predicted, rel=0.2)
        spreads[label] = empirical
    assert spreads["random"] / spreads["plan"] > 1.7, spreads


def test_travel_order_is_a_permutation_with_short_moves(hayati, pool):
    q = pool[0][:40]
    route = travel_order(hayati, q)
    assert sorted(route.order) == list(range(40))
    np.testing.assert_allclose(fk(hayati, route.q), fk(hayati, q[route.order]), atol=1e-12)
    step = np.abs(np.diff(route.q, axis=0)).max(axis=1).sum()
    assert step == pytest.approx(route.total)
    assert step < np.abs(np.diff(q, axis=0)).max(axis=1).sum()
    move, joint, value = route.longest
    assert value == np.abs(np.diff(route.q, axis=0)).max() == route.moves[move, joint]


def test_board_and_camera_arguments(tmp_path):
    board = parse_board("7x10@20mm")
    assert (board.rows, board.columns, board.spacing) == (7, 10, pytest.approx(0.02))
    assert parse_board("5X6@0.03").spacing == 0.03
    with pytest.raises(RelcalError, match="ROWSxCOLS@SQUARE"):
        parse_board("seven by ten")
    cam = parse_camera("2000,2000,640,480,1280,960")
    assert (cam.fx, cam.width, cam.height) == (2000, 1280, 960)
    frame = Cell(board=board, center=np.array([0.5, 0.1, 0.0])).board_pose
    # By hand: 7 x 10 squares of 20 mm put the pattern centre at (0.08, 0.05) in the board frame;
    # lying face up with x along base x, the board's y and z axes point along base -y and -z.
    np.testing.assert_allclose(frame[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-15)
    np.testing.assert_allclose(frame[:3, 3], [0.5 - 0.08, 0.1 + 0.05, 0.0], atol=1e-15)


def test_command_line_plan(tmp_path, hayati, capsys):
    out, rnd = tmp_path / "plan.csv", tmp_path / "random.csv"
    code = main(
        ["plan", "--robot", "a465", "--hayati", "auto", "--poses", "12", "--candidates", "200"]
        + ["--random-sets", "3", "--out", str(out), "--random-out", str(rnd)]
    )
    assert code == 0
    text = capsys.readouterr().out
    assert "12 poses selected from 200 feasible candidates" in text and "x lower" in text
    q = read_joints(out, hayati, "deg")
    assert q.shape == (12, 6) and read_joints(rnd, hayati, "deg").shape == (12, 6)
    assert check(hayati, Cell(), q, Constraints())["board in view"].all()
    assert main(["plan", "--board", "7 by 10"]) == 2


def test_candidate_batches_do_not_depend_on_how_many_are_drawn(hayati):
    """Each IK batch has its own random stream: asking for fewer candidates gives a prefix of
    the larger pool, batch by batch (so the pool cannot depend on how batches are shared out)."""
    cell, c = Cell(), Constraints()
    small, rej_small = candidates(hayati, cell, c, 70, seed=5, batch=60)
    large, rej_large = candidates(hayati, cell, c, 200, seed=5, batch=60)
    np.testing.assert_array_equal(small, large[:70])
    assert sum(rej_small.values()) < sum(rej_large.values())
    other, _ = candidates(hayati, cell, c, 70, seed=6, batch=60)
    assert not np.allclose(other, small)


@pytest.fixture(scope="module")
def cluster():
    """A local Dask cluster of 2 single-threaded worker processes (as `--workers 2` makes)."""
    pytest.importorskip("distributed")
    from relcal.cluster import local_cluster

    with local_cluster(2) as cluster:
        yield cluster


def test_plan_on_the_cluster_chooses_the_same_poses(hayati, cluster, monkeypatch):
    """`plan(client=...)`: candidate batches run as tasks and every scoring step on actors of
    both workers, and the pool, the plan and the random sets are those of one process."""
    from distributed import Client, get_task_stream

    import relcal.design.feasibility as feasibility
    import relcal.design.scoring as scoring

    monkeypatch.setattr(scoring, "MIN_SHARD", 100)  # a shard per worker for a small pool
    monkeypatch.setattr(scoring, "BLOCK", 64)  # several blocks per shard
    monkeypatch.setattr(feasibility, "TASK_SECONDS", 1e-6)  # one IK batch per task
    cell = Cell(**CELL)
    options = dict(n_poses=10, n_candidates=400, random_sets=3, seed=3)
    here = plan(hayati, cell, **options)
    with Client(cluster) as client, get_task_stream(client) as stream:
        there = plan(hayati, cell, **options, client=client)
    np.testing.assert_array_equal(there.q, here.q)
    assert there.rejected == here.rejected and there.swaps == here.swaps
    assert there.plan.worst == here.plan.worst
    np.testing.assert_array_equal(there.random_q, here.random_q)
    workers: dict[str, list] = {}
    for task in stream.data:
        workers.setdefault(task["key"].split("-")[0], []).append(task["worker"])
    assert len(workers["_batch_task"]) >= 2, workers  # the first batch runs here, to time it
    assert len(set(workers["_Shard"])) == 2, workers  # a scoring actor on each worker


def test_cluster_scoring_breaks_ties_as_one_process(hayati, pool, cluster, monkeypatch):
    """A pool of three identical copies scored in blocks on the cluster: equal scores go to the
    lowest index, so greedy and exchange choose exactly as in one process, for a criterion of
    the Woodbury path and one of the eigenvalue path."""
    from distributed import Client

    import relcal.design.scoring as scoring

    monkeypatch.setattr(scoring, "MIN_SHARD", 50)
    q = np.concatenate([pool[0][:60]] * 3)
    info = information(selection_problem(hayati, Cell(), q), DEFAULT_NOISE, 0.5)
    with Client(cluster) as client:
        for name in ("worst", "O3"):
            with Scorer(info) as local, Scorer(info, client, block=37) as remote:
                g = greedy(info, 8, name, local)
                assert g[0] < 60 and len(set(g)) == 8
                np.testing.assert_array_equal(greedy(info, 8, name, remote), g)
                e, swaps = exchange(info, g, name, scorer=local)
                np.testing.assert_array_equal(exchange(info, g, name, scorer=remote)[0], e)
                calls = remote.remote_calls
                assert len(calls) == 2 and min(calls) > 8, calls  # both workers scored


def test_command_line_plan_on_a_scheduler(cluster, tmp_path, capsys):
    """`relcal plan --scheduler`: the same CSV as without."""
    argv = ["plan", "--robot", "a465", "--hayati", "auto", "--poses", "8", "--candidates", "150"]
    argv += ["--random-sets", "2", "--quiet", "--out"]
    assert main([*argv, str(tmp_path / "here.csv")]) == 0
    there = tmp_path / "there.csv"
    assert main([*argv, str(there), "--scheduler", cluster.scheduler_address]) == 0
    assert there.read_text() == (tmp_path / "here.csv").read_text()
    assert capsys.readouterr().out == ""
