"""Line of sight in planning (relcal.design.sight): the camera must see the pattern past the
robot's own links. Checked against a brute-force distance, a URDF's collision geometry laid out
by hand, and the virtual cell's MuJoCo rendering of the planned poses."""

from __future__ import annotations

import numpy as np
import pytest

from relcal.design.cell import Cell
from relcal.design.collision import skeleton
from relcal.design.feasibility import Constraints, camera_poses, check, line_of_sight
from relcal.design.sight import sight_lines, skeleton_sight_free
from relcal.robot.loading import get_robot

UR5E = get_robot("ur5e")


def point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from points ``p`` ``(..., 3)`` to segment ``a b``."""
    ab = b - a
    t = np.clip(np.einsum("...i,...i->...", p - a, ab) / max(ab @ ab, 1e-18), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


def test_sight_lines_run_from_near_the_camera_to_the_pattern():
    cell = Cell()
    rng = np.random.default_rng(0)
    q = rng.uniform(-np.pi, np.pi, (3, 6))
    cams = camera_poses(UR5E, cell, q)
    lines = sight_lines(cams, cell.board_pose, cell.corners, grid=4, near=0.03, far=0.01)
    assert lines.shape == (3, 16, 2, 3)
    eye = cams[:, None, :3, 3]
    np.testing.assert_allclose(np.linalg.norm(lines[:, :, 0] - eye, axis=-1), 0.03)
    # extended by `far`, every line ends on the board's plane inside the pattern, the lattice's
    # first and last points on the pattern's corners
    unit = lines[:, :, 1] - lines[:, :, 0]
    unit /= np.linalg.norm(unit, axis=-1, keepdims=True)
    ends = lines[:, :, 1] + 0.01 * unit
    local = (ends - cell.board_pose[:3, 3]) @ cell.board_pose[:3, :3]
    np.testing.assert_allclose(local[..., 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(local[:, 0], np.broadcast_to(cell.corners[0], (3, 3)), atol=1e-12)
    np.testing.assert_allclose(local[:, -1], np.broadcast_to(cell.corners[2], (3, 3)), atol=1e-12)
    with pytest.raises(ValueError, match="grid"):
        sight_lines(cams, cell.board_pose, cell.corners, grid=1)


def test_skeleton_check_agrees_with_a_brute_force_distance():
    """Random configurations and random sight lines: blocked exactly when some point along a
    line lies within the capsule radius of a link segment (sampled every 0.5 mm)."""
    rng = np.random.default_rng(3)
    n, radius = 60, 0.04
    q = rng.uniform(-np.pi, np.pi, (n, 6))
    handeye = Cell().handeye
    lines = rng.uniform(-0.6, 0.6, (n, 3, 2, 3)) + np.array([0.3, 0.0, 0.3])
    free = skeleton_sight_free(UR5E, q, handeye, lines, radius)
    seg, links = skeleton(UR5E, q, handeye)
    body = seg[:, np.array(links) != UR5E.n_joints + 1]
    brute, margins = [], []
    for k in range(n):
        nearest = np.inf
        for a, b in lines[k]:
            steps = int(np.ceil(np.linalg.norm(b - a) / 5e-4)) + 1
            points = a + np.linspace(0, 1, steps)[:, None] * (b - a)
            for s0, s1 in body[k]:
                nearest = min(nearest, point_segment_distance(points, s0, s1).min())
        brute.append(nearest >= radius)
        margins.append(abs(nearest - radius))
    brute, margins = np.array(brute), np.array(margins)
    clear = margins > 1e-3  # cases the sampling decides
    np.testing.assert_array_equal(free[clear], brute[clear])
    assert 5 < (~free).sum() < n - 5  # both outcomes present


ARM = """<?xml version="1.0"?>
<robot name="column_arm">
  <link name="base_link">
    <collision><origin xyz="0.5 0 0.05"/><geometry><box size="0.1 0.1 0.1"/></geometry></collision>
  </link>
  <joint name="j1" type="revolute"><parent link="base_link"/><child link="column"/>
    <origin xyz="0 0 0.1"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/>
  </joint>
  <link name="column">
    <collision><origin xyz="0 0 0.15"/><geometry><cylinder radius="0.04" length="0.3"/></geometry>
    </collision>
  </link>
  <joint name="j2" type="revolute"><parent link="column"/><child link="upper"/>
    <origin xyz="0 0 0.3"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/>
  </joint>
  <link name="upper">
    <collision><origin xyz="0.15 0 0" rpy="0 1.5707963 0"/>
      <geometry><cylinder radius="0.03" length="0.3"/></geometry></collision>
  </link>
  <joint name="tool" type="fixed"><parent link="upper"/><child link="tool0"/>
    <origin xyz="0.3 0 0"/></joint>
  <link name="tool0">
    <collision><geometry><sphere radius="0.03"/></geometry></collision>
  </link>
</robot>
"""


def test_urdf_check_uses_the_collision_geometry(tmp_path):
    pytest.importorskip("fcl")
    from relcal.design.feasibility import urdf_geometry
    from relcal.design.sight import urdf_sight_free

    path = tmp_path / "arm.urdf"
    path.write_text(ARM)
    arm = get_robot(str(path), "base_link", "tool0")
    geometry = urdf_geometry(arm)
    assert geometry is not None
    # horizontal lines across the column (axis x = y = 0, radius 0.04, z 0.1 .. 0.4) at
    # z = 0.25, offset sideways by y; rays of radius 1 mm
    ys = [0.0, 0.035, 0.038, 0.042, 0.045, 0.2]
    lines = np.array([[[[-0.3, y, 0.25], [0.3, y, 0.25]]] for y in ys])
    q = np.zeros((len(ys), 2))
    np.testing.assert_array_equal(
        urdf_sight_free(geometry, q, lines), [False, False, False, True, True, True]
    )
    # the upper arm and the sphere on the tool link move with the camera (no pose changes what
    # they hide) and are left out; the column and a static body (the box on the base, off the
    # chain) hide the view
    from relcal.design.sight import camera_bodies

    assert sorted(geometry.bodies[k].link for k in camera_bodies(geometry)) == ["tool0", "upper"]
    over_upper = [[0.15, -0.2, 0.4], [0.15, 0.2, 0.4]]  # across the upper arm at q = 0
    base_box = [[0.5, -0.3, 0.05], [0.5, 0.3, 0.05]]
    tool_sphere = [[0.31, -0.2, 0.4], [0.31, 0.2, 0.4]]
    lines = np.array([[base_box], [tool_sphere], [over_upper]])
    np.testing.assert_array_equal(
        urdf_sight_free(geometry, np.zeros((3, 2)), lines), [False, True, True]
    )


def test_check_reports_the_line_of_sight_and_can_turn_it_off():
    rng = np.random.default_rng(1)
    q = rng.uniform(-np.pi, np.pi, (200, 6))
    cell = Cell()
    every = np.ones(len(q), dtype=bool)
    on = line_of_sight(UR5E, cell, q, Constraints(), every)
    off = line_of_sight(UR5E, cell, q, Constraints(sight_grid=0), every)
    assert off.all() and 0 < (~on).sum() < len(q)
    masks = check(UR5E, cell, q, Constraints())
    assert "line of sight" in masks and masks["line of sight"].shape == (len(q),)


def rejected_frames(robot: str, q: np.ndarray) -> list[str | None]:
    """Per configuration of ``q`` ``(N, n)`` (rad), why the virtual cell's rendered (noise-free)
    frame fails the capture's frame gates, or None: what a capture would skip."""
    from relcal.capture.loop import judge_frame
    from relcal.capture.virtual import make_cell

    cell = make_cell(get_robot(robot), seed=1)
    out: list[str | None] = []
    try:
        for row in q:
            levels, _ = cell.renderer.render(row)
            image = (np.clip(levels, 0, 1) * 255).astype(np.uint8)
            judged = judge_frame(image, cell.truth.board, cell.truth.camera)
            out.append(judged if isinstance(judged, str) else None)
    finally:
        cell.close()
    return out


# Configurations (deg) of a UR5e plan searched without the check (relcal plan --robot ur5e
# --poses 30 --candidates 400 --random-sets 0 --sight-lines 0): in the first two the arm hides
# part of the board in the virtual cell's image, the others see all of it.
HIDDEN = [[196.945, 1.553, -91.745, 9.091, -111.557, -94.092],
          [173.872, 12.107, -50.514, 158.152, -252.366, -87.405]]  # fmt: skip
SEEN = [[195.581, -82.863, 122.037, -126.937, -121.334, -85.147],
        [130.967, -95.514, 97.585, -74.028, -65.328, -132.852],
        [22.077, -193.19, 118.06, 14.244, -85.417, -158.471],
        [174.894, -80.906, 104.463, -102.627, -107.499, 106.404]]  # fmt: skip


def test_the_check_finds_the_poses_whose_image_shows_a_link_over_the_board():
    """The rendered image is the independent truth: the two poses it shows hidden fail the
    frame gates and the line-of-sight check; the four it shows whole pass both."""
    q = np.radians(np.array(HIDDEN + SEEN))
    rejected = rejected_frames("ur5e", q)
    assert [r is not None for r in rejected] == [True, True, False, False, False, False]
    assert all("board not found" in r or "too few points" in r for r in rejected[:2])
    sight = line_of_sight(UR5E, Cell(), q, Constraints(), np.ones(len(q), dtype=bool))
    np.testing.assert_array_equal(sight, [False, False, True, True, True, True])


def test_a_ur5e_plan_with_the_check_has_no_self_occluded_pose(tmp_path):
    from relcal.cli import main
    from relcal.design.planfile import read_plan

    out = tmp_path / "plan.csv"
    args = ["plan", "--robot", "ur5e", "--poses", "12", "--candidates", "200",
            "--random-sets", "0", "--out", str(out), "--quiet"]  # fmt: skip
    assert main(args) == 0
    rejected = rejected_frames("ur5e", read_plan(out, UR5E).q)
    assert [r for r in rejected if r is not None] == []
