"""
The published simulation
========================

A Thermo CRS A465 with random geometric errors (0.1 to 0.9 mm and 0.01 to 0.9 degrees) is
measured at 60 camera poses in front of a board; relative position and orientation of
consecutive pairs identify the errors. Parameters the relative data cannot determine are left at
nominal and named with the reason.
"""

import matplotlib.pyplot as plt
import numpy as np

import relcal

model = relcal.get_robot("a465")
sim = relcal.simulate(model, measure="pose", formulation="published", seed=0)
result = sim.result
print(result)

# %%
# Specified against identified error of every identifiable parameter (lengths in mm, angles in
# degrees). The others are combinations the data cannot separate:

names = np.array(sim.layout.names)
shown = result.identifiable
angle = sim.layout.is_angle()
scale = np.where(angle, np.degrees(1.0), 1e3)
fig, axes = plt.subplots(1, 2, figsize=(9, 3.2), constrained_layout=True)
for ax, is_angle, unit in ((axes[0], False, "mm"), (axes[1], True, "deg")):
    k = np.flatnonzero(shown & (angle == is_angle))
    x = np.arange(len(k))
    ax.bar(x - 0.2, sim.specified[k] * scale[k], 0.4, label="specified")
    ax.bar(x + 0.2, result.params[k] * scale[k], 0.4, label="identified")
    ax.set_xticks(x, names[k], rotation=90, fontsize=8)
    ax.set_ylabel(unit)
axes[0].legend()
plt.show()

for text in result.unidentifiable:
    print("not identifiable:", text)

# %%
# Without noise the identified errors equal the specified ones to round-off:
k = np.flatnonzero(shown)
print(f"largest |identified - specified|: {np.abs(result.params[k] - sim.specified[k]).max():.2e}")
