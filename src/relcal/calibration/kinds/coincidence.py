"""Coincidences: a tool point seated again and again at unknown points (a ball in the sockets of
a plate, a touch-off pin), with known distances between some of them; the residual
``p_g(k) - F(q_k) t`` per sample and a row per known distance
(:mod:`relcal.calibration.coincidence`), the tool point ``t`` and the group points ``p_g``
estimated with the geometry.

What the kind supplies to the skeleton, beyond what it shares with absolute points
(:class:`~relcal.calibration.kinds.points.PointKind`: the point noise learned from a first fit of
the geometry, weighting the sample rows, the distance rows weighted by their own standard
deviation; outliers from each sample's point error; each candidate fitted and linearised at its
own fit): the guesses of the tool point and the group points from the training samples at the
nominal model (:func:`~relcal.calibration.coincidence.make_coincidence`), the refusal of data that
cannot be this robot's coincidences (:func:`~relcal.calibration.coincidence.check_plausible`, from
the baseline fit), and validation on whole placements held out (a new plate position is the honest
test): the kinematics and the tool point frozen, the held-out placement's group points refitted,
the spread of the predicted points per group and the error of the known distances
(:func:`~relcal.calibration.validate.held_out_placements`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from relcal.calibration.coincidence import (
    check_plausible,
    dataset_problem,
    make_coincidence,
    nuisance_columns,
    placement_of,
)
from relcal.calibration.identifiability import analyse_problem
from relcal.calibration.identify import Result, identify_lm
from relcal.calibration.kinds import Training
from relcal.calibration.kinds.points import PointKind
from relcal.calibration.measurement import Problem
from relcal.calibration.plausibility import check_joint_dataset
from relcal.calibration.validate import folds, held_out_placements
from relcal.errors import RelcalError


@dataclass(frozen=True)
class CoincidenceKind(PointKind):
    """Coincidence groups and known distances; see the module docstring. Samples are split by
    placement (``PLACEMENT/NAME`` groups): ``holdout_ids`` name placements, a random share holds
    out that share of the placements (at least one, leaving one)."""

    formulation = "coincidence"
    baseline = "tool point and group points only"
    what = "samples"

    def problem_on(self, samples: np.ndarray) -> Problem:
        """The coincidence problem of ``samples``, the tool point (``tool:`` in dataset.yaml,
        else solved) and the group points guessed from them at the nominal model."""
        return dataset_problem(self.dataset, samples)

    # --- whole placements ----------------------------------------------------------------------

    def placement_of_samples(self) -> np.ndarray:
        """The placement of each sample ``(N,)``."""
        return np.array([placement_of(g) for g in self.dataset.groups])

    def placements(self) -> tuple[str, ...]:
        """The placements of the usable samples, by name (an order of the data alone)."""
        return tuple(sorted(set(self.placement_of_samples()[self.usable()])))

    def split(
        self, holdout: float, seed: int, holdout_ids: Sequence[str] | None
    ) -> tuple[np.ndarray, np.ndarray]:
        usable = self.usable()
        places = self.placements()
        where = self.placement_of_samples()
        if holdout_ids is not None:
            unknown = [p for p in holdout_ids if p not in places]
            if unknown:
                raise RelcalError(
                    f"held-out placement(s) {', '.join(unknown[:5])} are not in "
                    f"{self.dataset.spec_path.parent}: coincidence samples are held out by "
                    f"placement, one of {', '.join(places)}"
                )
            held = list(holdout_ids)
        elif holdout > 0:
            if len(places) < 2:
                raise RelcalError(
                    f"{self.dataset.spec_path}: {len(places)} placement: holding out a placement "
                    "needs at least two (name groups PLACEMENT/NAME), or --holdout 0"
                )
            n_test = min(max(1, int(round(holdout * len(places)))), len(places) - 1)
            order = np.random.default_rng(seed).permutation(len(places))
            held = [places[i] for i in np.sort(order[:n_test])]
        else:
            held = []
        test = usable[np.isin(where[usable], held)]
        train = np.setdiff1d(usable, test)
        if len(train) < 4:
            raise RelcalError(
                f"{self.dataset.spec_path}: {len(train)} samples left to calibrate; at least 4 "
                "are needed (and many more for a useful calibration)"
            )
        return train, test

    def folds(self, k: int, seed: int) -> list[list[str]]:
        """``k`` folds of whole placements (their names)."""
        places = self.placements()
        if not 2 <= k <= len(places):
            raise RelcalError(
                f"--kfold {k}: {self.dataset.spec_path.parent} has {len(places)} placements; "
                f"coincidence samples are held out by placement, so K is 2 to {len(places)}"
            )
        return [[places[i] for i in f] for f in folds(len(places), k, seed)]

    # --- plausibility and validation ------------------------------------------------------------

    def check_data(self, samples: np.ndarray | None = None) -> None:
        """The joint readings against the model's limits (every usable sample), then another
        robot's joints or a wrong distance refused from the baseline fit (nominal geometry, the
        tool point and the group points fitted to ``samples``, default every usable one)."""
        check_joint_dataset(self.dataset, self.measurements)
        problem = self.problem_on(self.usable() if samples is None else samples)
        ident = analyse_problem(problem)
        nuisance = replace(ident, subset=nuisance_columns(problem))
        baseline = identify_lm(problem, 200, nuisance)
        check_plausible(problem, baseline.params, str(self.dataset.spec_path))
        return None

    def check_inputs(self, train: np.ndarray) -> None:
        """:meth:`check_data`, the baseline fitted to the training samples."""
        return self.check_data(train)

    def validate(
        self,
        training: Training,
        result: Result,
        baseline: Result,
        test: np.ndarray,
        screen: bool = False,  # held-out placements are validated whole
    ):
        """The held-out placements (at least one sample)."""
        if len(test) < 1:
            return None
        ds = self.dataset
        groups = [ds.groups[k] for k in test]  # the tool point guess is not used: frozen
        held = make_coincidence(ds.model, ds.q[test], groups, ds.distances, np.zeros(3))
        params = (result.params, baseline.params)
        return held_out_placements(training.problem, *params, ds.q[test], held, test)

    def result_settings(self, training: Training, result: Result) -> dict:
        """How the covariance was computed: placements as clusters (the samples of one placement
        share its systematic errors: the plate's flatness and socket machining, its
        temperature, what the geometry does not model as it shows at that placement's
        configurations; :func:`~relcal.calibration.uncertainty.clustered_covariance`), the
        method, the number of placements, the inflation of the variances over independent
        samples and its degrees of freedom (:attr:`Result.clustered`, computed once with the
        covariance)."""
        return {"covariance": result.clustered.settings()}

    def settings(self, training: Training) -> dict:
        return {
            "holdout": "placements",
            "baseline": "nominal geometry with the tool point and the group points fitted to the "
            "training samples",
        }
