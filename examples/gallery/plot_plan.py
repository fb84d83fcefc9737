"""
Plan the poses before the robot moves
=====================================

:func:`relcal.plan` chooses joint configurations that keep the board in view, respect the joint
limits and make the weakest parameter as well determined as possible, and compares the plan with
random feasible sets of the same size. A small pool (600 candidates, 12 poses) keeps this
example quick; the command line's default is 2000 candidates and 30 poses.
"""

import matplotlib.pyplot as plt
import numpy as np

import relcal
from relcal.robot.model import auto_hayati

model = auto_hayati(relcal.get_robot("a465"))
result = relcal.plan(model, relcal.Cell(), n_poses=12, n_candidates=600, random_sets=10, seed=0)
print(
    f"{len(result.q)} poses from {result.n_candidates} feasible candidates "
    f"in {result.seconds:.1f} s"
)
print(
    f"worst-parameter std: plan {result.plan.worst[1] * 1e3:.4f} mm-equivalent, median random "
    f"set {result.random_median_worst * 1e3:.4f} ({result.improvement:.2f}x lower)"
)

# %%
# The planned joint configurations (degrees), in travel order:
fig, ax = plt.subplots(figsize=(8, 3), constrained_layout=True)
ax.plot(np.degrees(result.q), "o-")
ax.set_xlabel("pose")
ax.set_ylabel("joint angle (deg)")
ax.legend([f"q{i + 1}" for i in range(model.n_joints)], ncol=6, fontsize=8)
plt.show()
