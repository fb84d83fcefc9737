"""The verdict on a calibration: deploy it or not, from the held-out evidence alone.

The verdict reads the 95 % interval of the held-out RMS ratio (calibrated over baseline, from the
bootstrap over held-out samples of :func:`relcal.calibration.validate.ratio_interval`) and the
number of held-out samples:

- ``deploy``: the whole interval lies below 1 (better than the baseline beyond sampling doubt);
- ``collect more samples``: the interval spans 1 (the held-out samples cannot tell), or fewer
  than :data:`MIN_JUDGED` held-out samples leave no interval worth reading (a bootstrap over
  two samples, one pair of poses, has none);
- ``do not deploy``: the whole interval lies above 1, or the exported model is the baseline
  (the data support no kinematic correction, or the calibrated model is worse than the
  baseline on the held-out samples: a worse model is never exported);
- ``not validated``: no held-out samples (``--holdout 0``).

The evidence is counted in distinct configurations: repeats of one configuration (within the
joints' noise, :mod:`relcal.calibration.coverage`) are held out together and drawn together by
the bootstrap, so fewer than :data:`MIN_JUDGED` distinct held-out configurations cannot make a
"deploy", however many repeats they hold. Nor can held-out samples that share a limitation of the
whole set (``limits``: a joint that never moved, every sample at a singular configuration): they
validate the model only where the samples were; the interval given for a new session then
reaches down to 1 (no improvement), as nothing measured bounds the model elsewhere.

Fewer than :data:`MIN_HELD_OUT` held-out samples add a warning: a bootstrap over so few samples
gives a rough interval.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from relcal.calibration.validate import PlacementValidation, Validation

MIN_HELD_OUT = 10  # held-out samples below which the verdict warns
MIN_JUDGED = 5  # held-out samples below which the verdict cannot be "deploy"
Code = Literal["deploy", "collect more samples", "do not deploy", "not validated"]


@dataclass(frozen=True)
class Verdict:
    """``code`` (see the module docstring) and ``text``, the one line a person reads;
    ``factor``: baseline RMS over calibrated RMS (how many times better, > 1 is better) with its
    95 % ``interval``; ``n_held_out``: held-out samples (points, pose samples or coincidence
    samples) the evidence rests on; ``warnings``."""

    code: Code
    text: str
    factor: float | None
    interval: tuple[float, float] | None
    n_held_out: int
    warnings: tuple[str, ...] = ()
    n_configurations: int | None = None  # distinct configurations among the held-out samples
    # the interval of the held-out samples alone, where ``interval`` (for a new session) is wider
    held_out_interval: tuple[float, float] | None = None
    limits: tuple[str, ...] = ()  # what the held-out evidence cannot show


def times(factor: float) -> str:
    """A factor as people say it: ``1.04x``, ``5.8x``, ``48x``, ``110x`` (three significant
    digits below 2, so that a bound near 1 does not read as 1; two below 10; whole numbers
    above)."""
    if factor < 2:
        return f"{factor:.3g}x"
    return f"{factor:.2g}x" if factor < 10 else f"{factor:.0f}x"


def held_out_what(validation: Validation | PlacementValidation, formulation: str = "") -> str:
    """How the held-out evidence is named: ``poses`` (each predicted in the world frame),
    ``points`` (one point per sample), ``pairs of poses`` (relative poses) or ``placements``
    (coincidences): what the validation says, or for one that does not say, what its
    ``formulation`` compares."""
    if isinstance(validation, PlacementValidation):
        return "placements"
    if validation.what is not None:
        return validation.what
    named = {"tracker": "points", "absolute": "points", "board": "poses"}
    return named.get(formulation, "pairs of poses")


def n_held_out(validation: Validation | PlacementValidation) -> int:
    """The number of held-out samples the validation rests on."""
    if isinstance(validation, PlacementValidation):
        return len(validation.samples)
    return len(np.unique(validation.pairs))


def n_configurations(validation: Validation | PlacementValidation) -> int:
    """The distinct configurations (placements for coincidences) the validation rests on."""
    if isinstance(validation, PlacementValidation):
        return len(validation.placements)
    return validation.n_configurations


def verdict(
    validation: Validation | PlacementValidation | None,
    exported: str = "calibrated",
    formulation: str = "invariant",
    limits: tuple[str, ...] = (),
) -> Verdict:
    """The verdict on the exported model from its ``validation`` (see the module docstring);
    ``exported``: ``calibrated`` or ``baseline`` (the data supported no correction, or the
    calibrated model was worse than the baseline on ``validation``, which then names how much);
    ``formulation``: names the evidence of a validation that does not name it; ``limits``:
    what the held-out samples cannot show, in words (a joint that never moved, ...)."""
    if validation is None:
        return Verdict(
            "not validated",
            "not validated: no held-out samples (--holdout 0); measure it with --kfold or "
            "relcal verify before deploying",
            None,
            None,
            0,
            limits=tuple(limits),
        )
    n = n_held_out(validation)
    n_conf = n_configurations(validation)
    placements = isinstance(validation, PlacementValidation)
    warnings: tuple[str, ...] = ()
    if n < MIN_HELD_OUT:
        warnings = (
            f"the validation rests on {n} held-out samples (fewer than {MIN_HELD_OUT}): its "
            "interval is rough; hold out more (--holdout) or cross-validate (--kfold)",
        )
    what = held_out_what(validation, formulation)
    ratio = validation.ratio()
    r, (lo, hi) = ratio["after_over_before"], ratio["ci95"]
    factor = 1.0 / max(r, 1e-300)
    held = (1.0 / max(hi, 1e-300), 1.0 / max(lo, 1e-300))
    evidence = f"{n} held-out samples"
    if n_conf < n and not placements:
        evidence += f" in {n_conf} distinct configuration" + ("s" if n_conf != 1 else "")
    span = f"95% interval {times(held[0])}..{times(held[1])}, {evidence}"
    worse_span = f"95% interval {times(lo)}..{times(hi)}, {evidence}"  # of after over before
    limits = tuple(limits)
    if exported == "baseline":
        exported_text = (
            "the exported model is the baseline, nominal kinematics with the measurement "
            "frames fitted"
        )
        why = "the data support none"
        if validation.rms("calibrated") > validation.rms("before"):  # not the selection's
            why = (
                f"the calibrated model is {times(r)} worse than the baseline on held-out "
                f"{what} ({worse_span})"
            )
        return Verdict(
            "do not deploy",
            f"do not deploy a correction: {why} ({exported_text})",
            None,
            None,
            n,
            warnings,
            n_conf,
            limits=limits,
        )
    few = (n if placements else n_conf) < MIN_JUDGED
    if few:
        code: Code = "collect more samples"
        count = f"{n} held-out samples" if n_conf == n or placements else evidence
        text = (
            f"collect more samples: {count} are too few to judge ({times(factor)} better on "
            f"held-out {what} in this split, no interval to read)"
        )
    elif hi < 1.0 and not limits:
        code = "deploy"
        text = f"deploy: {times(factor)} better on held-out {what} ({span})"
    elif hi < 1.0:
        code = "collect more samples"
        text = (
            f"collect more samples: {times(factor)} better on held-out {what} ({span}), but "
            f"only where the samples were: {'; '.join(limits)}"
        )
    elif lo > 1.0:
        code = "do not deploy"
        text = (
            f"do not deploy: {times(r)} worse than the baseline on held-out {what} ({worse_span})"
        )
    else:
        code = "collect more samples"
        text = (
            f"collect more samples: the interval spans 1 ({times(factor)} better on held-out "
            f"{what}, {span})"
        )
    interval = held
    if few or limits:  # nothing measured bounds the model where the samples were not
        interval = (min(held[0], 1.0), held[1])
        if code != "do not deploy":
            text += f"; a new session: {times(interval[0])}..{times(interval[1])}"
    return Verdict(code, text, factor, interval, n, warnings, n_conf, held, limits)
