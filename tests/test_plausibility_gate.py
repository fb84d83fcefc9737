"""The one plausibility gate before a model is written (issue 20): every kind, every entry point."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from helpers_dataset import synthetic_dataset

from relcal.calibration.pipeline import calibrate
from relcal.calibration.plausibility import (
    STD_REFUSE,
    check_calibration,
    frame_shifts,
    joint_limit_warnings,
    nongeometric_problems,
    std_consistency,
)
from relcal.data.dataset import load_dataset
from relcal.data.imaging import measure
from relcal.errors import RelcalError
from relcal.robot.kinematics import make_layout
from relcal.robot.loading import get_robot


def test_nongeometric_terms_beyond_their_bounds_are_named():
    names = ("scale[1]", "scale[2]", "compliance[3]", "harmonic_c[4]", "a[1]")
    kinds = ("scale", "scale", "compliance", "harmonic_c", "a")
    units = ("1", "1", "rad/(N m)", "rad", "m")
    ok = np.array([0.01, -0.049, np.radians(4.9), np.radians(1.9), 1.0])
    assert nongeometric_problems(names, kinds, units, ok) == []
    bad = np.array([0.06, 0.0, np.radians(6.0), np.radians(-2.5), 0.0])
    lines = nongeometric_problems(names, kinds, units, bad)
    assert [line.split(" ")[0] for line in lines] == ["scale[1]", "compliance[3]", "harmonic_c[4]"]
    assert "+6e+04 ppm" in lines[0]
    # a prismatic joint's compliance is a length per force
    assert nongeometric_problems(("compliance[1]",), ("compliance",), ("m/N",), [2e-4])
    assert not nongeometric_problems(("compliance[1]",), ("compliance",), ("m/N",), [5e-5])


def test_frames_moved_from_the_baseline_are_warned_of():
    names = [f"handeye.{c}" for c in ("tx", "ty", "tz", "rx", "ry", "rz")]
    kinds = ["handeye"] * 6
    base = np.zeros(6)
    assert frame_shifts(names, kinds, np.r_[0.03, 0, 0, 0, 0, 0.01], base) == []
    (line,) = frame_shifts(names, kinds, np.r_[0.04, 0.04, 0, 0, 0, 0], base)
    assert "hand-eye transform" in line and "56.6 mm" in line
    (line,) = frame_shifts(names, kinds, np.r_[0, 0, 0, 0, 0, np.radians(6)], base)
    assert "6 deg" in line


def test_zero_offsets_that_put_samples_beyond_the_joint_limits_are_warned_of():
    model = get_robot("a465")
    layout = make_layout(model)
    q = np.zeros((3, 6))
    q[0, 1] = model.upper[1] - np.radians(1)
    params = np.zeros(layout.size)
    params[layout.names.index("theta_off[2]")] = np.radians(3)
    assert joint_limit_warnings(model, layout, params, q) == []  # 2 deg beyond: tolerated
    params[layout.names.index("theta_off[2]")] = np.radians(8)
    (line,) = joint_limit_warnings(model, layout, params, q)
    assert line.startswith("theta_off[2] +8 deg puts shoulder 7 deg beyond its limits")


def test_predicted_and_bootstrap_std_disagreeing_warn_then_refuse():
    names = ("a", "b", "c", "d")
    predicted = np.array([1.0, 1.0, 1.0, np.nan])
    warn, refuse = std_consistency(names, predicted, np.array([1.5, 0.2, 4.0, 1.0]))
    assert refuse is None and len(warn) == 2
    assert "below the bootstrap's (intervals too narrow): c 1 vs 4 SI" in warn[0]
    assert "above the bootstrap's (intervals conservative): b 1 vs 0.2 SI" in warn[1]
    # conservative intervals are never refused; overconfident ones for the median parameter are
    wide = predicted * (STD_REFUSE + 1)
    assert std_consistency(names, wide, np.ones(4))[1] is None
    narrow = predicted / (STD_REFUSE + 1)
    warn, refuse = std_consistency(names, narrow, np.ones(4))
    assert "a, b, c" not in warn[0] and "noise model does not describe these data" in refuse


def test_the_pipeline_passes_the_gate_and_it_refuses_a_planted_term(tmp_path):
    """A calibration of a synthetic set passes the gate; the same result with a planted joint
    scale of 8 % (the kind of number a wrong unit or a weak direction gives) is refused."""
    syn = synthetic_dataset(tmp_path / "d", n=40, seed=5, nongeometric=("scale",))
    dataset = load_dataset(syn.root)
    cal = calibrate(dataset, measure(dataset, progress=False), selection="all")
    assert isinstance(cal.warnings, tuple)
    layout = cal.problem.full_layout
    k = layout.kinds.index("scale")
    params = cal.result.params.copy()
    params[k] = 0.08
    planted = r"(?s)non-geometric terms too large.*scale\[1\] = \+8e\+04 ppm"
    with pytest.raises(RelcalError, match=planted):
        check_calibration(cal.dataset, cal.problem, replace(cal.result, params=params))
