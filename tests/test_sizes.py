"""Coincidence data are bounded like every other kind: their size, memory and time are estimated
from the samples and groups before any work (the group points are unknowns of one dense fit),
and data beyond the limits are refused with the estimate and the remedy, which works; the
placements' design effect is linear in the placements (an exact identity, checked against the
pair-by-pair sum)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from relcal.calibration.uncertainty import _square_pairwise, design_effect
from relcal.data.dataset import load_dataset
from relcal.errors import RelcalError
from relcal.limits import coincidence_cost
from relcal.outputset import tracking


def coincidence_folder(root, n_groups: int, per_group: int, seed: int = 0):
    """A coincidence dataset of the UR5e: ``n_groups`` groups (two sockets per placement, each
    pair 50 mm apart) of ``per_group`` random configurations."""
    rng = np.random.default_rng(seed)
    root.mkdir(parents=True)
    rows = ["id,group," + ",".join(f"q{i}" for i in range(1, 7))]
    k = 0
    for g in range(n_groups):
        group = f"p{g // 2}/hole_{g % 2}"
        for _ in range(per_group):
            q = rng.uniform(-2.5, 2.5, 6)
            rows.append(f"{k},{group}," + ",".join(f"{v:.9f}" for v in q))
            k += 1
    distances = "".join(
        f"  - {{groups: [p{p}/hole_0, p{p}/hole_1], distance: 0.05}}\n"
        for p in range(n_groups // 2)
    )
    (root / "samples.csv").write_text("\n".join(rows) + "\n")
    (root / "dataset.yaml").write_text(
        "robot: ur5e\nmeasurement: coincidence\njoint_unit: rad\nsamples: samples.csv\n"
        f"distances:\n{distances}"
    )
    return root


@pytest.mark.parametrize(
    ("n_groups", "per_group", "limit"),
    [(500, 2, "minutes"), (900, 6, "memory"), (3000, 6, "memory")],  # 5,400 and 18,000 samples
)
def test_large_coincidence_data_are_refused_before_any_work(tmp_path, n_groups, per_group, limit):
    folder = coincidence_folder(tmp_path / "big", n_groups, per_group)
    started = time.perf_counter()
    with tracking(), pytest.raises(RelcalError) as info:
        load_dataset(folder)
    assert time.perf_counter() - started < 20  # refused from the counts, nothing fitted
    message = str(info.value)
    n = n_groups * per_group
    assert f"{n:,} coincidence samples in {n_groups:,} groups" in message, message
    assert "calibrate fewer placements at a time" in message
    if limit == "memory":
        assert "of memory, above the limit" in message and "RELCAL_MAX_MEMORY_MB" in message
    else:
        assert "minutes (RELCAL_MAX_MINUTES)" in message, message


def test_the_suggestion_fewer_placements_loads(tmp_path):
    folder = coincidence_folder(tmp_path / "part", 40, 6)  # 20 placements of the 450 above
    with tracking():
        data = load_dataset(folder)
    assert len(data.ids) == 240 and len(set(data.groups)) == 40


def test_the_estimate_follows_the_measured_runs():
    """The estimate reproduces the runs it was fitted to (within 30 %), and grows with the
    groups as the dense fit does."""
    measured = [((360, 60), 8.0, 179), ((720, 120), 24.0, 240), ((1440, 120), 34.0, 251)]
    for (n, g), seconds, megabytes in measured:
        need, estimate = coincidence_cost(n, g, g // 2, 24 + 18)
        assert abs(estimate - seconds) / seconds < 0.3, (n, g, estimate)
        assert need / 2**20 >= 0.7 * megabytes, (n, g, need / 2**20)
    assert coincidence_cost(5400, 900, 450, 42)[1] > 100 * coincidence_cost(5400, 90, 45, 42)[1]


def test_the_design_effects_linear_sum_is_the_pairwise_one():
    rng = np.random.default_rng(4)
    for k, clusters in ((3, 2), (6, 5), (9, 12)):
        hh = [rng.normal(size=(k, k)) for _ in range(clusters)]
        squares = [x @ x for x in hh]
        total = sum(squares, np.zeros((k, k)))
        pairs = zip(hh, squares, strict=True)
        linear = sum(float(np.trace(x2) - 2 * np.sum(x2 * x.T)) for x, x2 in pairs)
        linear += float(np.sum(total * total.T))
        assert linear == pytest.approx(_square_pairwise(hh), rel=1e-12)


def test_the_design_effect_is_linear_in_the_clusters():
    """The same answer as the pair-by-pair formula on a small problem, and 200 clusters of a
    60-column Jacobian in well under a second (pairwise: 40,000 products of 60 x 60)."""
    rng = np.random.default_rng(5)

    def problem(clusters: int, per: int, k: int):
        jac = rng.normal(size=(clusters * per, k))
        r = rng.normal(size=clusters * per)
        r -= jac @ np.linalg.lstsq(jac, r, rcond=None)[0]  # at a least-squares estimate
        return jac, r, np.repeat(np.arange(clusters), per)

    jac, r, labels = problem(6, 8, 5)
    effect, dof, s2 = design_effect(jac, r, labels)
    unit = jac / np.linalg.norm(jac, axis=0)
    h_inv = np.linalg.pinv(unit.T @ unit)
    hh = [h_inv @ (unit[labels == c].T @ unit[labels == c]) for c in range(6)]
    mean = sum(float(np.trace(x) - np.trace(x @ x)) for x in hh)
    assert dof == pytest.approx(mean**2 / _square_pairwise(hh), rel=1e-10)
    jac, r, labels = problem(200, 6, 60)
    started = time.perf_counter()
    design_effect(jac, r, labels)
    assert time.perf_counter() - started < 5
