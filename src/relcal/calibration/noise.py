"""The noise model of measured poses and joint readings, and its estimation from residuals.

A measured camera pose is ``C_k exp(eps_k)`` with ``eps_k`` the pose error in the camera's own
(body) frame, translation (m) then rotation (rad). A relative measurement of the pair (i, j) then
carries ``eps_j - Ad(M_ij^-1) eps_i`` (``M_ij`` the relative motion), so its residual covariance
is ``Sigma + Ad Sigma Ad^T``: the rotation of the pair mixes the components, and camera-pose
errors in translation and rotation are strongly correlated (a small tilt of the camera and a
sideways shift explain the same image motion). :func:`estimate_pose_noise` finds the full 6x6
``Sigma`` from the residuals by the method of moments, robustly.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse

from relcal.checks import check_array, check_instance, check_number, describe
from relcal.errors import ArgumentError, RelcalError, excerpt
from relcal.geometry import DEG, MM


@dataclass(frozen=True)
class Noise:
    """Standard deviations of measurement noise: position (m), orientation (rad), joints (rad).

    Parameters
    ----------
    position : float
        Standard deviation of each position component of a measured pose, m.
    orientation : float
        Standard deviation of each rotation-vector component of a measured pose, rad.
    joints : float
        Standard deviation of each joint reading, rad (m for prismatic joints).
    covariance : (6, 6) ndarray of float or None
        Covariance of a pose's body-frame error (translation m, rotation rad) replacing the
        isotropic ``position`` and ``orientation`` levels when given (a learned noise model).
    """

    position: float = 0.0
    orientation: float = 0.0
    joints: float = 0.0
    # (6, 6) covariance of the body-frame pose error (translation m, rotation rad), replacing the
    # isotropic position and orientation levels when given (a learned noise model).
    covariance: np.ndarray | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        """Arguments checked where the API is entered: each level a finite number >= 0 (SI:
        m, rad; a string such as '0.05mm' is for :meth:`parse`), the covariance ``(6, 6)``."""
        for name in ("position", "orientation", "joints"):
            value = getattr(self, name)
            if isinstance(value, str):
                raise ArgumentError(
                    f"Noise.{name}: expected a number (m or rad), got {describe(value)}; text "
                    "such as '0.05,0.01' (mm, degrees) is read by Noise.parse"
                )
            object.__setattr__(self, name, check_number(value, f"Noise.{name}", 0))
        if self.covariance is not None:
            cov = check_array(
                self.covariance,
                "Noise.covariance",
                (6, 6),
                hint="the covariance of a pose's body-frame error (translation m, rotation rad)",
            )
            object.__setattr__(self, "covariance", cov)

    def pose_covariance(self) -> np.ndarray:
        """The covariance of one measured pose's body-frame error.

        Returns
        -------
        (6, 6) ndarray of float
            Translation (m^2) then rotation-vector (rad^2) blocks: ``covariance`` when given,
            otherwise diagonal from ``position`` and ``orientation``.
        """
        if self.covariance is not None:
            return np.asarray(self.covariance, dtype=float)
        return np.diag(np.r_[np.full(3, self.position**2), np.full(3, self.orientation**2)])

    @classmethod
    def parse(cls, text: str) -> Noise:
        """Noise levels from text (as the command line's noise option takes them).

        Parameters
        ----------
        text : str
            ``"POS_MM,ORI_DEG[,JOINT_DEG]"``, e.g. ``"0.05,0.01,0.001"``: mm and degrees.

        Returns
        -------
        Noise
            The levels in m and rad.

        Raises
        ------
        RelcalError
            Not two or three numbers (read strictly, :func:`relcal.numbers.parse_number`), or
            a level below 0 or beyond 1000 mm or 180 deg.
        """
        from relcal.numbers import NotANumber, noise_numbers

        check_instance(text, str, "text", "noise levels such as '0.05,0.01' (mm, degrees)")
        try:
            values = noise_numbers(text)
        except NotANumber as exc:
            raise RelcalError(
                f"noise levels {excerpt(text)}: expected POS_MM,ORI_DEG[,JOINT_DEG] standard "
                f"deviations: {exc}"
            ) from None
        return cls(values[0] * MM, values[1] * DEG, values[2] * DEG)


def robust_scale(values: np.ndarray) -> float:
    """1.4826 times the median absolute deviation of ``values`` (any shape): their standard
    deviation where they are normal, little moved by outliers."""
    values = np.asarray(values, dtype=float)
    return 1.4826 * float(np.median(np.abs(values - np.median(values))))


def robust_sigma(errors: np.ndarray) -> np.ndarray:
    """Per-row noise levels ``(6,)``: :func:`robust_scale` of the translation and of the
    rotation rows of ``errors`` ``(n, 6)``, at least 1e-12."""
    sigma = np.empty(6)
    for rows in (slice(0, 3), slice(3, 6)):
        sigma[rows] = max(robust_scale(errors[:, rows]), 1e-12)
    return sigma


# --- learning the pose noise from pair residuals -------------------------------------------------

_SYM = np.array([(a, b) for a in range(6) for b in range(a, 6)])  # the 21 free entries of Sigma
_BASIS = np.zeros((len(_SYM), 6, 6))  # Sigma = sum_s theta_s _BASIS[s]: ones at (a, b), (b, a)
_BASIS[np.arange(len(_SYM)), _SYM[:, 0], _SYM[:, 1]] = 1.0
_BASIS[np.arange(len(_SYM)), _SYM[:, 1], _SYM[:, 0]] = 1.0


def pair_covariances(sigma: np.ndarray, left: np.ndarray) -> np.ndarray:
    """Residual covariances ``(P, 6, 6)`` of pairs whose residual is ``eps_j + L_p eps_i`` with
    ``left`` ``(P, 6, 6)`` = ``-Ad(M_ij^-1)``, for pose errors of covariance ``sigma`` (6, 6)."""
    # (the transposes as one array: a strided view makes every small product slower)
    return sigma + left @ sigma @ np.ascontiguousarray(np.swapaxes(left, -1, -2))


def _moment_design(left: np.ndarray) -> np.ndarray:
    """``D`` ``(P * 36, 21)``: ``vec(pair covariance) = D theta`` for Sigma's free entries (the
    pair covariance of each basis element of :data:`_BASIS`)."""
    return pair_covariances(_BASIS[:, None], left).reshape(len(_SYM), -1).T


@dataclass(frozen=True)
class PoseNoise:
    """A learned noise model: the covariance of each measured pose's body-frame error."""

    covariance: np.ndarray  # (6, 6): translation (m), rotation (rad)
    n_pairs: int
    downweighted: int  # pairs whose weight the robust estimate reduced

    @property
    def std(self) -> np.ndarray:
        """Standard deviations ``(6,)`` of the pose error components (m, rad)."""
        return np.sqrt(np.diag(self.covariance))

    @property
    def correlation(self) -> np.ndarray:
        s = self.std
        return self.covariance / np.outer(s, s)

    @property
    def noise(self) -> Noise:
        s = self.std
        return Noise(
            position=float(np.sqrt(np.mean(s[:3] ** 2))),
            orientation=float(np.sqrt(np.mean(s[3:] ** 2))),
            covariance=self.covariance,
        )

    def max_translation_rotation_correlation(self) -> float:
        """The largest ``|rho|`` between a translation and a rotation component."""
        return float(np.abs(self.correlation[:3, 3:]).max())


def _fit_correction(
    left: np.ndarray, pairs: np.ndarray, jac: np.ndarray, row_weights: np.ndarray, keep
) -> np.ndarray:
    """``C`` ``(K * 36, 21)`` with ``E vec(r_p r_p^T) = (D - C) theta`` for the residuals ``r``
    left by a least-squares fit of ``jac`` ``(P, 6, k)`` with row weights ``row_weights``
    ``(6,)``, at the ``K`` pairs ``keep``: what the fit takes out of each pair's covariance.

    With ``y = G e`` the pairs' noise (``G``: pose ``j`` enters as itself, pose ``i`` through
    ``L_p``), the fit removes ``J A y`` with ``A = (J^T W J)^+ J^T W``; so
    ``E r_p r_p^T = S_pp - T_p - T_p^T + J_p Q J_p^T``, where ``M = A G`` ``(N, k, 6)`` per pose,
    ``T_p = (Sigma M_j^T + L_p Sigma M_i^T) J_p^T`` and ``Q = sum_n M_n Sigma M_n^T``.
    """
    n_pairs, _, k = jac.shape
    w2 = np.asarray(row_weights, dtype=float) ** 2
    rows = jac.reshape(-1, k)
    weighted = (jac * w2[:, None]).reshape(-1, k)  # W J
    scale = np.sqrt(np.clip(np.einsum("rk,rk->k", rows, weighted), 1e-300, None))
    normal = (rows.T @ weighted) / np.outer(scale, scale)
    inv = np.linalg.pinv(normal, hermitian=True) / np.outer(scale, scale)
    a = np.swapaxes((weighted @ inv).reshape(n_pairs, 6, k), 1, 2)  # A per pair (P, k, 6)
    i, j = np.asarray(pairs, dtype=int).T
    n_poses = int(max(i.max(), j.max())) + 1
    # M = A G per pose: pair p adds A_p to pose j_p and A_p L_p to pose i_p
    incidence = scipy.sparse.csr_matrix(
        (np.ones(2 * n_pairs), (np.r_[j, i], np.arange(2 * n_pairs))), (n_poses, 2 * n_pairs)
    )
    m = (incidence @ np.concatenate([a, a @ left]).reshape(2 * n_pairs, -1)).reshape(-1, k, 6)
    jk, lk = jac[keep], left[keep]
    # M_j^T J_p^T and M_i^T J_p^T (K, 6, 6), as arrays (not strided views): the 21 K small
    # products below take twice as long on views
    after = np.ascontiguousarray(np.swapaxes(jk @ m[j[keep]], 1, 2))
    before = np.ascontiguousarray(np.swapaxes(jk @ m[i[keep]], 1, 2))
    basis = _BASIS[:, None]
    cross = basis @ after + lk @ (basis @ before)  # (21, K, 6, 6)
    # sum_n M_n E M_n^T for each basis element E (from one product: G[k, a, l, b] =
    # sum_n M_n[k, a] M_n[l, b]), then J_p (.) J_p^T
    flat = m.reshape(len(m), -1)
    gram = (flat.T @ flat).reshape(k, 6, k, 6)
    q = gram[:, _SYM[:, 0], :, _SYM[:, 1]] + gram[:, _SYM[:, 1], :, _SYM[:, 0]]  # (21, k, k)
    q[_SYM[:, 0] == _SYM[:, 1]] /= 2.0
    jq = (jk.reshape(-1, k) @ q).reshape(len(_SYM), len(jk), 6, k)  # one product per E
    out = cross + np.swapaxes(cross, -1, -2) - jq @ np.swapaxes(jk, -1, -2)
    return out.reshape(len(_SYM), -1).T


def estimate_pose_noise(
    errors: np.ndarray,
    left: np.ndarray,
    fit: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    iterations: int = 5,
    clip: float = 16.8,
    max_pairs: int = 3000,
) -> PoseNoise:
    """The pose-error covariance ``Sigma`` that explains pair residuals ``errors`` ``(P, 6)``
    (translation m, rotation rad; as measured minus modelled) with ``left`` ``(P, 6, 6)`` of
    :func:`pair_covariances`.

    Method of moments: ``r_p r_p^T ~ Sigma + L_p Sigma L_p^T``, linear in the 21 entries of
    ``Sigma``, solved by least squares over all pairs; pairs whose Mahalanobis distance exceeds
    ``clip`` (the 99 % point of chi-square with 6 degrees of freedom) are weighted down (Huber),
    iterated. ``fit``: ``(pairs (P, 2), jac (P, 6, k), row_weights (6,))`` of the least-squares
    fit that left these residuals; the moments then include what it took out of each component
    (:func:`_fit_correction`: a fit absorbs more of the translation rows than of the rotation
    rows, which one degrees-of-freedom factor for all would leave biased).
    """
    errors = np.asarray(errors, dtype=float)
    n_pairs = len(errors)
    keep = np.arange(n_pairs)
    if n_pairs > max_pairs:  # a random share carries the same information about 21 numbers
        keep = np.sort(np.random.default_rng(0).choice(n_pairs, max_pairs, replace=False))
    design = _moment_design(left[keep])
    if fit is not None:
        design = design - _fit_correction(left, *fit, keep)
    errors, left = errors[keep], left[keep]
    outer = (errors[:, :, None] * errors[:, None, :]).reshape(len(errors), 36)
    # per pair, the normal equations' share (weights are per pair): formed once
    blocks = design.reshape(len(errors), 36, len(_SYM))
    normal = np.swapaxes(blocks, 1, 2) @ blocks  # (K, 21, 21)
    rhs = np.einsum("pri,pr->pi", blocks, outer)
    weight = np.ones(len(errors))
    sigma = np.eye(6)
    for _ in range(iterations):
        theta = np.linalg.lstsq(np.tensordot(weight, normal, 1), weight @ rhs, rcond=None)[0]
        sigma = np.tensordot(theta, _BASIS, 1)
        vals, vecs = np.linalg.eigh(sigma)
        floor = 1e-12 * max(vals.max(), 1e-30)
        sigma = (vecs * np.clip(vals, floor, None)) @ vecs.T
        cov = pair_covariances(sigma, left)
        d2 = np.einsum("pi,pi->p", errors, np.linalg.solve(cov, errors[..., None])[..., 0])
        weight = np.minimum(1.0, clip / np.maximum(d2, 1e-300))
    return PoseNoise(sigma, n_pairs, int(np.sum(weight < 1.0)))


def row_factors(whiten: np.ndarray) -> np.ndarray | None:
    """The row factors ``(6,)`` when every block of ``whiten`` ``(P, 6, 6)`` is the same diagonal
    matrix (the plain weighting, :func:`relcal.calibration.selection.plain_whiteners`), else
    None. Such a whitening is a scaling of the rows: the same numbers as the block products,
    without them."""
    if not len(whiten):
        return None
    first = whiten[0]
    factors = np.diag(first)
    if np.any(first != np.diag(factors)) or np.any(whiten != first):
        return None
    return factors.copy()


def pair_whiteners(sigma: np.ndarray, left: np.ndarray) -> np.ndarray:
    """``W_p`` ``(P, 6, 6)`` with ``W_p S_p W_p^T = I`` for the pair covariances ``S_p``: the
    inverse Cholesky factors."""
    chol = np.linalg.cholesky(pair_covariances(sigma, left))
    return np.linalg.inv(chol)
