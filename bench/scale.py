"""Calibration time and peak memory against the number of samples (issue 20, "scale without a
cliff").

Synthetic A465 sets of 1000, 3000 and 10,000 samples (Hayati's beta, planted geometric errors of
0.1..0.9 mm and 0.01..0.9 deg, pose noise 0.05 mm / 0.01 deg, 0.5 % of the samples off by 5 mm
and 1 deg, no hand-eye guess given) are calibrated by ``relcal calibrate DATASET --quiet`` with the
default pairing (``auto``: the board formulation above 300 usable samples), each in a fresh
process: its CPU time (user + system, one BLAS thread) and its peak resident memory (the
child's high-water mark ``VmHWM``) are measured, the time is compared with
the 1000-sample row scaled linearly and the memory with the 1000-sample row's. Goals: within
1.5x of linear time, and peak memory below the 2 GB limit of ``RELCAL_MAX_MEMORY_MB`` (all pairs
of 10,000 samples would be 50 million).

``python bench/scale.py`` prints the rows alone; ``bench/run.py`` (``make bench``) puts them in
its table.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from relcal import geometry as tf
from relcal.data.dataset import write_samples
from relcal.robot.kinematics import apply_errors, fk, make_layout
from relcal.robot.loading import get_robot
from relcal.robot.model import auto_hayati

SIZES = (1000, 3000, 10_000)
LINEAR_GOAL = 1.5  # time per sample at most this many times the 1000-sample row's
MEMORY_GOAL_MB = 2048.0


def write_dataset(root: Path, n: int, seed: int = 0) -> Path:
    """A synthetic dataset of ``n`` samples (camera poses given) in ``root``."""
    rng = np.random.default_rng(seed)
    model = auto_hayati(get_robot("a465"))
    layout = make_layout(model)
    angle = layout.is_angle()
    size = np.where(angle, np.radians(rng.uniform(0.01, 0.9, layout.size)), 0.0)
    size = np.where(angle, size, rng.uniform(0.1, 0.9, layout.size) * 1e-3)
    true_model = apply_errors(model, layout, size * rng.choice([-1.0, 1.0], layout.size))
    lo = np.where(np.isfinite(model.lower), model.lower, -np.pi)
    hi = np.where(np.isfinite(model.upper), model.upper, np.pi)
    q = rng.uniform(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), (n, model.n_joints))
    handeye = tf.from_vector(np.array([0.0, 0.04, 0.06, 0.01, -0.02, 0.0]))
    board = tf.from_vector(np.array([0.5, 0.1, -0.2, 3.0, 0.1, 0.4]))
    noise = np.c_[rng.normal(0, 5e-5, (n, 3)), rng.normal(0, np.radians(0.01), (n, 3))]
    bad = rng.choice(n, n // 200, replace=False)
    direction = rng.normal(size=(len(bad), 6))
    noise[bad, :3] += 5e-3 * direction[:, :3] / np.linalg.norm(direction[:, :3], axis=1)[:, None]
    noise[bad, 3:] += (
        np.radians(1.0) * direction[:, 3:] / np.linalg.norm(direction[:, 3:], axis=1)[:, None]
    )
    poses = board @ fk(true_model, q) @ handeye @ tf.from_vector(noise)
    root.mkdir(parents=True, exist_ok=True)
    # no hand-eye guess: relcal guesses it from the data (on at most the pairs of 300 samples)
    (root / "dataset.yaml").write_text("robot: a465\nhayati: auto\njoint_unit: deg\n")
    ids = [f"s{k:05d}" for k in range(n)]
    (root / "samples.csv").write_text(
        write_samples(root / "samples.csv", ids, np.degrees(q), poses=poses)
    )
    return root


def calibrate_in_child(dataset: Path, out: Path) -> dict:
    """``relcal calibrate`` in a fresh process: CPU seconds, wall seconds, peak RSS (MB), exit
    code. The peak is the child's own ``VmHWM`` (read by the child as it ends): the kernel's
    ``ru_maxrss`` of a child also counts the copy of the parent it was forked from (the whole
    bench's memory under ``bench/run.py``)."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    with tempfile.TemporaryDirectory() as tmp:
        peak_file = Path(tmp) / "vmhwm"
        code = (
            "import sys\n"
            "from relcal.cli import main\n"
            "try:\n"
            "    rc = main(sys.argv[2:])\n"
            "finally:\n"
            "    hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM')]\n"
            "    open(sys.argv[1], 'w').write(hwm[0].split()[1] if hwm else '')\n"
            "sys.exit(rc)\n"
        )
        argv = [sys.executable, "-c", code, str(peak_file), "calibrate", str(dataset)]
        argv += ["--out", str(out), "--quiet"]
        started = time.perf_counter()
        child = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        _, status, usage = os.wait4(child.pid, 0)
        wall = time.perf_counter() - started
        child.returncode = os.waitstatus_to_exitcode(status)
        err = child.stderr.read().decode(errors="replace") if child.stderr else ""
        text = peak_file.read_text().strip() if peak_file.exists() else ""
    return {
        "cpu": usage.ru_utime + usage.ru_stime,
        "wall": wall,
        "peak_mb": int(text) / 1024 if text else float("nan"),  # kB in /proc
        "rc": child.returncode,
        "err": err.strip()[-300:],
    }


def run(sizes: tuple[int, ...] = SIZES) -> list[dict]:
    rows, first = [], None
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            root = write_dataset(Path(tmp) / f"d{n}", n)
            got = calibrate_in_child(root, Path(tmp) / f"o{n}")
            task = f"relcal calibrate, {n:,} samples (--pairs auto: board), A465"
            if got["rc"] != 0:
                rows.append({"task": task, "note": f"failed ({got['rc']}): {got['err']}"})
                continue
            first = first or (n, got["cpu"], got["peak_mb"])
            linear = first[1] * n / first[0]  # the first row's time, scaled to n samples
            rows.append(
                {
                    "task": task,
                    "value": got["cpu"],
                    "unit": "s",
                    "peer": linear,
                    "peer_name": f"{first[0]:,}-sample row x {n / first[0]:g} (linear)",
                    "ratio": linear / got["cpu"],
                    "goal": f"within {LINEAR_GOAL:g}x of linear",
                    "goal_ratio": 1 / LINEAR_GOAL,
                    "note": f"time {got['cpu'] / first[1]:.2f}x the {first[0]:,}-sample row; "
                    f"wall {got['wall']:.1f} s",
                }
            )
            rows.append(
                {
                    "task": f"peak memory of that calibration ({n:,} samples)",
                    "value": got["peak_mb"],
                    "unit": "MB",
                    "peer": first[2],
                    "peer_name": f"{first[0]:,}-sample row (ratio: x its memory)",
                    "goal": f"< {MEMORY_GOAL_MB:g} MB",
                    "met": got["peak_mb"] < MEMORY_GOAL_MB,
                    "note": "VmHWM of the child process, read by it as it ends",
                }
            )
    return rows


if __name__ == "__main__":
    for row in run():
        print(row)
