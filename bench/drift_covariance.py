"""Which covariance should the registry's drift test use? Not a speed row: the statistics behind
the README's registry and drift numbers (``python bench/drift_covariance.py [PAIRS] [PLANTED]``,
default 200 and 20; a few minutes).

Synthetic sessions as in ``tests/test_drift.py`` (30 poses, 0.05 mm / 0.0057 deg pose noise per
axis, A465 and UR5e alternating, new poses and noise per session): two sessions of each of
``PAIRS`` robots (noise only) and, for the first ``PLANTED`` robots, a third session with ``a[2]``
0.3 mm longer. Each session is calibrated once; two covariances of its estimated subset:

- ``registry``: what the registry stores (:func:`relcal.fleet.records.covariance`, the
  calibration's own: the learned 6x6 pose noise propagated through the pairs), the std that
  ``results.json`` prints;
- ``isotropic``: the same propagation with the pose noise at the robust (MAD) isotropic level of
  the pair residuals, what the registry stored before the noise learning counted what the fit
  absorbs of each component.

Printed per covariance: the std ratio to ``registry``, the z of identified minus true errors
(identifiable link parameters), false drift flags on the noise-only pairs (``drift.compare``, F
test as shipped, and with the noise level taken as known), the spread of their p-values, and the
planted change's detection.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import sys  # noqa: E402
import tempfile  # noqa: E402
from copy import deepcopy  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import numpy as np  # noqa: E402
import scipy.stats  # noqa: E402
from helpers_fleet import make_robot, write_session  # noqa: E402

from relcal.calibration.identify import result_covariance  # noqa: E402
from relcal.calibration.pipeline import calibrate  # noqa: E402
from relcal.data.dataset import load_dataset  # noqa: E402
from relcal.data.imaging import measure  # noqa: E402
from relcal.fleet.drift import compare  # noqa: E402
from relcal.fleet.records import calibration_record  # noqa: E402
from relcal.fleet.registry import run_from_record  # noqa: E402
from relcal.reporting.documents import results_document  # noqa: E402
from relcal.robot.kinematics import make_layout  # noqa: E402
from relcal.robot.loading import get_robot  # noqa: E402
from relcal.robot.model import auto_hayati  # noqa: E402

KINDS = ("registry", "isotropic")


def session(root: Path, robot, seed: int, change=None) -> dict:
    """One calibration: its registry record under each covariance, and the learned noise."""
    dataset = load_dataset(write_session(root, robot, seed, change=change))
    cal = calibrate(dataset, measure(dataset, progress=False))
    record = calibration_record(cal, results_document(cal))
    columns = np.flatnonzero(np.isfinite(cal.std))
    res = cal.result
    ident = replace(res.identifiability, subset=columns)
    isotropic = result_covariance(cal.problem, res.params, ident)  # no noise model handed in
    other = deepcopy(record)
    cov = isotropic[np.ix_(columns, columns)]
    other["covariance"]["matrix"] = cov.tolist()
    std = dict(zip(other["covariance"]["names"], np.sqrt(np.diag(cov)), strict=True))
    for p in other["parameters"]:
        p["std"] = float(std[p["name"]]) if p["name"] in std else None
    return {"registry": record, "isotropic": other, "noise": cal.noise.std}


def known_noise(record: dict):
    """The run with the noise level taken as known (chi-square and normal z)."""
    record = deepcopy(record)
    record["covariance"]["residual_dof"] = None
    return run_from_record(record)


def main(n_pairs: int = 200, n_planted: int = 20) -> None:
    tmp = Path(tempfile.mkdtemp())
    pairs, planted, truths = [], [], []
    for s in range(n_pairs):
        model = ("a465", "ur5e")[s % 2]
        robot = make_robot(model, f"r{s}", 500 + s)
        names = make_layout(auto_hayati(get_robot(model))).names
        truths.append(dict(zip(names, robot.truth, strict=True)))
        first = session(tmp / f"{s}-1", robot, 10_000 + s)
        pairs.append((first, session(tmp / f"{s}-2", robot, 20_000 + s)))
        if s < n_planted:
            planted.append((first, session(tmp / f"{s}-3", robot, 30_000 + s, {"a[2]": 3e-4})))
    noise = np.mean([x["noise"] for p in pairs for x in p], axis=0)
    print(f"{2 * n_pairs} noise-only sessions, {n_planted} with a[2] + 0.3 mm")
    print("mean learned pose noise std (m, rad; truth 5e-05, 1e-04):")
    print("  " + " ".join(f"{x:.2e}" for x in noise))
    for kind in KINDS:
        ratio, z_truth = [], []
        for (a, b), truth in zip(pairs, truths, strict=True):
            for x in (a, b):
                mine = np.diag(np.asarray(x[kind]["covariance"]["matrix"]))
                ratio.append(
                    np.sqrt(mine / np.diag(np.asarray(x["registry"]["covariance"]["matrix"])))
                )
                for p in x[kind]["parameters"]:
                    n = p["name"]
                    if p["estimated"] and p["identifiable"] and n in truth:
                        if not n.startswith("handeye."):
                            z_truth.append((p["value"] - truth[n]) / p["std"])
        ratio = np.concatenate(ratio)
        shipped = [compare(run_from_record(a[kind]), run_from_record(b[kind])) for a, b in pairs]
        known = [compare(known_noise(a[kind]), known_noise(b[kind])) for a, b in pairs]
        found = [compare(run_from_record(a[kind]), run_from_record(b[kind])) for a, b in planted]
        p = np.array([c.p_value for c in shipped])
        z = np.concatenate([[q.z for q in c.parameters] for c in shipped])
        za2 = [next(q.z for q in c.parameters if q.name == "a[2]") for c in found]
        one_sided = sum(bool(c.one_sided) for c in shipped)
        print(f"\n{kind}:")
        print(
            f"  std / registry std: median {np.median(ratio):.3f}, 5-95 % "
            f"{np.percentile(ratio, 5):.3f} to {np.percentile(ratio, 95):.3f}"
        )
        print(f"  (identified - true) / std: sd {np.std(z_truth):.3f} over {len(z_truth)}")
        by_f = sum(c.p_value < c.alpha for c in shipped)
        by_z = sum(bool(c.flagged) for c in shipped)
        print(
            f"  noise-only pairs flagged: {sum(c.drift for c in shipped)} of {len(pairs)} "
            f"(F test {by_f}, z {by_z}); noise level taken as known: {sum(c.drift for c in known)}"
        )
        ks = scipy.stats.kstest(p, "uniform").pvalue
        print(
            f"  p-values median {np.median(p):.2f}, Kolmogorov-Smirnov p {ks:.1g}; "
            f"sd of z {np.std(z):.3f}; pairs with different chosen models {one_sided}"
        )
        print(
            f"  planted: flagged {sum(c.drift for c in found)} of {len(found)}, on a[2] "
            f"{sum('a[2]' in c.flagged for c in found)}, median z {np.median(za2):.1f}, "
            f"largest p {max(c.p_value for c in found):.1g}"
        )


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:3]))
