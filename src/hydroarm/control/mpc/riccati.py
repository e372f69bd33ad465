"""The terminal weight: the discrete algebraic Riccati equation (DARE, paper eqs. 16-17) and its LQR gain.

``P = A'PA - A'PB (R + B'PB)^-1 B'PA + Q`` is solved by the structure-preserving doubling
algorithm (:func:`_doubling`: quadratically convergent, history-free, compiled by numba and
cached on disk after the first call in a fresh environment), with
``scipy.linalg.solve_discrete_are`` as the fallback when the doubling has not converged.
Shapes: A (nx, nx), B (nx, nu), Q (nx, nx), R (nu, nu). Sign convention:
``K = (R + B' P B)^-1 B' P A`` and the LQR move is ``du = -K e``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import scipy.linalg


@dataclass(frozen=True)
class RiccatiSolution:
    """``P`` (nx, nx) of the DARE, its LQR gain ``K`` (nu, nx) (du = -K e), how it was found."""

    P: np.ndarray
    K: np.ndarray
    iterations: int
    method: str


@numba.njit(cache=True)
def _solve_two(w, b1, b2):  # pragma: no cover - compiled
    """Overwrite b1, b2 (nx, nx) with w^-1 b1, w^-1 b2; Gaussian elimination, partial pivoting.

    ``w`` (nx, nx) is destroyed. Hand-written so that numba need not compile
    ``np.linalg.solve`` (seconds of JIT time) for a 12 x 12 system.
    """
    n = w.shape[0]
    m = b1.shape[1]
    for col in range(n):
        piv = col
        for r in range(col + 1, n):
            if abs(w[r, col]) > abs(w[piv, col]):
                piv = r
        if piv != col:
            for c in range(n):
                w[col, c], w[piv, c] = w[piv, c], w[col, c]
            for c in range(m):
                b1[col, c], b1[piv, c] = b1[piv, c], b1[col, c]
                b2[col, c], b2[piv, c] = b2[piv, c], b2[col, c]
        for r in range(col + 1, n):
            f = w[r, col] / w[col, col]
            for c in range(col + 1, n):
                w[r, c] -= f * w[col, c]
            for c in range(m):
                b1[r, c] -= f * b1[col, c]
                b2[r, c] -= f * b2[col, c]
    for col in range(n - 1, -1, -1):
        for c in range(m):
            s1 = b1[col, c]
            s2 = b2[col, c]
            for k in range(col + 1, n):
                s1 -= w[col, k] * b1[k, c]
                s2 -= w[col, k] * b2[k, c]
            b1[col, c] = s1 / w[col, col]
            b2[col, c] = s2 / w[col, col]


@numba.njit(cache=True)
def _doubling(a_mat, g_mat, h_mat, tolerance, max_iterations):  # pragma: no cover - compiled
    """Structure-preserving doubling (SDA) for ``X = A'XA - A'XB (R + B'XB)^-1 B'XA + Q``.

    ``A_0 = A``, ``G_0 = B R^-1 B'``, ``H_0 = Q``; with ``W = I + G_k H_k``:
    ``A_{k+1} = A_k W^-1 A_k``, ``G_{k+1} = G_k + A_k W^-1 G_k A_k'``,
    ``H_{k+1} = H_k + A_k' H_k W^-1 A_k`` -> X quadratically (H_k equals 2^k
    Riccati iterations from X = 0). Stops when the largest entry of the
    update is below ``tolerance`` times the largest entry of H.
    Returns ``(X (nx, nx), iterations, converged)``.
    """
    nx = a_mat.shape[0]
    ak = a_mat.copy()
    gk = g_mat.copy()
    hk = h_mat.copy()
    w_a = np.empty((nx, nx))
    w_g = np.empty((nx, nx))
    for it in range(1, max_iterations + 1):
        w = np.dot(gk, hk)
        for i in range(nx):
            w[i, i] += 1.0
        w_a[:, :] = ak
        w_g[:, :] = gk
        _solve_two(w, w_a, w_g)
        a_t = np.ascontiguousarray(ak.T)
        step = np.dot(np.dot(a_t, hk), w_a)
        g_step = np.dot(np.dot(ak, w_g), a_t)
        ak = np.dot(ak, w_a)
        step_max = 0.0
        h_max = 0.0
        for i in range(nx):
            for j in range(nx):
                s = 0.5 * (step[i, j] + step[j, i])
                hk[i, j] += s
                gk[i, j] += 0.5 * (g_step[i, j] + g_step[j, i])
                step_max = max(step_max, abs(s))
                h_max = max(h_max, abs(hk[i, j]))
        if not np.isfinite(h_max):
            return hk, it, False
        if step_max <= tolerance * h_max:
            return hk, it, True
    return hk, max_iterations, False


def lqr_gain(A: np.ndarray, B: np.ndarray, R: np.ndarray, P: np.ndarray) -> np.ndarray:
    """``K = (R + B' P B)^-1 B' P A`` (nu, nx): the LQR move is ``du = -K e``."""
    bt_p = B.T @ P
    return np.linalg.solve(R + bt_p @ B, bt_p @ A)


def riccati_solution(
    A: np.ndarray,
    B: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    tolerance: float = 1e-12,
    max_iterations: int = 60,
) -> tuple[np.ndarray, int, str]:
    """``(P, iterations, method)``: :func:`solve_riccati` without the gain.

    ``R`` may be given by its diagonal (nu,).
    """
    A = np.ascontiguousarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    Q = np.ascontiguousarray(Q, dtype=float)
    R = np.asarray(R, dtype=float)
    if R.ndim == 1:
        g_mat = (B / R) @ B.T
        R = np.diag(R)
    else:
        g_mat = B @ np.linalg.solve(R, B.T)
    P, iterations, converged = _doubling(A, np.ascontiguousarray(g_mat), Q, float(tolerance), int(max_iterations))
    if converged:
        return P, int(iterations), "doubling"
    P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    return 0.5 * (P + P.T), int(iterations), "scipy"


def solve_riccati(
    A: np.ndarray,
    B: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    tolerance: float = 1e-12,
    max_iterations: int = 60,
) -> RiccatiSolution:
    """Stabilising solution of the DARE ``P = A'PA - A'PB (R + B'PB)^-1 B'PA + Q`` and K.

    Structure-preserving doubling (:func:`_doubling`, compiled by numba), stopping when
    the relative change of P is below ``tolerance``; ``scipy.linalg.solve_discrete_are``
    is the fallback when the doubling has not converged within ``max_iterations``
    (``method`` says which was used: ``"doubling"`` or ``"scipy"``). Needs (A, B)
    stabilisable and (A, Q^1/2) detectable. Shapes: A (nx, nx), B (nx, nu),
    Q (nx, nx) >= 0, R (nu, nu) > 0.
    """
    P, iterations, method = riccati_solution(A, B, Q, R, tolerance, max_iterations)
    return RiccatiSolution(P=P, K=lqr_gain(A, B, R, P), iterations=iterations, method=method)
