"""
Calibrate from NumPy arrays
===========================

Joint values and measured camera poses already in memory (from your own capture code, a
notebook, a ROS node) go into :meth:`relcal.Dataset.from_arrays`, and :func:`relcal.calibrate`
does the rest: outliers, noise model, model selection, the fit and the validation on held-out
samples. Here the arrays come from a simulated A465 with known errors and 0.05 mm / 0.01 degree
camera noise.
"""

import matplotlib.pyplot as plt
import numpy as np

import relcal
from relcal import geometry as tf

rng = np.random.default_rng(0)
model = relcal.get_robot("a465")
layout = relcal.make_layout(model)
truth = relcal.apply_errors(model, layout, rng.uniform(-1, 1, layout.size) * 5e-4)

# 40 configurations, a camera 6 cm off the flange, a board somewhere in the cell:
q = np.radians(rng.uniform([-60, 10, 20, -90, -60, -90], [60, 50, 70, 90, 60, 90], (40, 6)))
handeye = tf.from_xyz_rpy([0.0, 0.04, 0.06], [0.0, 0.0, 0.0])
board = tf.from_xyz_rpy([0.9, 0.1, -0.3], [0.2, -0.1, 0.3])  # unknown to relcal, never needed
noise = np.c_[rng.normal(0, 5e-5, (40, 3)), rng.normal(0, np.radians(0.01), (40, 3))]
poses = board @ relcal.fk(truth, q) @ handeye @ tf.from_vector(noise)  # camera in board frame

# %%
# One call builds the dataset (checked: shapes, units, rigid transforms), one calibrates:
dataset = relcal.Dataset.from_arrays(model, q, poses, mode="eye_in_hand", handeye=handeye)
cal = relcal.calibrate(dataset, seed=0)
print(dataset)
print(cal)

# %%
# Held-out relative position error per pair, baseline (nominal kinematics, hand-eye fitted)
# against the calibrated model:
val = cal.validation
before = np.linalg.norm(val.before[:, :3], axis=1) * 1e3
after = np.linalg.norm(val.calibrated[:, :3], axis=1) * 1e3
fig, ax = plt.subplots(figsize=(7, 3), constrained_layout=True)
bins = np.geomspace(min(after.min(), before.min()), max(after.max(), before.max()), 30)
ax.hist(before, bins, alpha=0.6, label=f"baseline, RMS {np.sqrt(np.mean(before**2)):.3f} mm")
ax.hist(after, bins, alpha=0.6, label=f"calibrated, RMS {np.sqrt(np.mean(after**2)):.3f} mm")
ax.set_xscale("log")
ax.set_xlabel("held-out relative position error per pair (mm)")
ax.legend()
plt.show()
