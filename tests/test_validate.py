"""Held-out statistics: the summary numbers and the bootstrap interval of the RMS ratio."""

import numpy as np
import pytest

from relcal.calibration.measurement import make_pairs
from relcal.calibration.validate import Validation, ratio_interval, stats
from relcal.reporting.documents import validation_document


def test_stats_of_known_norms():
    errors = np.zeros((4, 6))
    errors[:, 0] = [1e-3, 2e-3, 3e-3, 4e-3]  # 1..4 mm
    errors[:, 5] = np.radians([1.0, 1.0, 1.0, 5.0])
    s = stats(errors)
    assert s["position_mm"]["median"] == pytest.approx(2.5)
    assert s["position_mm"]["rms"] == pytest.approx(np.sqrt(7.5))
    assert s["orientation_deg"]["max"] == pytest.approx(5.0)


def test_uniform_improvement_has_a_degenerate_interval():
    rng = np.random.default_rng(0)
    pairs = make_pairs(10, "all")
    before = rng.normal(0, 1e-3, (len(pairs), 6))
    r = ratio_interval(pairs, before, 0.25 * before)
    for key in ("position_mm", "orientation_deg"):
        assert r[key]["after_over_before"] == pytest.approx(0.25)
        np.testing.assert_allclose(r[key]["ci95"], [0.25, 0.25])


def test_interval_reflects_how_many_samples_there_are():
    """One bad sample spoils every pair it is in: the interval, drawn over samples, must say that
    the evidence is thin, and it narrows as the held-out set grows."""
    rng = np.random.default_rng(1)
    widths = []
    for n in (8, 32):
        pairs = make_pairs(n, "all")
        quality = rng.uniform(0.3, 1.5, n)  # per-sample effect of the calibration
        before = rng.normal(0, 1e-3, (len(pairs), 6))
        after = before * np.sqrt(quality[pairs[:, 0]] * quality[pairs[:, 1]])[:, None]
        val = Validation(pairs, before, after)
        r = validation_document(val)["ratio_to_baseline"]["position_mm"]
        lo, hi = r["ci95"]
        assert lo < r["after_over_before"] < hi
        widths.append(hi - lo)
    assert widths[1] < 0.7 * widths[0]
