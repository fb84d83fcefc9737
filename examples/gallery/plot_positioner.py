"""
A real calibration: the robot_cal_tools positioner
==================================================

205 real measurements of a two-axis positioner carrying a target in front of a fixed camera
(ROS-Industrial's robot_cal_tools data, in ``../shared/data``). The data are imported into a
dataset folder and calibrated; the numbers printed here are those of this build.
"""

import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import relcal
from relcal.data.importers import import_rct_positioner

# The data sit beside the checkout: ../shared from the repository, ../../../shared from here.
DATA = next(
    path / "data/rct_positioner/positioner_kinematic_measurements.yaml"
    for path in (Path("../shared"), Path("../../../shared"))
    if path.is_dir()
)
folder = Path(tempfile.mkdtemp()) / "positioner"
import_rct_positioner(DATA, folder)

dataset = relcal.load_dataset(folder)
cal = relcal.calibrate(dataset)
print(cal)
print(cal.validation.improvement())

# %%
# The model selection's candidates, scored by 5-fold cross-validation over the training samples:
for score in cal.selection:
    mark = "chosen" if score is cal.selection[cal.chosen] else ""
    print(
        f"{score.candidate.name:<30s} {len(score.candidate.columns):3d} parameters, "
        f"cross-validated position RMS {score.position_rms * 1e3:.3f} mm {mark}"
    )

# %%
# Held-out errors per pair: baseline (nominal kinematics, hand-eye fitted) against calibrated.
val = cal.validation
before = np.linalg.norm(val.before[:, :3], axis=1) * 1e3
after = np.linalg.norm(val.calibrated[:, :3], axis=1) * 1e3
order = np.argsort(before)
fig, ax = plt.subplots(figsize=(8, 3), constrained_layout=True)
ax.plot(before[order], ".", ms=2, label="baseline")
ax.plot(after[order], ".", ms=2, label="calibrated")
ax.set_xlabel("held-out pair (sorted by the baseline's error)")
ax.set_ylabel("relative position error (mm)")
ax.legend()
plt.show()
