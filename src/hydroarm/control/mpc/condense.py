"""Condensing: the MPC over the horizon as one QP in the stacked input moves.

The error dynamics ``e_{i+1} = A_i e_i + B_i du_i + c_i`` (i < N) and the cost
``sum_{i<N} e_i' Q e_i + du_i' R du_i + e_N' P e_N`` become ``min 1/2 dU' H dU + g' dU``
in dU = [du_0; ...; du_{N-1}] (N nu,), the QP objective equal to the MPC cost minus the
constant terms (:class:`CondensedQP`). :func:`condense` runs compiled (numba, skipping the
block-triangular zeros) when Q and R are given by their diagonals; :func:`condense_numpy`
is its plain-NumPy twin, equal up to rounding, and documents the algebra.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np


@dataclass(frozen=True)
class CondensedQP:
    """The condensed MPC problem in dU = [du_0; ...; du_{N-1}] (N nu,).

    ``cost(dU) = 1/2 dU' H dU + g' dU + constant`` equals the MPC cost
    ``sum_{i<N} e_i'Q e_i + du_i'R du_i + e_N'P e_N``. ``H`` (N nu, N nu), ``g``
    (N nu,). Predicted errors: ``e_{i+1} = prediction[i] @ dU + free[i + 1]``
    with ``prediction`` (N, nx, N nu) and the free response ``free`` (N + 1, nx)
    (``free[0] = e_0``); ``terminal_map = prediction[-1]``.
    """

    H: np.ndarray
    g: np.ndarray
    prediction: np.ndarray
    free: np.ndarray

    @property
    def terminal_map(self) -> np.ndarray:
        return self.prediction[-1]

    @property
    def terminal_free(self) -> np.ndarray:
        return self.free[-1]

    def terminal_error(self, du: np.ndarray) -> np.ndarray:
        """Predicted e_N (nx,) for moves dU (N nu,)."""
        return self.prediction[-1] @ du + self.free[-1]


@numba.njit(cache=True)
def _condense_kernel(A, B, c, q_diag, r_diag, P, e0):  # pragma: no cover - compiled
    """Compiled :func:`condense_numpy` for diagonal Q and R: ``(H, g, work)``.

    The same recursion and products, skipping the structural zeros: block row i
    of the prediction matrix is nonzero in column blocks 0..i only, so the
    recursion and ``G' Qbar [G | w]`` touch ~half the entries, and only the upper
    triangle of the symmetric ``H = 2 (G' Qbar G + Rbar)`` is summed (then
    mirrored). ``work[i] = [G_i | w_{i+1}]`` as in :func:`condense_numpy`.
    """
    horizon, nx, nu = B.shape
    m = horizon * nu
    work = np.zeros((horizon, nx, m + 1))
    for r in range(nx):
        s = 0.0
        for k in range(nx):
            s += A[0, r, k] * e0[k]
        work[0, r, m] = c[0, r] + s
        for u in range(nu):
            work[0, r, u] = B[0, r, u]
    for i in range(1, horizon):
        prev = work[i - 1]
        cur = work[i]
        width = i * nu  # nonzero columns of the previous block row
        for r in range(nx):
            for k in range(nx):
                a_rk = A[i, r, k]
                for col in range(width):
                    cur[r, col] += a_rk * prev[k, col]
            s = 0.0
            for k in range(nx):
                s += A[i, r, k] * prev[k, m]
            cur[r, m] = c[i, r] + s
            for u in range(nu):
                cur[r, width + u] = B[i, r, u]
    weighted = np.empty((horizon, nx, m + 1))
    for i in range(horizon - 1):
        for r in range(nx):
            for col in range(m + 1):
                weighted[i, r, col] = q_diag[r] * work[i, r, col]
    last = horizon - 1
    for r in range(nx):
        for col in range(m + 1):
            weighted[last, r, col] = 0.0
        for k in range(nx):
            p_rk = P[r, k]
            for col in range(m + 1):
                weighted[last, r, col] += p_rk * work[last, k, col]
    upper = np.zeros((m, m))
    linear = np.zeros(m)
    for i in range(horizon):
        width = (i + 1) * nu
        for r in range(nx):
            row = work[i, r]
            wrow = weighted[i, r]
            for a in range(width):
                coefficient = row[a]
                if coefficient == 0.0:
                    continue
                for b in range(a, width):
                    upper[a, b] += coefficient * wrow[b]
                linear[a] += coefficient * wrow[m]
    hessian = np.empty((m, m))
    for a in range(m):
        hessian[a, a] = 2.0 * upper[a, a] + 2.0 * r_diag[a % nu]
        for b in range(a + 1, m):
            value = 2.0 * upper[a, b]
            hessian[a, b] = value
            hessian[b, a] = value
    return hessian, 2.0 * linear, work


def condense(
    A: np.ndarray,
    B: np.ndarray,
    c: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    P: np.ndarray,
    e0: np.ndarray,
) -> CondensedQP:
    """Condense ``e_{i+1} = A_i e_i + B_i du_i + c_i`` (i < N) into a QP in dU.

    The algebra of :func:`condense_numpy` (which documents it); with Q and R
    given by their diagonals it runs compiled (:func:`_condense_kernel`, equal to
    :func:`condense_numpy` up to rounding), otherwise :func:`condense_numpy`.
    """
    Q = np.asarray(Q, dtype=float)
    R = np.asarray(R, dtype=float)
    if Q.ndim != 1 or R.ndim != 1:
        return condense_numpy(A, B, c, Q, R, P, e0)
    A = np.ascontiguousarray(A, dtype=float)
    B = np.ascontiguousarray(B, dtype=float)
    c = np.ascontiguousarray(c, dtype=float)
    hessian, linear, work = _condense_kernel(
        A, B, c, np.ascontiguousarray(Q), np.ascontiguousarray(R),
        np.ascontiguousarray(P, dtype=float), np.ascontiguousarray(e0, dtype=float),
    )  # fmt: skip
    horizon, nx, nu = B.shape
    m = horizon * nu
    free = np.empty((horizon + 1, nx))
    free[0] = e0
    free[1:] = work[:, :, m]
    return CondensedQP(H=hessian, g=linear, prediction=work[:, :, :m], free=free)


def condense_numpy(
    A: np.ndarray,
    B: np.ndarray,
    c: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    P: np.ndarray,
    e0: np.ndarray,
) -> CondensedQP:
    """Condense ``e_{i+1} = A_i e_i + B_i du_i + c_i`` (i < N) into a QP in dU.

    A (N, nx, nx), B (N, nx, nu), c (N, nx), e0 (nx,), P (nx, nx); Q (nx, nx)
    and R (nu, nu), or their diagonals (nx,) and (nu,). Builds the prediction
    matrix row by row (``G_i = A_i G_{i-1}`` plus B_i in block i; the free
    response rides along as one extra column), then ``H = 2 (G' Qbar G + Rbar)``
    and ``g = 2 G' Qbar w`` with one (N nu) x (N nx) x (N nu + 1) product:
    N - 1 small products in the loop, none per block.
    """
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    Q = np.asarray(Q, dtype=float)
    R = np.asarray(R, dtype=float)
    horizon, nx, nu = B.shape
    m = horizon * nu
    # work[i] = [G_i | w_{i+1}]: the block row of e_{i+1} and its free response.
    work = np.zeros((horizon, nx, m + 1))
    index = np.arange(horizon)
    work[:, :, :m].reshape(horizon, nx, horizon, nu)[index, :, index, :] = B
    work[:, :, m] = c
    work[0, :, m] += A[0] @ e0
    for i in range(1, horizon):
        work[i] += A[i] @ work[i - 1]
    weighted = np.empty_like(work)
    if Q.ndim == 1:
        np.multiply(work[:-1], Q[:, None], out=weighted[:-1])
    else:
        np.matmul(Q, work[:-1], out=weighted[:-1])
    np.matmul(P, work[-1], out=weighted[-1])
    prediction = work[:, :, :m]
    hg = prediction.reshape(horizon * nx, m).T @ weighted.reshape(horizon * nx, m + 1)
    hessian = hg[:, :m]
    hessian = hessian + hessian.T  # = 2 G' Qbar G, exactly symmetric
    if R.ndim == 1:
        hessian.ravel()[:: m + 1] += np.tile(2.0 * R, horizon)  # a view: hessian is a new array
    else:
        hessian += np.kron(np.eye(horizon), R + R.T)
    free = np.empty((horizon + 1, nx))
    free[0] = e0
    free[1:] = work[:, :, m]
    return CondensedQP(H=hessian, g=2.0 * hg[:, m], prediction=prediction, free=free)
