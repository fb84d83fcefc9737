"""Plans a real cell can run: the robot's own and the user's joint limits, self- and cell
collisions of capsules about the links, a travel order with short joint moves over the angles'
equivalents, and the plan file that names the joints and states its unit."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from relcal.cli import main
from relcal.design.cell import Cell, default_handeye
from relcal.design.collision import cell_collision, segment_distance, self_collision, skeleton
from relcal.design.feasibility import Constraints, check
from relcal.design.planfile import plan_text, read_plan
from relcal.design.travel import move_costs, nearest_neighbour, two_opt, unwrap
from relcal.errors import RelcalError
from relcal.robot.kinematics import forward_frames
from relcal.robot.loading import get_robot
from relcal.robot.model import restrict_limits

UR5E = get_robot("ur5e")
HOME = np.radians([0.0, -90.0, 90.0, -90.0, -90.0, 0.0])


def test_library_limits_follow_the_manufacturers():
    """UR's own description limits the UR5e elbow to +-180 deg (its other joints +-360); the FR3's
    are Franka's published values."""
    np.testing.assert_allclose(np.degrees(UR5E.upper), [360, 360, 180, 360, 360, 360])
    np.testing.assert_allclose(np.degrees(UR5E.lower), [-360, -360, -180, -360, -360, -360])
    fr3 = get_robot("franka_fr3")
    np.testing.assert_allclose(fr3.lower[[3, 5]], [-3.0421, 0.5445])
    np.testing.assert_allclose(fr3.upper[[3, 5]], [-0.1518, 4.5169])


def test_segment_distance_against_sampling():
    rng = np.random.default_rng(0)
    p0, p1, q0, q1 = (rng.normal(size=(200, 3)) for _ in range(4))
    p1[:20] = p0[:20]  # points
    q1[20:40] = q0[20:40]  # points as the second segment (the camera's sphere)
    exact = segment_distance(p0, p1, q0, q1)
    t = np.linspace(0, 1, 1001)[:, None]
    for k in [*range(0, 200, 7), *range(20, 40, 4)]:
        a = p0[k] + t * (p1[k] - p0[k])
        b = q0[k] + t * (q1[k] - q0[k])
        sampled = np.linalg.norm(a[:, None] - b[None], axis=-1).min()
        assert exact[k] <= sampled + 1e-12 and sampled - exact[k] < 2e-3
    # parallel and crossing segments, by hand
    x = np.array([1.0, 0, 0])
    assert segment_distance(0 * x, x, np.array([0, 0.3, 0]), np.array([1, 0.3, 0])) == 0.3
    cross = segment_distance(-x, x, np.array([0, -1, 0.2]), np.array([0, 1, 0.2]))
    assert cross == pytest.approx(0.2)


def test_skeleton_follows_the_dh_frames():
    seg, links = skeleton(UR5E, HOME[None], default_handeye())
    origins = forward_frames(UR5E, HOME[None])[0, :, :3, 3]
    # consecutive segments join, from the base to the last joint frame, then the camera
    ends = seg[0, :, 1][:-2]
    np.testing.assert_allclose(seg[0, 1:-1, 0], ends, atol=1e-12)
    np.testing.assert_allclose(seg[0, 0, 0], origins[0])
    assert links[-1] == 7 and links[:2] == [1, 2]


def test_self_collision_of_a_folded_ur5e_and_the_camera():
    free = self_collision(UR5E, HOME[None], default_handeye(), 0.04, 0.04)
    assert free[0]
    folded = HOME.copy()
    folded[2] = np.radians(178)  # forearm folded back onto the upper arm: wrist hits the shoulder
    assert not self_collision(UR5E, folded[None], default_handeye(), 0.04, 0.04)[0]
    assert self_collision(UR5E, folded[None], default_handeye(), 0.0, 0.0)[0]  # check off


def test_cell_collision_with_a_box():
    frames = forward_frames(UR5E, HOME[None])[0]
    wrist = frames[4, :3, 3]
    box = np.r_[wrist - 0.02, wrist + 0.02]
    assert not cell_collision(UR5E, HOME[None], default_handeye(), box[None], 0.04, 0.04)[0]
    away = np.array([[2.0, 2.0, 2.0, 2.5, 2.5, 2.5]])
    assert cell_collision(UR5E, HOME[None], default_handeye(), away, 0.04, 0.04)[0]
    masks = check(UR5E, Cell(), HOME[None], Constraints(obstacles=(tuple(box),)))
    assert not masks["cell collision"][0]


def test_user_limits_narrow_and_never_widen():
    narrow = restrict_limits(UR5E, {"elbow": (-2.0, 2.0), "q6": (-1.0, 1.0)})
    assert narrow.upper[2] == 2.0 and narrow.lower[5] == -1.0 and narrow.upper[0] == UR5E.upper[0]
    with pytest.raises(RelcalError, match="goes beyond the robot's own limits"):
        restrict_limits(UR5E, {"elbow": (-4.0, 4.0)})
    with pytest.raises(RelcalError, match="unknown joint 'knee'"):
        restrict_limits(UR5E, {"knee": (0.0, 1.0)})


def test_unwrap_takes_the_near_equivalent_within_limits():
    q = np.tile(HOME, (3, 1))
    q[:, 5] = np.radians([170.0, -170.0, 175.0])  # wrist3, limits +-360
    q[:, 2] = np.radians([170.0, -170.0, 170.0])  # elbow, limits +-180: no equivalent
    out = unwrap(UR5E, q)
    np.testing.assert_allclose(np.degrees(out[:, 5]), [170.0, 190.0, 175.0])
    np.testing.assert_allclose(np.degrees(out[:, 2]), [170.0, -170.0, 170.0])
    cost = move_costs(UR5E, q)
    assert np.degrees(cost[0, 1]) == pytest.approx(340.0)  # the elbow must go round


def test_two_opt_finds_the_best_open_path_on_small_sets():
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.uniform(UR5E.lower / 2, UR5E.upper / 2, (7, 6))
        cost = move_costs(UR5E, q)

        def length(order, cost=cost):
            return sum(cost[a, b] for a, b in itertools.pairwise(order))

        nn = nearest_neighbour(cost, 0)
        improved = two_opt(cost, nn)
        best = min(length(p) for p in itertools.permutations(range(7)))
        assert length(improved) <= length(nn) + 1e-12
        assert length(improved) <= 1.15 * best


def test_plan_file_round_trip_and_old_files(tmp_path):
    q = np.radians([[10.0, -80, 90, -100, -90, 45], [20.0, -70, 80, -90, -95, 30]])
    path = tmp_path / "plan.csv"
    path.write_text(plan_text(UR5E, q))
    text = path.read_text().splitlines()
    assert text[0] == "# relcal plan: robot Universal Robots UR5e, joint unit deg"
    assert text[1] == "id,shoulder_pan,shoulder_lift,elbow,wrist1,wrist2,wrist3"
    plan = read_plan(path, UR5E)
    assert plan.ids == ("p001", "p002") and plan.unit == "deg" and plan.robot == UR5E.name
    np.testing.assert_allclose(plan.q, q)
    path.write_text(plan_text(UR5E, q, unit="rad"))
    np.testing.assert_allclose(read_plan(path, UR5E).q, q)
    with pytest.raises(RelcalError, match="states joint unit rad, but deg was asked"):
        read_plan(path, UR5E, "deg")
    old = tmp_path / "old.csv"  # what relcal plan wrote before: id,q1..qn in degrees
    old.write_text("id,q1,q2,q3,q4,q5,q6\np001,10,-80,90,-100,-90,45\n")
    np.testing.assert_allclose(read_plan(old, UR5E).q, q[:1])
    with pytest.raises(RelcalError, match="is for robot 'Universal Robots UR5e', not 'Franka"):
        read_plan(path, get_robot("franka_fr3"))
    bad = tmp_path / "bad.csv"
    bad.write_text("id,q1,q2,q3,q4,q5,q6\np001,10,-80,ninety,-100,-90,45\n")
    with pytest.raises(RelcalError, match="line 2: q3: expected a number, got 'ninety'"):
        read_plan(bad, UR5E)


def test_command_line_ur5e_plan_a_cell_can_run(tmp_path, capsys):
    """The issue's case: `relcal plan --robot ur5e` planned elbow values of -314 to +278 deg and
    consecutive poses 552 deg apart on one joint. Now the elbow stays in UR's +-180 deg (and in
    the user's narrower limits), and every single move is shorter than in the selection's own
    order."""
    out = tmp_path / "plan.csv"
    argv = ["plan", "--robot", "ur5e", "--poses", "12", "--candidates", "300"]
    argv += ["--random-sets", "2", "--out", str(out), "--limits", "elbow=-150:150"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "travel order: longest single move" in printed and "self-collision" in printed
    plan = read_plan(out, UR5E)
    assert plan.q.shape == (12, 6)
    assert np.abs(np.degrees(plan.q[:, 2])).max() <= 150 + 1e-9
    assert (plan.q >= UR5E.lower).all() and (plan.q <= UR5E.upper).all()
    longest = np.degrees(np.abs(np.diff(plan.q, axis=0)).max())
    assert longest <= 360
    assert f"longest single move {longest:.1f} deg" in printed
    masks = check(UR5E, Cell(), plan.q, Constraints())
    assert all(m.all() for k, m in masks.items() if k != "joint limits")


def test_command_line_limits_and_obstacles_errors(tmp_path, capsys):
    base = ["plan", "--robot", "ur5e", "--poses", "5", "--candidates", "50", "--quiet"]
    assert main([*base, "--limits", "elbow=-200:200"]) == 2
    assert "beyond the robot's own limits" in capsys.readouterr().err
    assert main([*base, "--limits", "elbow:-10:10"]) == 2
    assert "expected NAME=LOWER:UPPER" in capsys.readouterr().err
    assert main([*base, "--obstacle", "1,1,1,0,0,0"]) == 2
    assert "each minimum below its maximum" in capsys.readouterr().err
    spec = tmp_path / "dataset.yaml"
    spec.write_text("robot: ur5e\njoint_unit: deg\njoint_limits:\n  elbow: [-120, 120]\n")
    from relcal.cli.plan import parse_limits

    assert parse_limits(str(spec), UR5E, "deg") == {"elbow": pytest.approx((-2.0944, 2.0944), 1e-4)}


def test_dataset_joint_limits_narrow_the_model(tmp_path):
    from relcal.data.dataset import load_dataset

    rows = ["id,q1,q2,q3,q4,q5,q6,x,y,z,qx,qy,qz,qw"]
    rows += [f"s{k},{10 * k},-80,90,-100,-90,45,0.1,0.2,0.3,0,0,0,1" for k in range(6)]
    (tmp_path / "samples.csv").write_text("\n".join(rows) + "\n")
    spec = "robot: ur5e\nhayati: off\njoint_unit: deg\njoint_limits:\n  elbow: [-120, 120]\n"
    (tmp_path / "dataset.yaml").write_text(spec)
    model = load_dataset(tmp_path).model
    np.testing.assert_allclose(np.degrees([model.lower[2], model.upper[2]]), [-120, 120])
    assert model.upper[0] == UR5E.upper[0]
    (tmp_path / "dataset.yaml").write_text(spec.replace("[-120, 120]", "[-200, 200]"))
    with pytest.raises(RelcalError, match="dataset.yaml: joint_limits: elbow: .* beyond"):
        load_dataset(tmp_path)
