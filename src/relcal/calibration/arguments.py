"""The arguments of :func:`relcal.calibrate`, checked where the API is entered (the generic
primitives are :mod:`relcal.checks`)."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from relcal.calibration.selection import WEIGHTINGS
from relcal.checks import (
    check_choice,
    check_flag,
    check_names,
    check_number,
    check_seed,
    describe,
)
from relcal.data.dataset import check_dataset
from relcal.data.imaging import check_measurements
from relcal.errors import ArgumentError
from relcal.robot.model import NONGEOMETRIC

SELECTIONS = ("cv", "conservative", "all")
PRIORS = ("model", "none")  # the model file's priors, or plain least squares


def check_calibrate(
    dataset: Any,
    measurements: Any,
    holdout: Any,
    seed: Any,
    pairing: Any,
    method: Any,
    loss: Any,
    holdout_ids: Any,
    select_folds: Any,
    selection: Any,
    nongeometric: Any = "auto",
    weightings: Any = ("plain",),
    keep_outliers: Any = False,
    priors: Any = "model",
) -> None:
    """The arguments of :func:`relcal.calibrate`."""
    check_dataset(dataset)
    if measurements is not None:
        check_measurements(measurements, dataset)
    check_number(holdout, "holdout", 0, 1, high_open=True)
    check_seed(seed)
    check_choice(pairing, "pairing", ("auto", "consecutive", "star", "all", "board"))
    check_choice(method, "method", ("lm", "published"))
    check_choice(loss, "loss", ("linear", "huber", "cauchy", "soft_l1"))
    check_choice(selection, "selection", SELECTIONS)
    check_number(select_folds, "select_folds", 2, integer=True)
    if holdout_ids is not None:
        if (
            isinstance(holdout_ids, str)
            or not isinstance(holdout_ids, Iterable)
            or not all(isinstance(i, str) for i in holdout_ids)
        ):
            raise ArgumentError(
                f"holdout_ids: expected a list of sample ids (strings), got "
                f"{describe(holdout_ids)}"
                + ("; a single id is ['s1'], not 's1'" if isinstance(holdout_ids, str) else "")
            )
    if isinstance(nongeometric, str):
        if nongeometric not in ("auto", "none"):
            raise ArgumentError(
                f"nongeometric: unknown {describe(nongeometric)}; expected 'auto', 'none' or a "
                f"list of families ({', '.join(NONGEOMETRIC)}), e.g. ['scale']"
            )
    else:
        check_names(nongeometric, "nongeometric", NONGEOMETRIC, "['scale']", empty=True)
    check_names(weightings, "weightings", WEIGHTINGS, "['plain']")
    check_flag(keep_outliers, "keep_outliers")
    check_choice(priors, "priors", PRIORS)
    check_training_share(dataset, holdout, holdout_ids, nongeometric, pairing)


MIN_TRAINING = 4  # samples a calibration trains on at the very least (kinds' usable minimum)
ROWS = {"pose": 6, "image": 6, "position": 3}  # residual rows per measurement
REDUNDANCY = 1.25  # training rows per parameter at the least: a residual to learn the noise from


def training_minimum(
    dataset: Any, nongeometric: Any = "auto", pairing: str = "auto"
) -> tuple[int, int]:
    """``(samples, parameters)``: the fewest training samples whose residual rows cover the
    parameters of the largest candidate model and the frames (hand-eye, and the board for the
    board formulation; instrument and marker for points), and cover those of the geometry and
    the frames :data:`REDUNDANCY` times (one row per parameter fits, but leaves no residual to
    learn the noise from: the standard deviations are then refused; the non-geometric families
    are dropped when the samples do not determine them), never fewer than
    :data:`MIN_TRAINING`."""
    from relcal.calibration.selection import candidate_model
    from relcal.limits import pair_count, resolve_pairing
    from relcal.robot.kinematics import make_layout

    kind = getattr(dataset, "measured", "pose")
    size = make_layout(candidate_model(dataset.model, nongeometric)).size
    geometric = int(make_layout(candidate_model(dataset.model, "none")).is_geometric().sum())
    if kind == "position":
        frames, measurements = 9, (lambda n: n)
    else:
        used = resolve_pairing(pairing, len(dataset.ids))
        frames = 12 if used == "board" else 6
        measurements = lambda n: pair_count(n, used)  # noqa: E731
    n_params = size + frames
    need = max(n_params, REDUNDANCY * (geometric + frames))
    least = MIN_TRAINING
    while ROWS[kind] * measurements(least) < need and least < len(dataset.ids):
        least += 1
    return least, n_params


def check_training_share(
    dataset: Any, holdout: float, holdout_ids: Any, nongeometric: Any = "auto", pairing="auto"
) -> None:
    """Refuse a split that leaves too few samples to train on (every sample held out, or all
    but a few: fewer rows than the parameters of the largest candidate model and the frames),
    naming ``holdout_ids`` or ``holdout`` and a split that works, before any work. Coincidence
    data hold out whole placements: their kind checks them."""
    kind = getattr(dataset, "measured", None)
    if kind not in ROWS:
        return
    ids = list(dataset.ids)
    n = len(ids)
    least, n_params = training_minimum(dataset, nongeometric, pairing)
    if n < least + 2:  # too few to hold any out at all: the fit's own refusal says so
        return
    each = "sample" if kind == "position" else "measurement"
    why = (
        f"a calibration needs at least {least} ({n_params} parameters of the largest candidate "
        f"model and the frames, {ROWS[kind]} rows per {each}, and rows to spare to learn the "
        "noise from)"
    )
    if holdout_ids is not None:
        held = len(set(holdout_ids) & set(ids))
        left = n - held
        if left < least:
            raise ArgumentError(
                f"holdout_ids: holds out {held} of the {n} samples, leaving {left} to train on; "
                f"{why}: hold out at most {n - least}"
            )
    elif holdout > 0:
        held = _held(holdout, n)
        left = n - held
        if left < least:
            fits = [h / 100 for h in range(99, 0, -1) if n - _held(h / 100, n) >= least]
            fix = f"give holdout at most {fits[0]:.2f}" if fits else "give holdout 0"
            raise ArgumentError(
                f"holdout: {holdout:g} of {n} samples holds out {held}, leaving {left} to train "
                f"on; {why}: {fix}"
            )


def _held(holdout: float, n: int) -> int:
    """Samples a random split holds out (:func:`relcal.calibration.validate.split`)."""
    return max(2, int(round(holdout * n)))
