"""
Identifiability and Hayati's parameter
======================================

The A465's joints 2 and 3 are parallel. With standard DH only the sum ``d[2] + d[3]`` is
identifiable; Hayati's extra rotation ``beta[2]`` in place of ``d[2]`` cures it. The singular
values of the identification Jacobian (unit-norm columns) show it: one more direction is
determined with Hayati's parameter.
"""

import matplotlib.pyplot as plt
import numpy as np

import relcal
from relcal.robot.model import auto_hayati

fig, ax = plt.subplots(figsize=(7, 3.5), constrained_layout=True)
for label, model in (
    ("standard DH", relcal.get_robot("a465")),
    ("with Hayati's beta", auto_hayati(relcal.get_robot("a465"))),
):
    sim = relcal.simulate(model, formulation="invariant", measure="pose", n_poses=30, seed=1)
    ident = relcal.analyse_problem(sim.problem)
    s = ident.singular_values
    ax.semilogy(
        np.arange(1, len(s) + 1), np.maximum(s, 1e-17), "o-", label=f"{label}: rank {ident.rank}"
    )
    print(f"{label}: rank {ident.rank} of {len(s)}")
    for combination in ident.combinations:
        print("   ", combination.describe())
ax.axhline(1e-6 * s[0], color="grey", lw=0.8, ls="--", label="rank tolerance (1e-6 of the largest)")
ax.set_xlabel("singular value index")
ax.set_ylabel("singular value")
ax.legend(fontsize=8)
plt.show()
