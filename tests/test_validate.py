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


@pytest.mark.parametrize("chunk", [None, 7])
def test_bootstrap_sums_match_the_draws_one_by_one(monkeypatch, chunk):
    """The paired bootstrap's sums (several values per pair at once, the draws built once and
    reused for the same pairs, taken in chunks when large) against each draw's samples counted
    one by one, and ratio_interval against the percentile of those ratios."""
    from relcal.calibration import validate

    if chunk is not None:  # several chunks of draws (7 * P numbers each), and none kept
        monkeypatch.setattr(validate, "RESAMPLE_CHUNK", 7 * 45)
        monkeypatch.setattr(validate, "RESAMPLE_KEEP_BYTES", 100)
    monkeypatch.setattr(validate, "_LAST_RESAMPLER", ())
    rng = np.random.default_rng(3)
    pairs = make_pairs(10, "all") + 100  # sample numbers need not start at 0
    values = rng.uniform(0, 1, (len(pairs), 3))
    n_boot, seed = 50, 4
    resampled, drawn = validate._resampler(pairs, n_boot, seed)
    draws = np.random.default_rng(seed).integers(0, 10, (n_boot, 10))
    expected = np.zeros((n_boot, 3))
    for b, draw in enumerate(draws):
        counts = np.bincount(draw, minlength=10)
        expected[b] = (counts[pairs[:, 0] - 100] * counts[pairs[:, 1] - 100]) @ values
    np.testing.assert_allclose(resampled(values), expected, rtol=1e-12)
    np.testing.assert_allclose(resampled(values[:, 1]), expected[:, 1], rtol=1e-12)
    np.testing.assert_array_equal(drawn, expected[:, 0] > 0)
    again = validate._resampler(pairs.copy(), n_boot, seed)[0]
    # reused when its draw counts are small (n_boot x 10 bytes), rebuilt otherwise
    assert (again is resampled) == (chunk is None)
    np.testing.assert_array_equal(again(values), resampled(values))
    assert validate._resampler(pairs, n_boot, seed + 1)[0] is not resampled

    before = rng.normal(0, 1e-3, (len(pairs), 6))
    after = before * rng.uniform(0.2, 1.0, (len(pairs), 1))
    got = ratio_interval(pairs, before, after, n_boot=n_boot, seed=seed)["position_mm"]
    b2, a2 = (np.linalg.norm(e[:, :3] * 1e3, axis=1) ** 2 for e in (before, after))
    per_draw = []
    for draw in draws:
        counts = np.bincount(draw, minlength=10)
        w = counts[pairs[:, 0] - 100] * counts[pairs[:, 1] - 100]
        if w.sum() > 0:
            per_draw.append(np.sqrt((w @ a2) / (w @ b2)))
    np.testing.assert_allclose(got["ci95"], np.percentile(per_draw, [2.5, 97.5]), rtol=1e-12)
