"""The recovery tables of the README's "Non-geometric error models" section.

Runs the scenario of ``tests/test_nongeometric.py`` (A465 and FR3, all three terms on every joint,
planted or not) with one seed and prints the planted/identified/std rows and the held-out errors:
``.venv/bin/python docs/nongeometric_recovery.py``.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import test_nongeometric as scenario  # noqa: E402

from relcal.calibration.identify import identify  # noqa: E402
from relcal.calibration.measurement import residuals  # noqa: E402
from relcal.calibration.uncertainty import parameter_covariance  # noqa: E402
from relcal.robot.kinematics import apply_errors, gravity_torques, make_layout  # noqa: E402
from relcal.robot.loading import get_robot  # noqa: E402
from relcal.robot.model import auto_hayati  # noqa: E402

SEED = 12345


def held_out(problem, params) -> str:
    """RMS over pairs of the position (mm) and rotation (deg) residual norms."""
    r = residuals(problem, params, jacobian=False).reshape(-1, 6)
    position = np.sqrt(np.mean(np.sum(r[:, :3] ** 2, axis=1))) * 1e3
    rotation = np.degrees(np.sqrt(np.mean(np.sum(r[:, 3:] ** 2, axis=1))))
    return f"{position:.4f} mm / {rotation:.5f} deg"


def main() -> None:
    for name in ("a465", "franka_fr3"):
        for planted in (True, False):
            rng = np.random.default_rng(SEED)
            model, layout, train, held, truth = scenario._scenario(name, rng, planted)
            result = identify(train)
            ident = result.identifiability
            unc = parameter_covariance(train, scenario.NOISE, identifiability=ident)
            names = train.full_layout.names
            factor, unit = train.full_layout.display()
            what = "planted" if planted else "nothing planted"
            print(f"{name}, {what}: rank {result.identifiability.rank} of {len(names)}")
            if planted:
                tau = gravity_torques(model, train.q)
                bent = apply_errors(model, layout, truth[: layout.size]).compliance * tau
                bent_deg = np.degrees(np.abs(bent).max(axis=0)).round(4)
                print("  max |compliance tau| (deg):", bent_deg)
                print("  max |tau| (N m):", np.abs(tau).max(axis=0).round(1))
                for key, value in scenario.PLANTED[name].items():
                    k = names.index(key)
                    z = (result.params[k] - value) / unc.std[k]
                    print(
                        f"  | {key} | {unit[k]} | {value * factor[k]:.4g} | "
                        f"{result.params[k] * factor[k]:.4g} | {unc.std[k] * factor[k]:.2g} | "
                        f"{z:+.2f} |"
                    )
            nongeo = np.flatnonzero(~train.full_layout.is_geometric() & result.identifiable)
            z = (result.params[nongeo] - truth[nongeo]) / unc.std[nongeo]
            print(
                f"  non-geometric: {len(nongeo)} identifiable, max |z| {np.abs(z).max():.2f}, "
                f"mean z^2 {np.mean(z**2):.2f}"
            )
            nominal = auto_hayati(get_robot(name))
            geometric = replace(train, model=nominal, layout=make_layout(nominal))
            fit = identify(geometric)
            geo_held = replace(held, model=nominal, layout=geometric.layout)
            print(
                f"  held-out: floor {held_out(held, truth)} | with the terms "
                f"{held_out(held, result.params)} | geometric only {held_out(geo_held, fit.params)}"
            )


if __name__ == "__main__":
    main()
