"""Poses (a camera looking at a board, a motion-capture rigid body, a tracker's 6-D probe): by
default (pairing ``board``, what ``auto`` stands for) each measured pose against ``W F(q_k) X``,
with the hand-eye transform ``X`` and the world (board, instrument) transform ``W`` estimated with
the geometry: one residual block per sample, the maximum-likelihood form of independent pose
noise, in time and memory linear in the samples; or the frame-invariant relative form (pairings
``all``, ``consecutive``, ``star``) ``M_ij = C_i^-1 C_j`` against ``X^-1 F_i^-1 F_j X``, in which
``W`` cancels.

What the kind supplies to the skeleton: the hand-eye guess (``handeye:`` in dataset.yaml, else
:func:`~relcal.calibration.handeye.solve_handeye` on the training samples, kept once outliers are
left out), the plausibility checks of relative rotations and translation scale before fitting
(:func:`~relcal.calibration.plausibility.check_dataset`), outliers found from each sample's
errors in units of their robust noise, a 6x6 pose noise learned from the residuals
(:func:`~relcal.calibration.noise.estimate_pose_noise`) with two row weightings (``plain``:
translation in m, rotation times a lever arm; ``noise model``: each measurement whitened by its
learned covariance), one linearisation at the geometric fit shared by every candidate of model
selection, and validation of each held-out pose predicted in the world frame: ``W F(q) X`` with
``W`` taken from the training fit (:func:`held_out_poses`), whatever the pairing of the fit.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from relcal import geometry as tf
from relcal.calibration.handeye import solve_handeye
from relcal.calibration.identifiability import check_pose_set
from relcal.calibration.identify import Result
from relcal.calibration.kinds import MeasurementKind, NoiseModel, Training
from relcal.calibration.measurement import (
    Problem,
    board_guess,
    board_lever,
    make_pairs,
    pair_errors,
    residuals,
    resolve_pairing,
    world_of,
)
from relcal.calibration.noise import (
    estimate_pose_noise,
    pair_whiteners,
    robust_scale,
    robust_sigma,
)
from relcal.calibration.outcome import ROBUST_SCALE, outlier_samples
from relcal.calibration.plausibility import check_dataset, check_result
from relcal.calibration.selection import (
    geometric_columns,
    plain_whiteners,
)
from relcal.calibration.validate import held_out
from relcal.limits import check_calibration_memory
from relcal.robot.kinematics import fk, make_layout


@dataclass(frozen=True)
class PoseKind(MeasurementKind):
    """Relative camera (or mocap) poses; see the module docstring."""

    formulation = "invariant"
    measure = "pose"
    baseline = "hand-eye only"
    detection_loss = "linear"
    shared_linearisation = True
    refit_from_nominal = False

    @property
    def strategy(self) -> str:
        """The pairing used: the kind's ``pairing`` with ``auto`` resolved by the number of usable
        samples (:func:`~relcal.calibration.measurement.resolve_pairing`)."""
        return resolve_pairing(self.pairing, len(self.usable()))

    def problem_on(
        self, samples: np.ndarray, handeye: np.ndarray, board: np.ndarray | None = None
    ) -> Problem:
        """The problem of ``samples``: frame-invariant (paired as :attr:`strategy` says), or, for
        the ``board`` strategy, each pose against ``W F X`` with the board guess ``board`` (default:
        :func:`~relcal.calibration.measurement.board_guess` from these samples)."""
        ds = self.dataset
        q, poses = ds.q[samples], self.measurements.poses[samples]
        layout = make_layout(ds.model)
        if self.strategy == "board":
            if board is None:
                board = board_guess(fk(ds.model, q), poses, handeye)
            return Problem(ds.model, layout, q, poses, "board", "pose", None, handeye, board=board)
        pairs = make_pairs(len(samples), self.strategy)
        return Problem(ds.model, layout, q, poses, "invariant", "pose", pairs, handeye)

    def check_inputs(self, train: np.ndarray) -> dict:
        ds = self.dataset
        n_params = make_layout(ds.model).size + 6
        # all pairs are quadratic: refused before they are formed
        check_calibration_memory(len(ds.ids), self.strategy, n_params, str(ds.root), len(train))
        return self.check_data()

    def check_data(self) -> dict:
        """Joint limits, magnitudes, relative rotations and translations against the commanded
        ones, a wrong unit, order or board named
        (:func:`~relcal.calibration.plausibility.check_dataset`)."""
        return check_dataset(self.dataset, self.measurements)

    def training(self, train: np.ndarray, previous: Training | None = None) -> Training:
        ds = self.dataset
        if previous is not None:  # the frame guesses of the first training set (the fits'
            # frame parameters are moves from them), the analysis of these samples (a wrong
            # sample, an inverted pose, bends the Jacobian at nominal through its residual)
            problem = self.problem_on(train, previous.problem.handeye, previous.problem.board)
            ident = check_pose_set(problem, str(ds.spec_path), refuse=False)
            return Training(train, problem, ident, geometric_columns(problem, ident.subset))
        handeye = ds.handeye
        if handeye is None:
            handeye = solve_handeye(fk(ds.model, ds.q[train]), self.measurements.poses[train])
        problem = self.problem_on(train, handeye)
        ident = check_pose_set(problem, str(ds.spec_path), refuse=False)
        return Training(train, problem, ident, geometric_columns(problem, ident.subset))

    def weighted(
        self, training: Training, weighting: str, whiteners: dict[str, np.ndarray] | None = None
    ) -> Problem:
        return weighted_problem(training.problem, weighting, whiteners)

    def f_scale(self, weighted: Problem) -> float:
        """:data:`ROBUST_SCALE` robust standard deviations of the weighted rows at nominal."""
        r0 = residuals(weighted, np.zeros(weighted.full_layout.size), jacobian=False)
        return ROBUST_SCALE * max(robust_scale(r0), 1e-12)

    def outliers(self, training: Training, detection: Result) -> np.ndarray:
        """A robust per-sample median of its pairs' errors (a few bad samples do not hide among
        their pairs), the errors in units of their robust noise levels."""
        problem = training.problem
        errors = pair_errors(problem, detection.params)
        return outlier_samples(errors / robust_sigma(errors), problem.pair_indices())

    def learn_noise(self, training: Training, full: Result, lin) -> NoiseModel:
        """The full 6x6 pose noise from the pair residuals of the geometric fit, and the row
        whitening of both weightings."""
        problem = training.problem
        left = pair_left_maps(problem)
        fitted = (lin.pairs, lin.jac[:, :, training.geometric], plain_rows(problem))
        noise = estimate_pose_noise(pair_errors(problem, full.params), left, fitted)
        whiteners = {
            "plain": np.broadcast_to(np.diag(plain_rows(problem)), (len(left), 6, 6)),
            "noise model": pair_whiteners(noise.covariance, left),
        }
        return NoiseModel(noise, whiteners)

    def check_result(self, training: Training, result: Result) -> None:
        check_result(self.dataset, training.problem, result)

    def validate(
        self,
        training: Training,
        result: Result,
        baseline: Result,
        test: np.ndarray,
        screen: bool = False,
    ):
        """Each held-out pose predicted in the world frame, ``W F(q) X`` with ``W`` from the
        training fit, against the measured one (:func:`held_out_poses`), for the nominal model
        with the frame guesses, the baseline and the calibrated model."""
        if len(test) < 1:
            return None
        return held_out_poses(
            training,
            self.dataset.q,
            self.measurements.poses,
            result,
            baseline,
            test,
            screen=screen,
            units=self.configurations(),
        )

    def settings(self, training: Training) -> dict:
        """The pairing used (``auto`` resolved)."""
        return {"pairing": self.strategy}


def world_params(training: Training, params: np.ndarray) -> np.ndarray:
    """The fit ``params`` of ``training.problem`` as parameters of the board formulation with the
    identity as board guess: ``(geometry, hand-eye 6-vector, W as a 6-vector)``, ``W`` the fit's
    world transform (:func:`~relcal.calibration.measurement.world_of`)."""
    problem = training.problem
    n_frames = problem.layout.size + 6
    return np.r_[params[:n_frames], tf.to_vector(world_of(problem, params))]


def held_out_poses(
    training: Training,
    q: np.ndarray,
    poses: np.ndarray,
    result: Result,
    baseline: Result,
    test: np.ndarray,
    screen: bool = False,
    units: np.ndarray | None = None,
):
    """The held-out poses ``test`` (dataset indices into joints ``q`` and ``poses``) predicted
    in the world frame by the nominal model with the frame guesses, the ``baseline`` and
    ``result``, each with its world transform from the training fit (:func:`world_params`);
    with ``screen``, held-out samples that fit badly under both models left out
    (:func:`validate.held_out_outliers`)."""
    problem = training.problem
    everything = Problem(
        problem.model,
        problem.layout,
        q,
        poses,
        "board",
        "pose",
        None,
        problem.handeye,
        board=np.eye(4),
    )

    def as_board(fit: Result) -> Result:
        return replace(fit, params=world_params(training, fit.params))

    guess = world_params(training, np.zeros(problem.full_layout.size))
    return held_out(
        everything,
        as_board(result),
        test,
        baseline=as_board(baseline),
        train=training.samples if screen else None,
        guess=guess,
        units=units,
    )


def weighted_problem(
    problem: Problem, weighting: str, whiteners: dict[str, np.ndarray] | None = None
) -> Problem:
    """``problem`` with the rows weighted as ``weighting`` says (the plain weighting is diagonal:
    row factors, no per-pair blocks)."""
    if weighting == "plain":
        return replace(problem, weights=plain_rows(problem), pair_weights=None)
    return replace(problem, weights=None, pair_weights=whiteners[weighting])


def plain_rows(problem: Problem) -> np.ndarray:
    """The plain weighting's row factors ``(6,)``: translation rows in m, rotation rows times
    0.1 m/rad for pairs (:func:`~relcal.calibration.selection.plain_whiteners`); for the board
    formulation times the median distance (m) of the camera from the board's origin, the lever
    arm by which a camera's rotation error moves what it sees (a relative pose carries it in its
    translation; a pose against the board only in its rotation rows)."""
    rows = np.diag(plain_whiteners(1)[0]).copy()
    if problem.formulation == "board":
        rows[3:] = board_lever(problem.poses)
    return rows


def pair_left_maps(problem: Problem) -> np.ndarray:
    """``-Ad(M_ij^-1)`` ``(P, 6, 6)`` of the measured relative motions: how pose i's error enters
    pair (i, j)'s residual (pose j's enters as itself). Zero for the board formulation, whose
    measurements ``(k, k)`` carry one pose's error each."""
    if problem.formulation == "board":
        return np.zeros((len(problem.q), 6, 6))
    return -tf.adjoint(tf.invert(problem.measured_motions))
