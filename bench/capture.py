"""Capture rows of ``make bench``: ``relcal capture`` in the virtual cell (MuJoCo on the CPU).

- the whole loop on a UR5e plan of 30 poses (640 x 512 px camera, normal camera, no faults):
  poses per minute of wall time (rendering, detection, dataset writes), and per minute of the
  simulated arm's time (moves at 1 rad/s, settling, the still window: what a real arm with the
  cell's dynamics would manage);
- per pose: the rendering time (MuJoCo scene with the board's pixels from relcal's analytic
  renderer) and the detection and gating time;
- per frame: the rendering time with the board's pixels from the analytic renderer against
  MuJoCo's own texture (supersampled twice), with the corner accuracy of each (RMS distance of
  the detected corners from the true projections, px), which is why the cell composes the two;
- the loop through the ``franka`` driver against franky-sim (an FR3 simulated on MuJoCo behind
  the libfranka protocol, its own process, over loopback) with the virtual camera following the
  driver's joints, on a 10-pose plan: poses per minute of wall time, the median time the arm
  took to become still after franky's move returned, and its median speed then (skipped without
  franky and franky-sim installed). franky-sim runs slower than real time on a busy machine, so
  this row measures the machine as much as the loop.

Wall times on this machine (shared: other processes may hold the cores). Run ``python
bench/capture.py`` for the rows; ``run()`` returns them.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # as bench/run.py: one BLAS thread

import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

N_POSES = 30
N_FRAMES = 12  # frames rendered for the per-frame rows


def _plan(model):
    from relcal.design.cell import Cell
    from relcal.design.plan import plan

    return plan(model, Cell(), n_poses=N_POSES, n_candidates=400, random_sets=0, seed=0).q


def _loop(model, q) -> dict:
    from relcal.capture.loop import capture
    from relcal.capture.record import DatasetWriter
    from relcal.capture.virtual import make_cell

    cell = make_cell(model, seed=0)
    ids = [f"p{k + 1:03d}" for k in range(len(q))]
    with tempfile.TemporaryDirectory() as tmp:
        writer = DatasetWriter(
            Path(tmp) / "ds", model, "ur5e", cell.truth.board, cell.truth.camera, ids, q
        )
        assert cell.renderer is not None  # built before timing: once per run, not per pose
        begin, cpu = time.perf_counter(), time.process_time()
        summary = capture(
            ids, q, model, cell.robot, cell.camera, cell.clock, cell.truth.board, writer,
            intrinsics=cell.truth.camera, progress=False,
        )  # fmt: skip
        wall = time.perf_counter() - begin
        cpu = time.process_time() - cpu
    attempts = sum(o.attempts for o in summary.outcomes)
    return {
        "wall": wall,
        "cpu": cpu,
        "recorded": len(summary.recorded),
        "attempts": attempts,
        "frames": len(cell.frames),
        "render": cell.render_seconds,
        "detect": summary.detect_seconds,
        "simulated": summary.seconds,
    }


def _frames(model, q, board_pixels: str) -> tuple[float, float]:
    """Least CPU milliseconds per rendered frame (MuJoCo's rasteriser runs on threads of this
    process: all count) and the median over frames of the RMS corner error (px)."""
    from relcal import geometry as tf
    from relcal.capture.virtual import make_cell
    from relcal.vision.boards import board_points
    from relcal.vision.detect import Rejected, detect
    from relcal.vision.render import finish_image

    cell = make_cell(model, seed=0, board_pixels=board_pixels)
    renderer = cell.renderer
    truth = cell.truth
    errors, seconds = [], []
    for k in range(N_FRAMES):
        begin = time.process_time()
        levels, pose = renderer.render(q[k % len(q)])
        image = finish_image(levels, 0.6, 1.5, 0.2, seed=k)
        seconds.append(time.process_time() - begin)
        found = detect(image, truth.board)
        if isinstance(found, Rejected):
            continue
        points = board_points(truth.board)[found.ids]
        inv = tf.invert(pose)
        projected = truth.camera.project(points @ inv[:3, :3].T + inv[:3, 3])
        errors.append(np.sqrt(np.mean(np.sum((found.image_points - projected) ** 2, axis=1))))
    renderer.close()
    return 1e3 * float(np.min(seconds)), float(np.median(errors)) if errors else float("nan")


# 10 FR3 poses (deg) with the board in view near the arm's working posture (relcal plan --robot
# franka_fr3 --poses 10 --limits ..., as in tests/test_driver_franka.py)
FR3_PLAN = [
    [11.9817, -25.1619, -30.3836, -161.5264, 19.3639, 152.5054, 65.4545],
    [-29.7851, -1.9404, -12.4640, -136.8881, 40.0488, 113.3454, 101.5599],
    [-10.9031, -9.9409, -5.0352, -155.0745, 35.8326, 146.9447, 127.5013],
    [2.8168, 25.5598, -31.8883, -112.2396, 38.9845, 101.6985, 109.3895],
    [-8.2178, 37.1238, -39.5565, -80.0521, 38.6522, 70.3647, 130.5058],
    [-29.4142, 31.2730, 12.4622, -98.2445, 16.9299, 101.9450, 79.1233],
    [14.3915, 25.2148, 18.1773, -83.9173, -27.2748, 80.9621, 101.2537],
    [10.0469, 13.5408, 23.7486, -128.7959, -39.2839, 112.4743, 49.7036],
    [30.7486, -38.6468, 0.4175, -169.5, -45.2529, 138.5112, 59.2162],
    [14.8471, 17.7353, -20.3796, -110.9896, 16.0535, 106.1706, -0.0628],
]
FRANKY_SERVER = (
    "import sys; from franky_sim.run_server import main; sys.argv[0] = 'franky-sim'; main()"
)


def _franky_sim() -> dict | None:
    """The loop through franky to a franky-sim process; None without franky / franky-sim."""
    import importlib.util
    import re
    import subprocess
    import sys

    if not all(importlib.util.find_spec(m) for m in ("franky", "franky_sim", "mujoco")):
        return None
    from relcal.capture.interfaces import RealClock
    from relcal.capture.loop import DEG, CaptureSettings, capture
    from relcal.capture.robots.franka import FrankaRobot
    from relcal.capture.virtual import FollowingCamera
    from relcal.robot.loading import get_robot

    env = dict(os.environ, PYTHONUNBUFFERED="1", MUJOCO_GL="disable")
    server = subprocess.Popen(
        [sys.executable, "-c", FRANKY_SERVER, "--simulator", "mujoco"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )
    try:
        host = None
        for _ in range(50):
            line = server.stdout.readline()
            found = re.search(r"using '([\d.]+)'", line)
            if found or not line:
                host = found.group(1) if found else None
                break
        if host is None:
            raise RuntimeError("franky-sim did not start")
        model = get_robot("franka_fr3")
        q = np.radians(np.array(FR3_PLAN))
        ids = [f"p{k + 1:03d}" for k in range(len(q))]
        clock = RealClock()
        robot = FrankaRobot(host, joint_names=model.joint_names, clock=clock, dynamics=0.6)
        camera = FollowingCamera(robot, model, seed=2)
        samples: list = []

        class Keep:
            def record(self, sample):
                samples.append(sample)

            def skip(self, pose_id, index, reasons):
                pass

        settings = CaptureSettings(joint_tolerance=0.3 * DEG)
        begin = time.perf_counter()
        try:
            summary = capture(
                ids, q, model, robot, camera, clock, camera.cell.truth.board, Keep(),
                intrinsics=camera.intrinsics(), settings=settings, progress=False,
            )  # fmt: skip
        finally:
            camera.close()
            robot.close()
        wall = time.perf_counter() - begin
    finally:
        server.terminate()
        try:
            server.wait(10)
        except subprocess.TimeoutExpired:
            server.kill()
    return {
        "wall": wall,
        "planned": len(q),
        "recorded": len(summary.recorded),
        "settle": float(np.median([s.settle_seconds for s in samples])) if samples else np.nan,
        "speed": float(np.median([s.returned_speed for s in samples])) if samples else np.nan,
        "render": camera.cell.render_seconds / max(len(camera.cell.frames), 1),
    }


def run() -> list[dict]:
    """The rows (see the module docstring)."""
    from relcal.robot.loading import get_robot

    model = get_robot("ur5e")
    q = _plan(model)
    loop = _loop(model, q)
    ours_ms, ours_px = _frames(model, q, "analytic")
    peer_ms, peer_px = _frames(model, q, "mujoco")
    n = max(loop["recorded"], 1)
    franky = _franky_sim()
    if franky is None:
        franky_row = {
            "task": "capture through franky-sim (FR3, libfranka protocol over loopback)",
            "value": None,
            "unit": "poses/min",
            "note": "skipped: franky and franky-sim not installed",
        }
    else:
        franky_row = {
            "task": f"capture through franky-sim (FR3, libfranka protocol over loopback), "
            f"{franky['planned']} poses ({franky['recorded']} recorded), --camera sim",
            "value": round(60.0 * franky["recorded"] / franky["wall"], 1),
            "unit": "poses/min",
            "note": f"wall time {franky['wall']:.1f} s; median {franky['settle']:.2f} s from "
            f"franky's move returning to the end of the still window, the arm at "
            f"{franky['speed']:.2f} rad/s when it returned; rendering "
            f"{1e3 * franky['render']:.0f} ms per frame",
        }
    return [
        {
            "task": f"capture in the virtual cell, UR5e, {len(q)} poses, 640x512 px "
            f"({loop['recorded']} recorded, {loop['attempts']} attempts, {loop['frames']} frames)",
            "value": round(60.0 * loop["recorded"] / loop["wall"], 1),
            "unit": "poses/min",
            "note": f"wall time {loop['wall']:.1f} s, CPU time {loop['cpu']:.1f} s "
            f"({60.0 * loop['recorded'] / loop['cpu']:.0f} poses/min of CPU); the simulated arm's "
            f"own time "
            f"{loop['simulated']:.0f} s = {60.0 * loop['recorded'] / loop['simulated']:.1f} "
            "poses/min (moves at 1 rad/s, settling, 0.5 s still window)",
        },
        {
            "task": "capture: rendering per recorded pose (MuJoCo scene + analytic board), wall",
            "value": round(1e3 * loop["render"] / n, 1),
            "unit": "ms",
            "note": f"{1e3 * loop['render'] / max(loop['frames'], 1):.0f} ms per frame",
        },
        {
            "task": "capture: detection and gates per recorded pose, wall",
            "value": round(1e3 * loop["detect"] / n, 1),
            "unit": "ms",
        },
        {
            "task": "virtual-cell frame, board pixels analytic (peer: MuJoCo's texture, 2x)",
            "value": round(ours_ms, 1),
            "unit": "ms",
            "peer": round(peer_ms, 1),
            "peer_name": "MuJoCo texture",
            "goal": "-",
            "met": None,
            "note": f"least CPU time per frame; median corner RMS vs the true projection: "
            f"{ours_px:.3f} px analytic, {peer_px:.3f} px MuJoCo texture",
        },
        franky_row,
    ]


if __name__ == "__main__":
    for row in run():
        extra = f" vs {row['peer']} ({row['peer_name']})" if "peer" in row else ""
        print(f"{row['task']}: {row['value']} {row['unit']}{extra}  {row.get('note', '')}")
