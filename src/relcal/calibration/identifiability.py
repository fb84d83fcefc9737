"""Which parameters relative data can identify, judged on the scaled identification Jacobian.

Columns are scaled to unit norm so that metres and radians compare; the rank tolerance is relative
to the largest singular value of the scaled matrix (DESIGN.md). Null-space directions are reduced
to sparse combinations and named in words: a rigid motion of the base, a change of the hand-eye
transform, offsets along parallel axes, or no effect at all.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from relcal.robot.kinematics import Layout

DEFAULT_RCOND = 1e-6
_INVOLVED = 1e-6  # a parameter with a larger share of a null vector is not identifiable alone


@dataclass(frozen=True)
class Combination:
    """An unidentifiable direction: ``sum(coefficients * parameters)`` has no effect on the data."""

    names: tuple[str, ...]
    coefficients: tuple[float, ...]  # in SI units (m, rad)
    is_angle: tuple[bool, ...]
    reason: str

    def describe(self) -> str:
        """E.g. ``theta_off[6] +1 deg with a[6] +0.698 mm together: acts like ...``, in mm and
        deg, scaled so that the leading parameter (the first one not of the hand-eye transform)
        moves by one unit; terms below 0.1 % of the largest are left out of the text."""
        if len(self.names) == 1:
            return f"{self.names[0]}: {self.reason}"
        shown = np.array(
            [
                np.degrees(c) if a else c * 1e3
                for c, a in zip(self.coefficients, self.is_angle, strict=True)
            ]
        )
        lead = next((k for k, n in enumerate(self.names) if not n.startswith("handeye.")), None)
        shown /= shown[lead] if lead is not None else np.abs(shown).max()
        big = np.abs(shown) >= 1e-3 * np.abs(shown).max()
        terms = [
            f"{n} {c:+.3g} {'deg' if a else 'mm'}"
            for n, c, a, keep in zip(self.names, shown, self.is_angle, big, strict=True)
            if keep
        ]
        return f"{' with '.join(terms)} together: {self.reason}"


@dataclass(frozen=True)
class Identifiability:
    """Singular values of the scaled Jacobian and what they imply."""

    singular_values: np.ndarray  # (P,), descending, of the unit-column Jacobian
    column_norms: np.ndarray  # (P,) scale of each column
    rank: int
    rcond: float
    identifiable: np.ndarray  # (P,) bool: determined individually by the data
    subset: np.ndarray  # (rank,) parameter indices chosen by QR with column pivoting
    null_space: np.ndarray  # (P, P - rank) in original parameter units, columns unit-norm
    combinations: tuple[Combination, ...]

    @property
    def condition_number(self) -> float:
        s = self.singular_values
        return float(s[0] / s[self.rank - 1]) if self.rank else float("inf")


def scaled(jac: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit-norm columns and the norms. Columns at round-off level (below 1e-9 of the largest)
    have no effect: they keep norm 1 so that they stay (numerically) zero."""
    norms = np.linalg.norm(jac, axis=0)
    norms = np.where(norms > 1e-9 * norms.max(initial=0.0), norms, 1.0)
    return jac / norms, norms


def _rank_and_involved(s: np.ndarray, vt: np.ndarray, rcond: float) -> tuple[int, np.ndarray]:
    """Numerical rank from singular values ``s`` and the mask of parameters with a share of the
    null space (rows of ``vt`` beyond the rank), both in scaled coordinates."""
    rank = int(np.sum(s > rcond * (s[0] if len(s) else 0.0)))
    return rank, np.linalg.norm(vt[rank:], axis=0) > _INVOLVED


def _singular(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Singular values and right singular vectors ``(s, vt)`` of ``matrix``, from the SVD of its
    triangular QR factor: the same values, about half the cost for tall matrices (no ``U``)."""
    _, s, vt = np.linalg.svd(np.linalg.qr(matrix, mode="r"), full_matrices=False)
    return s, vt


def identifiable_mask(jac: np.ndarray, rcond: float = DEFAULT_RCOND) -> np.ndarray:
    """The ``identifiable`` mask of :func:`analyse` alone (one SVD, no QR or null-space naming)."""
    unit, _ = scaled(jac)
    return ~_rank_and_involved(*_singular(unit), rcond)[1]


def sparse_basis(
    null: np.ndarray, tol: float = 1e-9, preference: np.ndarray | None = None
) -> np.ndarray:
    """A sparse basis of the span of ``null`` ``(P, k)``: each column led by its own pivot parameter
    (chosen by QR with column pivoting, so the pivots are well conditioned), unit-norm columns.
    ``preference`` ``(P,)`` weighs the pivot choice: a parameter weighted 0.01 leads a column only
    when the others cannot."""
    k = null.shape[1]
    weight = np.ones(len(null)) if preference is None else preference
    _, _, piv = scipy.linalg.qr(null.T * weight, pivoting=True)
    basis = np.linalg.solve(null.T[:, piv[:k]], null.T)  # identity in the pivot columns
    basis[np.abs(basis) < tol] = 0.0
    basis = basis[np.argsort(piv[:k])]  # ordered by pivot parameter
    return (basis / np.linalg.norm(basis, axis=1, keepdims=True)).T


def analyse(
    jac: np.ndarray,
    layout: Layout,
    rcond: float = DEFAULT_RCOND,
    explain=None,
) -> Identifiability:
    """Rank, identifiable subset and named null-space combinations of a Jacobian ``(M, P)``.

    ``explain(vector) -> str``, if given, names why a null-space direction (in parameter units)
    does not change the data; otherwise the generic reason is used.
    """
    unit, norms = scaled(jac)
    s, vt = _singular(unit)
    rank, involved = _rank_and_involved(s, vt, rcond)
    null_scaled = vt[rank:].T  # (P, k) in scaled coordinates
    # The hand-eye transform is estimated whole where it can be: the link parameters it absorbs
    # (the leads of the combinations below) stay at nominal, so the exported model changes only
    # what the data determine.
    hand_eye = np.array([kind == "handeye" for kind in layout.kinds])
    _, _, piv = scipy.linalg.qr(
        unit * np.where(hand_eye, 10.0, 1.0), mode="economic", pivoting=True
    )
    subset = np.sort(piv[:rank])

    combos = []
    angle = layout.is_angle()
    null = np.zeros((len(norms), 0))
    if null_scaled.shape[1]:
        # Each combination led by a geometric parameter where possible: "theta_off[2] with a
        # change of X" reads better than a hand-eye component with several link parameters.
        sparse = sparse_basis(null_scaled, preference=np.where(hand_eye, 1e-2, 1.0))
        null = sparse / norms[:, None]  # back to parameter units
        null /= np.linalg.norm(null, axis=0)
        for v_scaled, v in zip(sparse.T, null.T, strict=True):
            idx = np.flatnonzero(np.abs(v_scaled) > 1e-6)
            reason = explain(v) if explain else "no effect on the measurements at these poses"
            combos.append(
                Combination(
                    names=tuple(layout.names[i] for i in idx),
                    coefficients=tuple((v[idx] / np.abs(v[idx]).max()).tolist()),
                    is_angle=tuple(bool(angle[i]) for i in idx),
                    reason=reason,
                )
            )
    return Identifiability(
        singular_values=s,
        column_norms=norms,
        rank=rank,
        rcond=rcond,
        identifiable=~involved,
        subset=subset,
        null_space=null,
        combinations=tuple(combos),
    )
