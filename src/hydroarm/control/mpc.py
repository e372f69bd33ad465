"""Linear time-varying MPC about the reference (paper Section 3.2, eqs. 13-18; SPEC section 5).

The method, in the error e = x - x_r of the state x = [q, v] (2n,) and the input
deviation du = u - u_r (n,):

* Nominal model: the dry rigid body plus an optional joint-acceleration
  feed-forward d (n,) (the GP-MPC puts its learned disturbance there):
  ``x' = f(x, u) = [v, ABA(q, v, u) + d]``, discretised by explicit Euler with the
  control period T: ``x_{k+1} = x_k + T f(x_k, u_k)``.
* Linearisation at every reference sample j (time j T) with Pinocchio's
  analytical ABA derivatives: ``A_j = I + T df/dx``, ``B_j = T df/du``, at
  (x_r,j, u_r,j) with ``u_r,j = RNEA(q_r, v_r, a_r)`` (nominal inverse dynamics).
  The affine term ``c_j = x_r,j + T f(x_r,j, u_r,j) - x_r,j+1 (+ T [0; d])``
  makes ``e_{j+1} = A_j e_j + B_j du_j + c_j`` exact to first order.
  Linearisations depend on the reference only, so they are cached by the
  integer time index ``j = round(t / T)`` in a sliding window of indices
  k .. k + N; as the horizon slides each step computes one new one (a jump in
  t or a new reference object rebuilds the window).
* Cost ``sum_{i<N} e_i' Q e_i + du_i' R du_i + e_N' P e_N``, Q = diag(q_position,
  q_velocity), R = diag(r), P the solution of the discrete algebraic Riccati
  equation (DARE, paper eqs. 16-17) at the horizon-end linearisation (index
  k + N), computed once per index by the structure-preserving doubling
  algorithm (:func:`solve_riccati`; ~10 iterations, quadratically convergent,
  history-free, compiled by numba: ~0.06 ms against ~1.2 ms for scipy's
  ``solve_discrete_are``, which is the fallback). The first call in a fresh
  environment JIT-compiles it (~7 s, then cached on disk like hydroarm.model.water).
* Condensed QP in the stacked moves dU (N n,): ``min 1/2 dU' H dU + g' dU``
  subject to ``-u_max - u_r <= dU <= u_max - u_r`` (:func:`condense`); the QP
  objective equals the MPC cost minus the constant terms. The condensing runs
  compiled (numba, skipping the block-triangular zeros: ~70 us against
  ~110 us for the NumPy :func:`condense_reference` at N = 10, equal to rounding),
  and so does the fill of A_j, B_j from ABA's derivatives (bit-identical to
  :func:`_linearise_into_reference`). Solved by DAQP (dense
  active set, warm-started from the shifted previous plan) by default; OSQP,
  quadprog and Clarabel are selectable (``MPCConfig.solver``; see
  ``bench/mpc_solvers.py`` for the measurement behind the default).
* Terminal set (paper: ``e_N' P e_N <= alpha``) is infeasible at start-up of the
  paper task, so it is off by default. ``terminal_set="soft"`` adds it with a
  slack s >= 0 penalised linearly (``terminal_slack_penalty * s``), a convex
  second-order-cone program solved by Clarabel (exact, no polytope
  approximation) whatever ``solver`` says (clarabel is then required);
  ``"hard"`` tries the hard constraint first and falls back to soft
  (``status="terminal_soft_fallback"``) when Clarabel does not solve it
  (at start-up: primal infeasible). The penalty trades enforcement against
  violence. Measured from rest on the paper task over 3 s (E_p in rad^2,
  joints 1 and 4; terminal cost only: dry 0.88 / 0.026, underwater 2.45 / 0.040):
  rho_s = 1e4 makes the first moves bang-bang on the light wrist and the loop
  diverges even on the dry model (the linearisation about the reference is
  then meaningless); 1e3: dry 0.32 / 0.59, underwater 0.43 / 0.95; the default
  300: dry 0.29 / 0.18, underwater 0.50 / 0.64, and the penalty is exact
  (slack 0) starting on the reference and in steady dry tracking; 100: the
  slack stays ~1e-3 where the set is reachable; 1 barely enforces the set.
  Clarabel's reduced-accuracy "AlmostSolved" is accepted (the moves are still
  checked against the box).
* Failures: a solver that does not report an optimal solution (or returns
  non-finite or out-of-bounds moves) triggers, in order, the shifted previous
  plan (``status="qp_failed_shift"``), the saturated LQR law
  ``u = u_r - K e`` (``status="qp_failed_lqr"``) and, if the gain cannot be
  computed, the saturated reference torque (``status="qp_failed_reference"``);
  each failure is a fault event (``ControlOutput.events``). The returned torque is always
  clipped to the limits as a last guard (counted in ``LinearMPC.clip_count``).

Sign convention: ``K = (R + B' P B)^-1 B' P A`` and the LQR move is ``du = -K e``.
Units: SI (rad, rad/s, N m, s).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Annotated, Literal

import daqp
import numba
import numpy as np
import pydantic
import scipy.linalg

from hydroarm.config import ConfigError, FrozenModel, per_joint
from hydroarm.control.interface import ControlOutput, Reference, require_period
from hydroarm.model.arm import Arm
from hydroarm.model.nominal import NominalModel

SOLVERS = ("daqp", "osqp", "quadprog", "clarabel")

PositiveFloat = Annotated[float, pydantic.Field(gt=0.0)]
NonNegativeFloat = Annotated[float, pydantic.Field(ge=0.0)]
PositiveList = Annotated[list[PositiveFloat], pydantic.Field(min_length=1, max_length=12)]
NonNegativeList = Annotated[list[NonNegativeFloat], pydantic.Field(min_length=1, max_length=12)]

CLIP_TOLERANCE = 1e-9
"""Relative excess over the torque limit above which the last-guard clip is counted."""


class MPCConfig(FrozenModel):
    """Settings of :class:`LinearMPC`. Per-joint fields take one value or a list of n.

    Defaults are the paper's (Section 4) where it gives them: Q = diag(300 x n,
    0.01 x n), R = 0.1 I, |u| <= 500 N m (the paper arm's limit, read from the
    arm file when ``torque_limit`` is None); N = 10 and T = 10 ms are SPEC's
    choices (the paper gives neither). ``discretisation`` departs from the
    paper's Euler step by default: the second-order Taylor step (the held torque
    also moves the position within the step) has the same nominal E_p but keeps
    the light wrist stable on a plant up to about 27 % lighter than the model, where
    Euler's gains diverge at 11 % (docs/deviations.md, docs/robustness.md).
    """

    horizon: int = pydantic.Field(10, ge=1, le=200, description="prediction horizon N (steps)")
    q_position: PositiveFloat | PositiveList = pydantic.Field(
        300.0, description="Q weight on joint position error (1/rad^2)"
    )
    q_velocity: NonNegativeFloat | NonNegativeList = pydantic.Field(
        0.01, description="Q weight on joint velocity error (s^2/rad^2)"
    )
    r: PositiveFloat | PositiveList = pydantic.Field(
        0.1, description="R weight on the torque deviation u - u_r (1/(N m)^2)"
    )
    torque_limit: PositiveFloat | PositiveList | None = pydantic.Field(
        None, description="|u_i| <= limit (N m); None = the arm's"
    )
    terminal_set: Literal["off", "soft", "hard"] = "off"
    terminal_alpha: float = pydantic.Field(1e-3, gt=0.0, description="terminal set level alpha")
    terminal_slack_penalty: float = pydantic.Field(
        300.0, gt=0.0, le=1e12, description="linear penalty rho_s on the terminal slack"
    )
    solver: Literal["daqp", "osqp", "quadprog", "clarabel"] = "daqp"
    discretisation: Literal["euler", "taylor2"] = pydantic.Field(
        "taylor2",
        description="prediction model: second-order Taylor (ZOH-consistent, default) or explicit Euler (paper)",
    )
    riccati_tolerance: float = pydantic.Field(
        1e-12, gt=0.0, le=1e-3, description="doubling stops when the relative change of P is below"
    )
    riccati_max_iterations: int = pydantic.Field(
        60, ge=1, le=1000, description="cap on doubling iterations (then scipy's DARE)"
    )

    @pydantic.model_validator(mode="after")
    def _check_ranges(self) -> MPCConfig:
        """Weights within [1e-6, 1e8] (q_velocity from 0), r within [1e-6, 1e6], torque_limit
        <= 1e12 N m: beyond these the Riccati equation and the QP lose all precision."""
        from hydroarm.config import field_error

        for name, low, high in (("q_position", 1e-6, 1e8), ("q_velocity", 0.0, 1e8), ("r", 1e-6, 1e6),
                                ("torque_limit", 0.0, 1e12)):  # fmt: skip
            value = getattr(self, name)
            for k, entry in enumerate(value if isinstance(value, list) else [value]):
                if entry is not None and not low <= entry <= high:
                    where = f"{name}.{k}" if isinstance(value, list) else name
                    raise field_error(where, entry, f"must be >= {low:g} and <= {high:g}")
        return self


# --------------------------------------------------------------------------------------
# Riccati
# --------------------------------------------------------------------------------------
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
    P, iterations, converged = _doubling(
        A, np.ascontiguousarray(g_mat), Q, float(tolerance), int(max_iterations)
    )
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

    Structure-preserving doubling (:func:`_doubling`, compiled by numba): about
    10 iterations for the paper arm at T = 10 ms (closed-loop spectral radius
    ~0.96), ~0.06 ms, against ~1.2 ms for ``scipy.linalg.solve_discrete_are``,
    which is the fallback when the doubling has not converged within
    ``max_iterations`` (``method`` says which was used). Needs (A, B)
    stabilisable and (A, Q^1/2) detectable. Shapes: A (nx, nx), B (nx, nu),
    Q (nx, nx) >= 0, R (nu, nu) > 0.
    """
    P, iterations, method = riccati_solution(A, B, Q, R, tolerance, max_iterations)
    return RiccatiSolution(P=P, K=lqr_gain(A, B, R, P), iterations=iterations, method=method)


# --------------------------------------------------------------------------------------
# Condensing
# --------------------------------------------------------------------------------------
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
    """Compiled :func:`condense_reference` for diagonal Q and R: ``(H, g, work)``.

    The same recursion and products, skipping the structural zeros: block row i
    of the prediction matrix is nonzero in column blocks 0..i only, so the
    recursion and ``G' Qbar [G | w]`` touch ~half the entries, and only the upper
    triangle of the symmetric ``H = 2 (G' Qbar G + Rbar)`` is summed (then
    mirrored). ``work[i] = [G_i | w_{i+1}]`` as in the reference.
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

    The algebra of :func:`condense_reference` (which documents it); with Q and R
    given by their diagonals it runs compiled (:func:`_condense_kernel`, equal to
    the reference up to rounding, ~4x faster at N = 10), otherwise the reference.
    """
    Q = np.asarray(Q, dtype=float)
    R = np.asarray(R, dtype=float)
    if Q.ndim != 1 or R.ndim != 1:
        return condense_reference(A, B, c, Q, R, P, e0)
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


def condense_reference(
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


# --------------------------------------------------------------------------------------
# Box-constrained QP solvers: min 1/2 x'Hx + g'x  s.t.  lb <= x <= ub
# --------------------------------------------------------------------------------------
QP_STATUSES = ("solved", "iteration_limit", "infeasible", "failed")
"""What a box-QP solve ended with, read from each solver's own status codes."""


@dataclass(frozen=True)
class QPResult:
    """``x`` (m,) or None; ``status``, one of :data:`QP_STATUSES` (``"solved"``: the solver
    reported an optimal solution); ``message``: the solver's own words, for people."""

    x: np.ndarray | None
    status: str
    message: str

    def __post_init__(self) -> None:
        if self.status not in QP_STATUSES:
            raise ValueError(f"status = {self.status!r}: must be one of {', '.join(QP_STATUSES)}")

    @property
    def ok(self) -> bool:
        return self.status == "solved"


def _crossed_bounds(lb: np.ndarray, ub: np.ndarray) -> QPResult | None:
    """An ``"infeasible"`` result if some ``lb_i > ub_i`` (checked before any solver runs:
    OSQP's update would refuse such data silently and return the previous solution)."""
    if (lb <= ub).all():  # every step of the MPC: the cheap test first
        return None
    i = int(np.flatnonzero(~(lb <= ub))[0])
    return QPResult(None, "infeasible", f"lb[{i}] = {lb[i]:g} > ub[{i}] = {ub[i]:g}")


_DAQP_STATUS = {1: "solved", -4: "iteration_limit", -1: "infeasible"}
"""DAQP exit flags (1 optimal, -1 primal infeasible, -4 iteration limit); others: failed."""


class DaqpBoxSolver:
    """DAQP (dense dual active set); simple bounds; warm start from ``x0`` (its active set).

    At most ``iteration_factor * m`` active-set iterations (an active set changes
    one constraint per iteration; an ill-conditioned H, e.g. r = 1e-6 with
    N = 50, can otherwise cycle to DAQP's default 10^4 iterations, ~1 s).
    """

    name = "daqp"

    def __init__(self, iteration_factor: int = 10) -> None:
        self.iteration_factor = iteration_factor
        self._empty: np.ndarray | None = None
        self._sense: np.ndarray | None = None

    def solve(self, H, g, lb, ub, x0=None) -> QPResult:
        crossed = _crossed_bounds(lb, ub)
        if crossed is not None:
            return crossed
        m = g.shape[0]
        if self._empty is None or self._empty.shape[1] != m:
            self._empty = np.zeros((0, m))
            self._sense = np.zeros(m, dtype=np.int32)
        x, _, flag, info = daqp.solve(
            H, g, self._empty, ub, lb, self._sense, primal_start=x0,
            iter_limit=self.iteration_factor * m,
        )  # fmt: skip
        message = f"daqp exitflag {flag}, {info['iterations']} iterations"
        return QPResult(np.asarray(x), _DAQP_STATUS.get(int(flag), "failed"), message)


class OsqpBoxSolver:
    """OSQP (sparse ADMM), set up once and updated per call, warm-started from ``x0``.

    Tight tolerances (``tolerance`` for eps_abs and eps_rel). No polishing by
    default: OSQP 1.1 prints a line on stdout at every polish that finds no
    active set, whatever ``verbose`` says.
    """

    name = "osqp"

    def __init__(
        self, tolerance: float = 1e-10, max_iterations: int = 50000, polishing: bool = False
    ) -> None:
        self.tolerance = tolerance
        self.max_iterations = max_iterations
        self.polishing = polishing
        self._solver = None
        self._size = -1

    def solve(self, H, g, lb, ub, x0=None) -> QPResult:
        import osqp
        import scipy.sparse as sp

        crossed = _crossed_bounds(lb, ub)
        if crossed is not None:
            return crossed
        m = g.shape[0]
        if self._solver is None or self._size != m:
            rows, cols = np.triu_indices(m)
            order = np.lexsort((rows, cols))  # CSC order: by column, then row
            self._rows, self._cols, self._size = rows[order], cols[order], m
            indptr = np.concatenate([[0], np.cumsum(np.arange(1, m + 1))])
            hessian = sp.csc_matrix((H[self._rows, self._cols], self._rows, indptr), shape=(m, m))
            solver = osqp.OSQP()
            solver.setup(
                hessian, g, sp.identity(m, format="csc"), lb, ub, verbose=False,
                eps_abs=self.tolerance, eps_rel=self.tolerance, max_iter=self.max_iterations,
                polishing=self.polishing, warm_starting=True,
            )  # fmt: skip
            self._solver = solver
        else:
            self._solver.update(Px=H[self._rows, self._cols], q=g, l=lb, u=ub)
        if x0 is not None:
            self._solver.warm_start(x=x0)
        result = self._solver.solve(raise_error=False)
        return QPResult(np.asarray(result.x), _osqp_status(result.info.status_val), f"osqp {result.info.status}")


def _osqp_status(value: int) -> str:
    """Our status of an OSQP ``status_val`` (its ``SolverStatus`` constants)."""
    import osqp

    codes = osqp.SolverStatus
    if value == codes.OSQP_SOLVED:
        return "solved"
    if value in (codes.OSQP_MAX_ITER_REACHED, codes.OSQP_TIME_LIMIT_REACHED):
        return "iteration_limit"
    if value in (codes.OSQP_PRIMAL_INFEASIBLE, codes.OSQP_PRIMAL_INFEASIBLE_INACCURATE):
        return "infeasible"
    return "failed"


class QuadprogBoxSolver:
    """quadprog (Goldfarb-Idnani dual active set, dense); no warm start."""

    name = "quadprog"

    def solve(self, H, g, lb, ub, x0=None) -> QPResult:
        import quadprog

        crossed = _crossed_bounds(lb, ub)
        if crossed is not None:
            return crossed
        m = g.shape[0]
        constraints = np.hstack([np.eye(m), -np.eye(m)])
        try:
            x = quadprog.solve_qp(H, -g, constraints, np.concatenate([lb, -ub]), 0)[0]
        except ValueError as error:  # quadprog reports only by exception text
            status = "infeasible" if "inconsistent" in str(error) else "failed"
            return QPResult(None, status, f"quadprog {error}")
        return QPResult(np.asarray(x), "solved", "quadprog optimal")


class ClarabelBoxSolver:
    """Clarabel (interior point, conic) on the box QP; a fresh solver per call."""

    name = "clarabel"

    def solve(self, H, g, lb, ub, x0=None) -> QPResult:
        import clarabel
        import scipy.sparse as sp

        crossed = _crossed_bounds(lb, ub)
        if crossed is not None:
            return crossed
        m = g.shape[0]
        eye = sp.identity(m, format="csc")
        constraints = sp.vstack([eye, -eye], format="csc")
        solver = clarabel.DefaultSolver(
            sp.triu(sp.csc_matrix(H), format="csc"), g, constraints,
            np.concatenate([ub, -lb]), [clarabel.NonnegativeConeT(2 * m)], _clarabel_settings(),
        )  # fmt: skip
        solution = solver.solve()
        return QPResult(np.asarray(solution.x), _clarabel_status(solution), f"clarabel {solution.status}")


def _clarabel_settings():
    import clarabel

    settings = clarabel.DefaultSettings()
    settings.verbose = False
    settings.tol_gap_abs = settings.tol_gap_rel = settings.tol_feas = 1e-8
    settings.max_threads = 1
    return settings


def _clarabel_status(solution) -> str:
    """Our status of a Clarabel solution: solved also to its reduced accuracy
    (AlmostSolved, gap ~5e-5)."""
    import clarabel

    codes = clarabel.SolverStatus
    if solution.status in (codes.Solved, codes.AlmostSolved):
        return "solved"
    if solution.status in (codes.MaxIterations, codes.MaxTime):
        return "iteration_limit"
    if solution.status in (codes.PrimalInfeasible, codes.AlmostPrimalInfeasible):
        return "infeasible"
    return "failed"


def make_box_qp_solver(name: str):
    """A box-QP solver by name (``SOLVERS``); all have ``solve(H, g, lb, ub, x0) -> QPResult``."""
    solvers = {
        "daqp": DaqpBoxSolver,
        "osqp": OsqpBoxSolver,
        "quadprog": QuadprogBoxSolver,
        "clarabel": ClarabelBoxSolver,
    }
    if name not in solvers:
        raise ConfigError(f"solver = {name!r}: must be one of {', '.join(SOLVERS)}")
    return solvers[name]()


def solve_terminal_qp(
    qp: CondensedQP,
    lb: np.ndarray,
    ub: np.ndarray,
    P: np.ndarray,
    alpha: float,
    slack_penalty: float | None,
) -> tuple[QPResult, float]:
    """The box QP plus the terminal set ``e_N' P e_N <= alpha (+ s)``, by Clarabel.

    Hard (``slack_penalty`` None): variables dU. Soft: variables [dU, s], s >= 0,
    cost + ``slack_penalty * s``. The quadratic constraint is the second-order
    cone ``||(alpha + s - 1, 2 L' e_N)|| <= alpha + s + 1`` with ``P = L L'``.
    Returns ``(QPResult over dU, slack)`` (slack 0 for the hard problem).
    """
    import clarabel
    import scipy.sparse as sp

    m = qp.g.shape[0]
    soft = slack_penalty is not None
    size = m + (1 if soft else 0)
    eigval, eigvec = np.linalg.eigh(0.5 * (P + P.T))
    root_t = np.sqrt(np.clip(eigval, 0.0, None))[:, None] * eigvec.T  # L' with L L' = P
    nx = P.shape[0]
    hessian = np.zeros((size, size))
    hessian[:m, :m] = qp.H
    linear = np.zeros(size)
    linear[:m] = qp.g
    box = np.zeros((2 * m + (1 if soft else 0), size))
    box[:m, :m] = np.eye(m)
    box[m : 2 * m, :m] = -np.eye(m)
    box_rhs = np.concatenate([ub, -lb, [0.0] if soft else []])
    if soft:
        linear[m] = slack_penalty
        box[2 * m, m] = -1.0
    # ||u||^2 <= z (u = L' e_N, z = alpha + s) as the second-order cone
    # ||(2 u / sqrt(g), z / g - 1)|| <= z / g + 1, scaled by g ~ the size of z so
    # that the cone is well conditioned when z >> 1 (start-up: z ~ 1e5).
    free = root_t @ qp.terminal_free
    scale = max(alpha, float(free @ free))
    cone = np.zeros((nx + 2, size))
    cone_rhs = np.empty(nx + 2)
    cone_rhs[0], cone_rhs[1] = alpha / scale + 1.0, alpha / scale - 1.0
    if soft:
        cone[0, m] = cone[1, m] = -1.0 / scale
    cone[2:, :m] = -2.0 / math.sqrt(scale) * root_t @ qp.terminal_map
    cone_rhs[2:] = 2.0 / math.sqrt(scale) * free
    solver = clarabel.DefaultSolver(
        sp.triu(sp.csc_matrix(hessian), format="csc"), linear,
        sp.csc_matrix(np.vstack([box, cone])), np.concatenate([box_rhs, cone_rhs]),
        [clarabel.NonnegativeConeT(box.shape[0]), clarabel.SecondOrderConeT(nx + 2)],
        _clarabel_settings(),
    )  # fmt: skip
    solution = solver.solve()
    status = _clarabel_status(solution)
    x = np.asarray(solution.x)
    slack = float(max(x[m], 0.0)) if soft and status == "solved" else 0.0
    return QPResult(x[:m], status, f"clarabel {solution.status}"), slack


# --------------------------------------------------------------------------------------
# The controller
# --------------------------------------------------------------------------------------
class LinearMPC:
    """Linear time-varying MPC about the reference, with the controller interface.

    ``LinearMPC(arm, config)``; ``compute(t, y, reference, feedforward_acceleration=None)``
    returns a :class:`~hydroarm.control.interface.ControlOutput` whose ``tau`` (n,) N m
    always satisfies ``|tau_i| <= u_max_i``. ``status`` is ``"ok"``,
    ``"terminal_soft_fallback"`` (hard terminal set infeasible, soft used),
    ``"qp_failed_shift"``, ``"qp_failed_lqr"`` or ``"qp_failed_reference"``; ``terminal_violation`` is
    ``max(e_N' P e_N - alpha, 0)`` of the plan used (the optimal slack; 0 when
    the terminal set is off); ``timings`` (s): ``linearise``, ``riccati``,
    ``qp_update``, ``qp_solve`` (with fallbacks), ``total``.

    Attributes: ``Q`` (2n, 2n), ``R`` (n, n), ``torque_limit`` (n,) N m.
    Counters since ``reset``: ``clip_count`` (last-guard clips that changed
    the torque by more than rounding), ``fallback_count``, ``riccati_scipy_count``;
    ``last_message``: the solver's last status text.
    """

    name = "MPC"

    def __init__(self, arm: Arm, config: MPCConfig | None = None, control_period: float = 0.01) -> None:
        self.arm = arm
        self.config = config if config is not None else MPCConfig()
        cfg = self.config
        n = arm.n_joints
        self.n = n
        self.horizon = cfg.horizon
        self.control_period = require_period(control_period)
        self.nominal = NominalModel(arm, inner_step=None)  # own workspace
        self._q_diag = np.concatenate(
            [per_joint(cfg.q_position, n, "q_position"), per_joint(cfg.q_velocity, n, "q_velocity")]
        )
        self._r_diag = per_joint(cfg.r, n, "r")
        self.Q = np.diag(self._q_diag)
        self.R = np.diag(self._r_diag)
        limit = arm.torque_limit if cfg.torque_limit is None else cfg.torque_limit
        self.torque_limit = per_joint(limit, n, "torque_limit")
        self._limit_stacked = np.tile(self.torque_limit, cfg.horizon)
        self._solver = make_box_qp_solver(cfg.solver)
        if cfg.terminal_set != "off":
            try:
                import clarabel  # noqa: F401
            except ImportError:
                raise ConfigError(
                    f"terminal_set = {cfg.terminal_set!r} needs the clarabel package"
                ) from None
        # The window of linearisations at reference indices start .. start + N.
        size = cfg.horizon + 1
        self._x_ref = np.zeros((size, 2 * n))
        self._u_ref = np.zeros((size, n))
        self._a = np.zeros((size, 2 * n, 2 * n))
        self._b = np.zeros((size, 2 * n, n))
        self._x_next = np.zeros((size, 2 * n))
        self._a[:, :n, :n] = np.eye(n)  # the constant blocks of every A and B
        self._a[:, :n, n:] = self.control_period * np.eye(n)
        self.reset()

    # --- interface -------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the linearisation window, the terminal weight, the previous plan, the counters."""
        self._start: int | None = None
        self._reference: Reference | None = None
        self._riccati_index: int | None = None
        self._P: np.ndarray | None = None
        self._plan: np.ndarray | None = None  # (N, n) absolute torques of the last solution
        self._plan_index = 0
        self.clip_count = 0
        self.fallback_count = 0
        self.riccati_scipy_count = 0
        self.last_message = ""

    def observe(self, t: float, y: np.ndarray, u: np.ndarray, y_next: np.ndarray) -> None:
        """No-op: plain MPC learns nothing."""

    def compute(
        self,
        t: float,
        y: np.ndarray,
        reference: Reference,
        feedforward_acceleration: np.ndarray | None = None,
        feedforward_torque: np.ndarray | None = None,
    ) -> ControlOutput:
        """Torque for the measured state ``y = [q, v]`` (2n,) at time t (s).

        The horizon starts at reference index ``k = round(t / T)`` (the error is
        taken against ``x_r(k T)``). Two ways to feed a disturbance estimate
        forward (None means zero):

        * ``feedforward_acceleration`` d (n,) rad/s^2 is added to the nominal
          model's joint acceleration at every step of the horizon (the affine
          term; the paper's eq. 14 with d = M^-1 w). The cost still penalises
          the torque that compensates it, as a deviation from the dry u_r.
        * ``feedforward_torque`` w (n,) N m is a generalised force acting with
          the input: the model becomes ``f(x, u + w)``, i.e. the input
          reference shifts to ``u_r - w`` (exact through B_k, which carries
          M^-1 along the reference), so compensating w costs nothing and the
          QP's box still limits the total torque.
        The reference must not change between calls except by passing another
        object (the linearisations are cached by index).
        """
        start = time.perf_counter()
        cfg = self.config
        n, horizon, period = self.n, self.horizon, self.control_period
        y = np.asarray(y, dtype=float)
        if y.shape != (2 * n,) or not np.all(np.isfinite(y)):
            raise ValueError(f"y must be finite with shape ({2 * n},), got shape {y.shape}: {y}")
        k = int(round(t / period))

        # Linearise: slide the window to k .. k + N, computing only the new indices.
        self._slide(k, reference)
        u_refs = self._u_ref[:horizon]
        if feedforward_torque is not None:
            w = np.asarray(feedforward_torque, dtype=float)
            if w.shape != (n,) or not np.all(np.isfinite(w)):
                raise ValueError(f"feedforward_torque must be finite with shape ({n},)")
            u_refs = u_refs - w
        offsets = self._x_next[:horizon] - self._x_ref[1:]
        if feedforward_acceleration is not None:
            d = np.asarray(feedforward_acceleration, dtype=float)
            if d.shape != (n,) or not np.all(np.isfinite(d)):
                raise ValueError(f"feedforward_acceleration must be finite with shape ({n},)")
            offsets[:, n:] += period * d
            if cfg.discretisation == "taylor2":  # the extra acceleration also moves the position
                offsets[:, :n] += 0.5 * period**2 * d
        e0 = y - self._x_ref[0]
        t_lin = time.perf_counter()

        # Terminal weight: DARE at the horizon-end linearisation, once per index.
        if self._riccati_index != k + horizon:
            P, _, method = riccati_solution(
                self._a[horizon], self._b[horizon], self.Q, self._r_diag,
                cfg.riccati_tolerance, cfg.riccati_max_iterations,
            )  # fmt: skip
            self.riccati_scipy_count += method != "doubling"
            self._P, self._riccati_index = P, k + horizon
        P = self._P
        t_ric = time.perf_counter()

        # Condensed QP and its box.
        qp = condense(self._a[:horizon], self._b[:horizon], offsets, self._q_diag, self._r_diag, P, e0)
        u_ref_flat = u_refs.ravel()
        lb = -self._limit_stacked - u_ref_flat
        ub = self._limit_stacked - u_ref_flat
        warm = self._shifted_plan(k)
        if warm is not None:
            warm = warm.ravel() - u_ref_flat
        t_upd = time.perf_counter()

        # Solve, with fallbacks; every fault is an event of this step.
        status = "ok"
        events: list[str] = []
        result = self._solve(qp, lb, ub, P, warm, cfg.terminal_set)
        if cfg.terminal_set == "hard" and not result.ok:
            status = "terminal_soft_fallback"
            events.append("terminal_soft_fallback")
            result = self._solve(qp, lb, ub, P, warm, "soft")
        self.last_message = result.message
        if result.ok and _valid_moves(result.x, lb, ub):
            du = result.x
            self._plan = (u_ref_flat + du).reshape(horizon, n)
            self._plan_index = k
        else:
            self.fallback_count += 1
            events.append(qp_failure_event(result))
            du, status = self._fallback(k, u_refs, P, e0)
        tau = u_refs[0] + du[:n]
        t_sol = time.perf_counter()

        # Last guard, and the terminal-set violation (the optimal slack) of the plan used.
        if not np.all(np.abs(tau) <= self.torque_limit * (1.0 + CLIP_TOLERANCE)):  # NaN included
            self.clip_count += 1
            events.append("torque_clipped")
            tau = np.where(np.isfinite(tau), tau, 0.0)
        tau = np.clip(tau, -self.torque_limit, self.torque_limit)
        violation = 0.0
        if cfg.terminal_set != "off":
            e_n = qp.terminal_error(du)
            violation = max(float(e_n @ P @ e_n) - cfg.terminal_alpha, 0.0)
        end = time.perf_counter()
        timings = {
            "linearise": t_lin - start,
            "riccati": t_ric - t_lin,
            "qp_update": t_upd - t_ric,
            "qp_solve": t_sol - t_upd,
            "total": end - start,
        }
        return ControlOutput(
            tau=tau, status=status, timings=timings, terminal_violation=violation, events=tuple(events)
        )

    # --- internals -------------------------------------------------------------------
    def _slide(self, k: int, reference: Reference) -> None:
        """Make the window hold the linearisations at indices k .. k + N."""
        size = self.horizon + 1
        shift = None if self._start is None else k - self._start
        if reference is not self._reference or shift is None or not 0 <= shift < size:
            self._reference = reference
            self._riccati_index = None
            new = range(size)
        else:
            for array in (self._x_ref, self._u_ref, self._a, self._b, self._x_next):
                array[: size - shift] = array[shift:]
            new = range(size - shift, size)
        self._start = None  # invalid until every new slot is filled (an exception leaves it so)
        for slot in new:
            q, v, a = reference.sample((k + slot) * self.control_period)
            q = np.asarray(q, dtype=float)
            v = np.asarray(v, dtype=float)
            u_ref = self.nominal.inverse_dynamics(q, v, np.asarray(a, dtype=float))
            self._x_next[slot] = self.nominal.linearise_into(
                q, v, u_ref, self.control_period, self._a[slot], self._b[slot],
                self.config.discretisation, constant_blocks_set=True,
            )
            self._x_ref[slot, : self.n] = q
            self._x_ref[slot, self.n :] = v
            self._u_ref[slot] = u_ref
        self._start = k

    def _solve(self, qp: CondensedQP, lb, ub, P, warm, terminal_set: str) -> QPResult:
        """The box QP by the configured solver, or the terminal-set problem by Clarabel."""
        cfg = self.config
        try:
            if terminal_set == "off":
                return self._solver.solve(qp.H, qp.g, lb, ub, warm)
            penalty = None if terminal_set == "hard" else cfg.terminal_slack_penalty
            return solve_terminal_qp(qp, lb, ub, P, cfg.terminal_alpha, penalty)[0]
        except Exception as error:  # a crashing solver is a failed solve
            return QPResult(None, "failed", f"solver raised {error!r}")

    def _shifted_plan(self, k: int) -> np.ndarray | None:
        """The last successful plan (N, n) shifted to start at index k (last move held)."""
        if self._plan is None:
            return None
        shift = k - self._plan_index
        if not 0 <= shift < self.horizon:
            return None
        return np.concatenate([self._plan[shift:], np.repeat(self._plan[-1:], shift, axis=0)])

    def _fallback(self, k: int, u_refs: np.ndarray, P: np.ndarray, e0: np.ndarray):
        """Moves (N n,) and status: the shifted previous plan (``qp_failed_shift``), else the
        saturated LQR law (``qp_failed_lqr``), else, if even the LQR gain cannot be
        computed, the saturated reference torque (``qp_failed_reference``)."""
        plan = self._shifted_plan(k)
        if plan is not None:
            plan = np.clip(plan, -self.torque_limit, self.torque_limit)
            return (plan - u_refs).ravel(), "qp_failed_shift"
        status = "qp_failed_lqr"
        try:
            tau = u_refs[0] - lqr_gain(self._a[0], self._b[0], self.R, P) @ e0
        except (np.linalg.LinAlgError, ValueError):
            tau = np.full(self.n, np.nan)
        if not np.all(np.isfinite(tau)):  # degenerate weights: the reference torque alone
            tau, status = u_refs[0].copy(), "qp_failed_reference"
        tau = np.clip(np.where(np.isfinite(tau), tau, 0.0), -self.torque_limit, self.torque_limit)
        du = np.zeros(u_refs.size)
        du[: self.n] = tau - u_refs[0]
        return du, status


_QP_FAILURE_EVENTS = {
    "solved": "qp_invalid_solution",
    "iteration_limit": "qp_iteration_limit",
    "infeasible": "qp_infeasible",
    "failed": "qp_failed",
}


def qp_failure_event(result: QPResult) -> str:
    """The fault event of a solve that was not used, from ``result.status``:
    ``"qp_iteration_limit"``, ``"qp_infeasible"``, ``"qp_failed"`` (anything else, e.g.
    the solver raised) or ``"qp_invalid_solution"`` (reported solved, but not finite or
    outside the box)."""
    return _QP_FAILURE_EVENTS[result.status]


def _valid_moves(x: np.ndarray | None, lb: np.ndarray, ub: np.ndarray) -> bool:
    """Finite and within the bounds up to 1e-6 of the box width (NaN fails the test)."""
    if x is None or x.shape != lb.shape:
        return False
    excess = np.maximum(lb - x, x - ub) / (1.0 + (ub - lb))
    return bool(excess.max() <= 1e-6)
