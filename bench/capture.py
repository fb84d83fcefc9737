"""Capture rows of ``make bench``: ``relcal capture`` in the virtual cell (MuJoCo on the CPU).

- the whole loop on a UR5e plan of 30 poses (640 x 512 px camera, normal camera, no faults):
  poses per minute of wall time (rendering, detection, dataset writes), and per minute of the
  simulated arm's time (moves at 1 rad/s, settling, the still window: what a real arm with the
  cell's dynamics would manage);
- per pose: the rendering time (MuJoCo scene with the board's pixels from relcal's analytic
  renderer) and the detection and gating time;
- per frame: the rendering time with the board's pixels from the analytic renderer against
  MuJoCo's own texture (supersampled twice), with the corner accuracy of each (RMS distance of
  the detected corners from the true projections, px), which is why the cell composes the two.

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


def run() -> list[dict]:
    """The rows (see the module docstring)."""
    from relcal.robot.loading import get_robot

    model = get_robot("ur5e")
    q = _plan(model)
    loop = _loop(model, q)
    ours_ms, ours_px = _frames(model, q, "analytic")
    peer_ms, peer_px = _frames(model, q, "mujoco")
    n = max(loop["recorded"], 1)
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
    ]


if __name__ == "__main__":
    for row in run():
        extra = f" vs {row['peer']} ({row['peer_name']})" if "peer" in row else ""
        print(f"{row['task']}: {row['value']} {row['unit']}{extra}  {row.get('note', '')}")
