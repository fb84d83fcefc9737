"""Compiled batched forward kinematics (Numba), the fast path of :func:`relcal.robot.kinematics.fk`.

The NumPy implementation in :mod:`relcal.robot.kinematics` stays the reference; this module computes
the same product ``base A_1 ... A_n tool`` (DESIGN.md conventions, Hayati's beta, prismatic
joints) element by element, for millions of configurations per second on one core:

- configurations are processed in blocks; inside a block the running transform is kept as
  structure-of-arrays (12 rows of ``BLOCK`` values), so that each joint's update is a loop of
  plain arithmetic over configurations that the compiler vectorises;
- each joint is applied as its elementary factors (``Rz(theta) Tz(d) Tx(a) Rx(alpha) Ry(beta)``
  in DH, ``Rx(alpha) Ry(beta) Tx(a) Rz(theta) Tz(d)`` in MDH), each touching only the columns it
  mixes, instead of a general 4x4 product;
- sine and cosine come from one argument reduction and two short polynomials (:func:`sincos`),
  which vectorise where calls into the C library would not.

Compiled functions are cached on disk (``cache=True``): the first call in a fresh environment
compiles them (a few seconds); later processes load the cache. Importing this module imports
Numba (a few hundred milliseconds), so :mod:`kinematics` imports it only when it is used.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from relcal.robot.model import RobotModel

BLOCK = 128  # configurations per block: the working set (16 rows of BLOCK doubles) fits in L1

# Argument reduction by pi/2 in three parts (Cody and Waite), as in fdlibm: exact for |x| < 1e5.
_TWO_OVER_PI = 2.0 / np.pi
_PIO2_1 = 1.57079632673412561417e00
_PIO2_2 = 6.07710050650619224932e-11
_PIO2_3 = 2.02226624879595063154e-21
# Minimax polynomials on [-pi/4, pi/4] (Cephes sin.c): errors below 1 ulp.
_S1, _S2, _S3 = -1.66666666666666307295e-1, 8.33333333332211858878e-3, -1.98412698295895385996e-4
_S4, _S5, _S6 = 2.75573136213857245213e-6, -2.50507477628578072866e-8, 1.58962301576546568060e-10
_C1, _C2, _C3 = 4.16666666666665929218e-2, -1.38888888888730564116e-3, 2.48015872888517045348e-5
_C4, _C5, _C6 = -2.75573141792967388112e-7, 2.08757008419747316778e-9, -1.13585365213876817300e-11


@njit(cache=True, inline="always")
def sincos(x: float) -> tuple[float, float]:
    """``(sin x, cos x)`` to within 1 ulp for ``|x| < 1e5`` (joint angles are far inside)."""
    k = np.floor(x * _TWO_OVER_PI + 0.5)  # nearest multiple of pi/2
    r = ((x - k * _PIO2_1) - k * _PIO2_2) - k * _PIO2_3  # r in [-pi/4, pi/4]
    z = r * r
    s = r + r * z * (_S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))))
    c = 1.0 - 0.5 * z + z * z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6)))))
    quadrant = k - 4.0 * np.floor(k * 0.25)  # 0, 1, 2, 3 as a float: no integer conversion
    odd = (quadrant == 1.0) | (quadrant == 3.0)
    sin_x = c if odd else s
    cos_x = s if odd else c
    if quadrant >= 2.0:
        sin_x = -sin_x
    if (quadrant == 1.0) | (quadrant == 2.0):
        cos_x = -cos_x
    return sin_x, cos_x


@njit(cache=True)
def _sincos_array(x: np.ndarray, sin_out: np.ndarray, cos_out: np.ndarray) -> None:
    for i in range(x.size):
        sin_out[i], cos_out[i] = sincos(x[i])


@njit(cache=True)
def _fk_kernel(q, theta_off, d, a, ca, sa, cb, sb, prismatic, mdh, base, tool, out):
    """Write ``base A_1 ... A_n tool`` for each row of ``q`` into ``out`` ``(N, 4, 4)``.

    ``ca, sa, cb, sb`` are cos/sin of alpha and beta per joint; ``base`` and ``tool`` are the top
    three rows of the frames, flattened row by row (12 values).
    """
    n_conf, n = q.shape
    # Running transform: rows 0..2 of the rotation in t[0:3], t[4:7], t[8:11]; position t[3::4].
    t = np.empty((12, BLOCK))
    sin_t = np.empty(BLOCK)
    cos_t = np.empty(BLOCK)
    d_t = np.empty(BLOCK)
    theta_t = np.empty(BLOCK)
    for start in range(0, n_conf, BLOCK):
        m = min(BLOCK, n_conf - start)
        for k in range(12):
            for e in range(m):
                t[k, e] = base[k]
        for j in range(n):
            # Joint values first (a strided gather), then sine and cosine in a loop of its own,
            # which the compiler vectorises only when nothing else is in it.
            if prismatic[j]:
                for e in range(m):
                    theta_t[e] = theta_off[j]
                    d_t[e] = d[j] + q[start + e, j]
            else:
                for e in range(m):
                    theta_t[e] = theta_off[j] + q[start + e, j]
                    d_t[e] = d[j]
            for e in range(m):
                sin_t[e], cos_t[e] = sincos(theta_t[e])
            aj, caj, saj, cbj, sbj = a[j], ca[j], sa[j], cb[j], sb[j]
            has_beta = sbj != 0.0
            for e in range(m):
                s, c, dd = sin_t[e], cos_t[e], d_t[e]
                # Columns x, y, z of the rotation and the position, one row at a time.
                for row in range(3):
                    o = 4 * row
                    x, y, z, p = t[o, e], t[o + 1, e], t[o + 2, e], t[o + 3, e]
                    if mdh:  # Rx(alpha) Ry(beta) Tx(a) Rz(theta) Tz(d)
                        y, z = caj * y + saj * z, caj * z - saj * y
                        if has_beta:
                            x, z = cbj * x - sbj * z, sbj * x + cbj * z
                        p += aj * x
                        x, y = c * x + s * y, c * y - s * x
                        p += dd * z
                    else:  # Rz(theta) Tz(d) Tx(a) Rx(alpha) Ry(beta)
                        x, y = c * x + s * y, c * y - s * x
                        p += dd * z + aj * x
                        y, z = caj * y + saj * z, caj * z - saj * y
                        if has_beta:
                            x, z = cbj * x - sbj * z, sbj * x + cbj * z
                    t[o, e], t[o + 1, e], t[o + 2, e], t[o + 3, e] = x, y, z, p
        for e in range(m):
            pose = out[start + e]
            for row in range(3):
                o = 4 * row
                x, y, z, p = t[o, e], t[o + 1, e], t[o + 2, e], t[o + 3, e]
                for col in range(4):
                    pose[row, col] = x * tool[col] + y * tool[4 + col] + z * tool[8 + col]
                pose[row, 3] += p
            pose[3, 0], pose[3, 1], pose[3, 2], pose[3, 3] = 0.0, 0.0, 0.0, 1.0


def fk(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """Tool poses ``(N, 4, 4)`` for configurations ``q`` ``(N, n)``, same as the NumPy ``fk``."""
    q = np.ascontiguousarray(np.atleast_2d(np.asarray(q, dtype=np.float64)))
    if q.ndim != 2 or q.shape[1] != model.n_joints:
        raise ValueError(f"q must have shape (N, {model.n_joints}), got {q.shape}")
    out = np.empty((q.shape[0], 4, 4))

    def row_major(frame: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(frame[:3], dtype=np.float64).reshape(12)

    def per_joint(values: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(values, dtype=np.float64)

    _fk_kernel(
        q,
        per_joint(model.theta_off),
        per_joint(model.d),
        per_joint(model.a),
        per_joint(np.cos(model.alpha)),
        per_joint(np.sin(model.alpha)),
        per_joint(np.cos(model.beta)),
        per_joint(np.sin(model.beta)),
        np.ascontiguousarray(model.prismatic, dtype=np.bool_),
        model.convention == "mdh",
        row_major(model.base),
        row_major(model.tool),
        out,
    )
    return out


def sin_cos(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Elementwise ``(sin x, cos x)`` with the kernel's :func:`sincos` (for tests)."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    s, c = np.empty_like(x), np.empty_like(x)
    _sincos_array(x.reshape(-1), s.reshape(-1), c.reshape(-1))
    return s, c
