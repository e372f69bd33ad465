"""The control algebra of the linear (time-varying) models, written once: the sampled double
integrator, the reference's one-step defects on it, the discrete algebraic Riccati equation
(DARE) of the regulators and of the Kalman filter, and the LQR gain.

Every controller and the filter take these from here (a test keeps it so:
tests/test_single_home.py). Shapes are given per function; units SI (s, rad, rad/s, rad/s^2).

The sampled double integrator (zero-order hold, exact for a constant acceleration over the
period T): ``x+ = A x + B a`` with ``x = [q, v]``, ``A = [[1, T], [0, 1]]``,
``B = [T^2/2, T]`` (:func:`double_integrator`); the one-step defect of a sampled reference,
``c_k = x_r,k+1 - A x_r,k - B a_r,k`` (:func:`reference_defects`), is zero for a reference of
constant acceleration.

The regulator's DARE ``P = A'PA - A'PB (R + B'PB)^-1 B'PA + Q`` (paper eqs. 16-17) has two
solvers here, and each user keeps the one its numbers were made with (:func:`solve_dare`,
``method``):

* ``"doubling"``: the structure-preserving doubling algorithm (:func:`_doubling`: quadratically
  convergent, history-free, compiled by numba and cached on disk after the first call in a fresh
  environment), with ``scipy.linalg.solve_discrete_are`` as the fallback when it has not
  converged. Used by the linear MPC's terminal weight (:mod:`hydroarm.control.mpc`: a 2n x 2n
  DARE at every new horizon end, where the compiled doubling is the fast one).
* ``"scipy"``: ``scipy.linalg.solve_discrete_are`` alone (the Schur method).

The ID-MPCs' per-joint 2 x 2 DARE (:func:`joint_lqr`: solved at the ID-MPCs' construction and in
the bandwidth searches of :mod:`hydroarm.control.delay_design`) is the Riccati recursion in scalar
fixed-order arithmetic (:func:`joint_dare`; scipy's Schur method before 2026-12-05, whose last bits
followed the CPU's BLAS kernel).

The filter's DARE (its dual, for the steady-state prior covariance) is solved by fixed-point
iteration (:func:`filter_covariance`): the per-joint Kalman filter's design
(:mod:`hydroarm.control.filter_design`), whose defaults were measured with it. Its correction
(:func:`kalman_correction`: gain and posterior) and prediction (:func:`covariance_prediction`)
are scalar fixed-order arithmetic, used by the filter at run time too (NumPy's ``@`` and
``np.linalg.inv`` before 2026-12-05: their last bits followed the BLAS kernel).

Sign convention: ``K = (R + B' P B)^-1 B' P A`` and the LQR move is ``du = -K e``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import scipy.linalg

from hydroarm.config import ConfigError


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


DARE_METHODS = ("doubling", "scipy")
"""The regulator DARE's solvers (module docstring): the compiled doubling with scipy's fallback,
or scipy's alone."""


def solve_dare(
    A: np.ndarray,
    B: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    method: str = "doubling",
    tolerance: float = 1e-12,
    max_iterations: int = 60,
) -> tuple[np.ndarray, int, str]:
    """``(P (nx, nx), iterations, method_used)``: the stabilising solution of the DARE
    ``P = A'PA - A'PB (R + B'PB)^-1 B'PA + Q``, symmetric.

    ``method`` (:data:`DARE_METHODS`): ``"doubling"`` runs :func:`_doubling` until the relative
    change of P is below ``tolerance`` and falls back to ``scipy.linalg.solve_discrete_are`` when
    it has not converged within ``max_iterations`` (``method_used`` then ``"scipy"``);
    ``"scipy"`` calls scipy directly (``iterations`` 0). Which caller uses which: the module
    docstring. Shapes: A (nx, nx), B (nx, nu), Q (nx, nx) >= 0, R (nu, nu) > 0 or its diagonal
    (nu,). Needs (A, B) stabilisable and (A, Q^1/2) detectable.
    """
    if method not in DARE_METHODS:
        raise ValueError(f"method = {method!r}: must be one of {', '.join(DARE_METHODS)}")
    A = np.ascontiguousarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    Q = np.ascontiguousarray(Q, dtype=float)
    R = np.asarray(R, dtype=float)
    iterations = 0
    if method == "doubling":
        if R.ndim == 1:
            g_mat = (B / R) @ B.T
            R = np.diag(R)
        else:
            g_mat = B @ np.linalg.solve(R, B.T)
        P, iterations, converged = _doubling(A, np.ascontiguousarray(g_mat), Q, float(tolerance), int(max_iterations))
        if converged:
            return P, int(iterations), "doubling"
    elif R.ndim == 1:
        R = np.diag(R)
    P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    return 0.5 * (P + P.T), int(iterations), "scipy"


def riccati_solution(
    A: np.ndarray,
    B: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    tolerance: float = 1e-12,
    max_iterations: int = 60,
) -> tuple[np.ndarray, int, str]:
    """``(P, iterations, method)``: :func:`solve_riccati` without the gain (the doubling, scipy's
    fallback; :func:`solve_dare`). ``R`` may be given by its diagonal (nu,)."""
    return solve_dare(A, B, Q, R, "doubling", tolerance, max_iterations)


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
    (``method`` says which was used: ``"doubling"`` or ``"scipy"``; :func:`solve_dare`). Needs (A, B)
    stabilisable and (A, Q^1/2) detectable. Shapes: A (nx, nx), B (nx, nu),
    Q (nx, nx) >= 0, R (nu, nu) > 0.
    """
    P, iterations, method = riccati_solution(A, B, Q, R, tolerance, max_iterations)
    return RiccatiSolution(P=P, K=lqr_gain(A, B, R, P), iterations=iterations, method=method)


def double_integrator(period: float) -> tuple[np.ndarray, np.ndarray]:
    """``(A (2, 2), B (2,))`` of the exact zero-order-hold double integrator with period T (s)
    (module docstring)."""
    return np.array([[1.0, period], [0.0, 1.0]]), np.array([0.5 * period * period, period])


def double_integrator_step(q, v, acceleration, period: float):
    """``(q + T v + T^2/2 a, v + T a)``: one period of the double integrator (arrays of one shape)."""
    return q + period * v + 0.5 * period * period * acceleration, v + period * acceleration


def joint_lqr(period: float, q_position: float, q_velocity: float, r_acceleration: float):
    """``(P (2, 2), K (2,), G (2,))`` of one joint's double integrator: the DARE solution
    (:func:`joint_dare`), the LQR gain ``K = (R + B'PB)^-1 B'PA`` and ``G = (R + B'PB)^-1 B'``."""
    weights = (float(q_position), float(q_velocity), float(r_acceleration))
    p00, p01, p11, scale, k0, k1 = joint_dare(float(period), *weights)
    b0, b1 = 0.5 * period * period, period
    return np.array([[p00, p01], [p01, p11]]), np.array([k0, k1]), np.array([scale * b0, scale * b1])


@numba.njit(cache=True)
def joint_dare(period, q_position, q_velocity, r_acceleration):  # pragma: no cover - compiled
    """``(p00, p01, p11, s, k0, k1)``: one joint's DARE solution P (symmetric 2 x 2), ``s = (R +
    B'PB)^-1`` and ``K = s B'PA`` for ``A = [[1, T], [0, 1]]``, ``B = [T^2/2, T]``, ``Q =
    diag(q_position, q_velocity)``, ``R = r_acceleration``, by the Riccati recursion from P = Q in
    scalar fixed-order arithmetic until no entry changes by more than 4e-16 of the largest (at most
    10^7 steps; it converges at the closed loop's squared spectral radius per step; scipy's
    solution agrees to 1e-13 relative, a test). Not LAPACK's Schur method
    (scipy's, used before 2026-12-05): its last bits follow the CPU's BLAS kernel, and the GP in
    GP-IDMPC's loop amplifies them into another run."""
    t = period
    b0, b1 = 0.5 * t * t, t
    p00, p01, p11 = q_position, 0.0, q_velocity
    for _ in range(10_000_000):
        pb0 = p00 * b0 + p01 * b1  # P B
        pb1 = p01 * b0 + p11 * b1
        bpa1 = pb0 * t + pb1  # B'P A = [pb0, pb0 T + pb1]
        s = 1.0 / (r_acceleration + (b0 * pb0 + b1 * pb1))
        n00 = q_position + p00 - pb0 * s * pb0  # Q + A'PA - A'PB s B'PA
        n01 = p00 * t + p01 - pb0 * s * bpa1
        n11 = q_velocity + (p00 * t + p01) * t + p01 * t + p11 - bpa1 * s * bpa1
        tol = 4e-16 * max(abs(n00), abs(n01), abs(n11))
        converged = abs(n00 - p00) <= tol and abs(n01 - p01) <= tol and abs(n11 - p11) <= tol
        p00, p01, p11 = n00, n01, n11
        if converged:
            break
    pb0 = p00 * b0 + p01 * b1
    pb1 = p01 * b0 + p11 * b1
    s = 1.0 / (r_acceleration + (b0 * pb0 + b1 * pb1))
    return p00, p01, p11, s, s * pb0, s * (pb0 * t + pb1)


def reference_defects(q_r: np.ndarray, v_r: np.ndarray, a_r: np.ndarray, period: float) -> np.ndarray:
    """The one-step defects ``c_k = x_r,k+1 - A x_r,k - B a_r,k`` (..., N, n, 2) of a reference
    sampled at N + 1 instants T apart: ``q_r, v_r, a_r`` (..., N + 1, n), the sample axis
    second to last (``a_r``'s last sample is not used). ``c[..., 0]`` rad, ``c[..., 1]`` rad/s."""
    c = np.empty(q_r.shape[:-2] + (q_r.shape[-2] - 1, q_r.shape[-1], 2))
    half = 0.5 * period * period  # the scalar first, as B's T^2/2 (the same rounding as inline)
    c[..., 0] = q_r[..., 1:, :] - q_r[..., :-1, :] - period * v_r[..., :-1, :] - half * a_r[..., :-1, :]
    c[..., 1] = v_r[..., 1:, :] - v_r[..., :-1, :] - period * a_r[..., :-1, :]
    return c


@numba.njit(cache=True)
def unconstrained_move(e0, c, p_mats, gains, gs, period):  # pragma: no cover - compiled
    """The first move u_0 (n,) of every joint's unconstrained horizon problem: the LQR law plus a
    preview of the reference's defects (:mod:`hydroarm.control.idmpc`'s docstring).

    ``e0`` (n, 2): errors [q - q_r, v - v_r]; ``c`` (N, n, 2): the reference defects;
    ``p_mats`` (n, 2, 2), ``gains`` (n, 2), ``gs`` (n, 2) per joint."""
    horizon = c.shape[0]
    n = e0.shape[0]
    out = np.empty(n)
    for j in range(n):
        k0, k1 = gains[j, 0], gains[j, 1]
        # closed loop A - B K, with B = [T^2/2, T]
        b0, b1 = 0.5 * period * period, period
        a00, a01 = 1.0 - b0 * k0, period - b0 * k1
        a10, a11 = -b1 * k0, 1.0 - b1 * k1
        p00, p01, p11 = p_mats[j, 0, 0], p_mats[j, 0, 1], p_mats[j, 1, 1]
        s0 = 0.0
        s1 = 0.0
        for k in range(horizon - 1, 0, -1):  # s_k = (A - BK)' (P c_k + s_{k+1})
            r0 = p00 * c[k, j, 0] + p01 * c[k, j, 1] + s0
            r1 = p01 * c[k, j, 0] + p11 * c[k, j, 1] + s1
            s0 = a00 * r0 + a10 * r1
            s1 = a01 * r0 + a11 * r1
        r0 = p00 * c[0, j, 0] + p01 * c[0, j, 1] + s0
        r1 = p01 * c[0, j, 0] + p11 * c[0, j, 1] + s1
        out[j] = -(k0 * e0[j, 0] + k1 * e0[j, 1]) - (gs[j, 0] * r0 + gs[j, 1] * r1)
    return out


def kalman_correction(sigma: np.ndarray, measurement: np.ndarray, noise: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The Kalman gain ``L = Sigma C^T (C Sigma C^T + R)^-1`` (2, m) and the posterior covariance
    ``(I - L C) Sigma`` (2, 2, symmetric) of one joint's filter for the prior ``sigma`` (2, 2,
    symmetric), the measurement matrix C (``measurement``: ``[[1, 0]]``, position only, or I) and a
    diagonal noise covariance R (``noise``, (m, m)). Scalar arithmetic in a fixed order (the 2 x 2
    inverse in closed form): the same bits on any machine (``@`` and ``np.linalg.inv`` follow the
    CPU's BLAS kernel, and a closed loop amplifies their last bits: issue 32)."""
    s00, s01, s11 = float(sigma[0, 0]), float(sigma[0, 1]), float(sigma[1, 1])
    c_mat = np.atleast_2d(measurement)
    if np.any(noise - np.diag(np.diag(noise))) or not np.array_equal(c_mat, np.eye(c_mat.shape[0], 2)):
        raise ValueError(f"kalman_correction: C must be [[1, 0]] or I and R diagonal, got C = {c_mat.tolist()}")
    if c_mat.shape[0] == 1:  # position only
        innovation = s00 + float(noise[0, 0])
        l00, l10 = s00 / innovation, s01 / innovation
        posterior = _symmetric(s00 - l00 * s00, s01 - l00 * s01, s11 - l10 * s01)
        return np.array([[l00], [l10]]), posterior
    a, d = s00 + float(noise[0, 0]), s11 + float(noise[1, 1])
    det = a * d - s01 * s01
    l00, l01 = (s00 * d - s01 * s01) / det, (s01 * a - s00 * s01) / det
    l10, l11 = (s01 * d - s11 * s01) / det, (s11 * a - s01 * s01) / det
    posterior = _symmetric(s00 - (l00 * s00 + l01 * s01), s01 - (l00 * s01 + l01 * s11), s11 - (l10 * s01 + l11 * s11))
    return np.array([[l00, l01], [l10, l11]]), posterior


def covariance_prediction(posterior: np.ndarray, period: float, acceleration_variance: float) -> np.ndarray:
    """``A P A^T + sigma_a^2 B B^T`` (2, 2): the covariance ``posterior`` P (2, 2, symmetric)
    carried one period T (``period``, s) on the double integrator driven by white acceleration noise
    of variance ``acceleration_variance`` ((rad/s^2)^2); scalar fixed-order arithmetic (as
    :func:`kalman_correction`)."""
    p00, p01, p11 = float(posterior[0, 0]), float(posterior[0, 1]), float(posterior[1, 1])
    t = float(period)
    b0, b1 = 0.5 * t * t, t
    q = float(acceleration_variance)
    row = p01 + t * p11  # (A P)[0, 1]
    return _symmetric((p00 + t * p01) + t * row + q * b0 * b0, row + q * b0 * b1, p11 + q * b1 * b1)


def _symmetric(d00: float, d01: float, d11: float) -> np.ndarray:
    return np.array([[d00, d01], [d01, d11]])


def filter_covariance(
    period: float, measurement: np.ndarray, noise: np.ndarray, acceleration_variance: float,
    tolerance: float = 1e-13, max_iterations: int = 1_000_000,
) -> np.ndarray:  # fmt: skip
    """The steady-state prior covariance Sigma (2, 2) of a Kalman filter on the double integrator
    driven by white acceleration noise of variance ``acceleration_variance`` ((rad/s^2)^2), for
    the measurement matrix C (``measurement``, ``[[1, 0]]`` or I) and diagonal noise covariance R
    (``noise``, (m, m)): the filter's DARE by fixed-point iteration of
    ``Sigma = A (Sigma - Sigma C^T (C Sigma C^T + R)^-1 C Sigma) A^T + Q_w``, ``Q_w = sigma_a^2 B B^T``
    (:func:`kalman_correction`, :func:`covariance_prediction`: fixed order, the same bits on any
    machine; NumPy's products and inverse before 2026-12-05). Raises :class:`ConfigError` if it
    does not converge."""
    c_mat = np.atleast_2d(measurement)
    noise = np.atleast_2d(np.asarray(noise, dtype=float))
    sigma = covariance_prediction(np.zeros((2, 2)), period, acceleration_variance)
    for _ in range(max_iterations):
        updated = covariance_prediction(kalman_correction(sigma, c_mat, noise)[1], period, acceleration_variance)
        if np.all(np.abs(updated - sigma) <= tolerance * np.abs(updated)):
            return updated
        sigma = updated
    raise ConfigError(
        f"estimator: the Kalman covariance did not converge in {max_iterations} iterations "
        f"(R = {np.asarray(noise).tolist()!r}, acceleration_variance = {acceleration_variance!r})"
    )
