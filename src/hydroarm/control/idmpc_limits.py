"""Torque limits of the inverse-dynamics MPC (:mod:`hydroarm.control.idmpc`).

Two ways to keep ``|tau_i| <= tau_max,i`` (N m) when the unconstrained first move does not:

:func:`allocate` (``limits = "allocation"``): the joints whose torque fits keep their planned
acceleration; the others take their clipped torque and the accelerations the dynamics then
give (S saturated, F free)::

    a_S = M_SS^-1 (tau_S - bias_S - M_SF a_F),    tau_F = M_FS a_S + M_FF a_F + bias_F

with ``bias = h - w_hat``; a free joint pushed over its limit joins S (at most n rounds). In a box
``lower <= tau <= upper`` (the drives' rate told), :func:`box_allocate`: the same about the box's
centre. :func:`held_torque` is the ID-MPC's one torque map over its box (the limits, or the drives'
rate box within them): the torque while it fits, else clipped, the QP's or the allocation's.

:class:`HorizonQP` (``limits = "qp"``): the horizon's problem of all n joints as one QP in the
stacked moves U (N n,), step-major (``U[k n + j]`` = joint j's move ``a - a_r`` at step k)::

    min 1/2 U' H U + U' (F_e vec(e0) + F_c vec(c))
    s.t. -tau_max <= tau_k(U) <= tau_max,   k = 0..N-1

H, F_e, F_c from :func:`condensed_problem` (the per-joint costs of the module idmpc, summed): the
double integrators' special case of :func:`hydroarm.control.mpc.condense`, equal to it up to
rounding, kept because GP-IDMPC's runs amplify last-bit differences (docs/controllers.md).
First solve (frozen rows): ``tau_k = M(q) (a_r,k + u_k) + h(q, v) - w_hat`` with M, h at the
current state for every k, exact at k = 0. Then ``sqp_iterations`` Gauss-Newton (SQP) steps:
along the predicted plan of the last solution U^ (states ``q_k, v_k``, accelerations ``a_k``
of each joint's double integrator), the rows are the inverse dynamics linearised there::

    tau_k(U) ~ ID(q_k, v_k, a_k) - w_hat + M(q_k) du_k
               + sum_{i<k} [dID/dq (k - i - 1/2) T^2 + dID/dv T] du_i,    du = U - U^

(Pinocchio's RNEA derivatives; ``dq_k/du_i = (k - i - 1/2) T^2``, ``dv_k/du_i = T`` for i < k);
with a ``disturbance_model`` (a learned model of the water) ``w_hat`` of row k is the model's
prediction at the plan's (q_k, v_k, a_k) instead of the current estimate, and its added-mass
inertia M_A,k joins M(q_k) in the row (the rest of its dependence on du is not linearised),
so the plan knows how its own motion changes M(q) and the Coriolis terms: while a base joint
is saturated, the plan folds the other joints the way that lowers the base joint's inertia.
Each solve is warm-started with the previous one's multipliers (DAQP ``dual_start``). The first
acceleration of the last successful solve is returned; None if the first solve fails.

``iteration_budget`` (the structured solver; None: none): the active-set iterations one
:meth:`HorizonQP.solve` may spend over all its QPs, counted (not timed: the same plan on any
machine). Each QP gets what the ones before it left; a QP that does not settle within it fails
(no DAQP fallback: its time has no bound) and the SQP stops there with the last settled
solve's plan (None if it is the first), and no SQP step starts with nothing left.

The drives' rate limit (``rate``: issue 32, the loop's ``actuator.rate_limit`` r, N m/s): N n rows
more, below the torque rows, on the torque's change per step and joint::

    -r T <= tau_k(U) - tau_{k-1}(U) <= r T,   k = 0..N-1,   tau_{-1} = the drives' output

(the differences of the torque rows, frozen or linearised: row block k minus row block k - 1, the
first against the torque the drives give before the plan's first command acts), so the plan
starts from what the drives give and ramps as fast as they can. Like the torque rows they couple
the joints through M; per torque component they are per joint. The structured solver forms
them itself from the torque rows (:func:`~hydroarm.control.plan_qp.solve_plan_qp`, no dense
2 N n x N n copy); DAQP gets them stacked (:func:`difference_rows`). ``rate_solver`` picks the
solver of these solves (:data:`RATE_SOLVER` by default), ``solver`` that of the torque rows alone;
``rate_solves`` counts the solves with rate rows. ``rate_warm`` (:data:`RATE_WARM`): a rate solve
starts from the last one's working set, a step on.
"""

from __future__ import annotations

import daqp
import numba
import numpy as np

from hydroarm.control.linear import double_integrator
from hydroarm.control.plan_qp import DUAL_TOL, PRIMAL_TOL, joint_factors, solve_plan_qp, warm_set
from hydroarm.model.dynamics import fixed_order
from hydroarm.model.dynamics.nominal import NominalModel

QP_SOLVERS = ("daqp", "structured")
"""The solvers of :class:`HorizonQP`: DAQP (dense) or :mod:`hydroarm.control.plan_qp` (its structure)."""


def _matvec(a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``a @ x`` (m,) for a (m, ...) flattened to (m, k) and x (k,), in fixed order
    (:mod:`hydroarm.model.dynamics.fixed_order`: no BLAS, whose per-CPU kernels round differently
    and a learner in the loop amplifies that)."""
    a = np.ascontiguousarray(a, dtype=float)
    return fixed_order.matvec(a.reshape(a.shape[0], -1), np.ascontiguousarray(x, dtype=float))


def _matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` for 2-D a, b, in fixed order (as :func:`_matvec`)."""
    return fixed_order.matmul(np.ascontiguousarray(a, dtype=float), np.ascontiguousarray(b, dtype=float))


RATE_SOLVER = "structured"
"""The default solver of the QPs with the drives' rate rows (module docstring): the structured one,
measured faster at the median, p99 and max step in IDMPC's, GP-IDMPC's and PI-IDMPC's rate-limited
runs (bench part ``rate``, docs/controllers.md); DAQP stays the torque rows' default (``solver``)."""
RATE_WARM = True
"""Whether a rate solve starts from the last one's working set (module docstring)."""
RATE_ITERATIONS = 4
"""The structured solver's iteration limit with the rate rows, per row (2 N n rows): their
problems churn (rows join and leave again); a cold 8-step paper-arm plan from a 2 rad start-up
took 283 iterations for 48 active rows (DAQP 185), more than the torque rows' limit of one per row."""


def difference_rows(rows: np.ndarray, n: int) -> np.ndarray:
    """The rate rows (N n, N n) of the torque rows ``rows`` (N n, N n): row block k less block
    k - 1, block 0 itself (module docstring)."""
    difference = rows.copy()
    difference[n:] -= rows[:-n]
    return difference


def allocate(mass: np.ndarray, bias: np.ndarray, acceleration: np.ndarray, limit: np.ndarray):
    """Torques within ``limit`` that keep the planned ``acceleration`` on every joint they can.

    ``bias`` = h - w_hat (n,): the torque is ``M a + bias``. Returns ``(tau (n,), a (n,),
    saturated (n,) bool)``: the saturated joints hold their clipped torque, the others their
    planned acceleration (module docstring)."""
    tau = _matvec(mass, acceleration) + bias
    saturated = np.abs(tau) > limit
    if not saturated.any():
        return tau, acceleration, saturated
    a = acceleration.copy()
    n = acceleration.shape[0]
    for _ in range(n):
        s, f = saturated, ~saturated
        target = np.clip(tau, -limit, limit)
        rhs = target[s] - bias[s]
        if f.any():
            rhs = rhs - _matvec(mass[np.ix_(s, f)], acceleration[f])
        a[s] = fixed_order.spd_solve(mass[np.ix_(s, s)], rhs)
        a[f] = acceleration[f]
        tau = _matvec(mass, a) + bias
        tau[s] = target[s]
        over = f & (np.abs(tau) > limit * (1.0 + 1e-12))
        if not over.any():
            break
        saturated = saturated | over
    return np.clip(tau, -limit, limit), a, saturated


def box_allocate(mass: np.ndarray, bias: np.ndarray, acceleration: np.ndarray, lower: np.ndarray, upper: np.ndarray):
    """:func:`allocate` in the box ``lower <= tau <= upper`` (n,) N m: about its centre c the box
    is the symmetric one of half-width ``(upper - lower) / 2`` on ``tau - c = M a + (bias - c)``.
    In the box of the limits, ``(-limit, limit)``, it is :func:`allocate` bit for bit: c = +0,
    ``bias - 0`` is ``bias``, the half-width ``limit``, the final clip holds what :func:`allocate`
    already held, and ``tau + 0`` changes only a -0.0, which :func:`allocate` does not give (its
    torques are ``M a + bias``, whose product sums from +0, or a clipped torque, ``+-limit``).
    Returns ``(tau (n,), a (n,), saturated (n,) bool)``."""
    centre = 0.5 * (lower + upper)
    tau, a, saturated = allocate(mass, bias - centre, acceleration, 0.5 * (upper - lower))
    return np.clip(tau + centre, lower, upper), a, saturated


SATURATION_TOLERANCE = 1e-9
"""Relative (-): a torque within this fraction of the box's larger bound of a bound counts as
saturated after the QP (:func:`held_torque`; the QP's rounding leaves an active row a few last
bits short of its bound)."""


def held_torque(limits: str, mass, bias, acceleration, lower, upper, constrained, *, plan_always: bool = False):
    """``(tau, a, saturated)``: the torque (n,) N m realising ``acceleration`` (n,) rad/s^2 on
    ``tau = M a + bias`` (``mass`` (n, n), ``bias`` (n,) N m), held in the box ``lower <= tau <=
    upper`` (n,) N m by the ID-MPC's ``limits`` (:class:`~hydroarm.control.idmpc.IDMPCConfig`):
    the torque as it is while it fits; else ``"clip"`` clips each torque into the box, ``"qp"``
    takes the horizon QP's first acceleration ``constrained()`` ((n,), or None: its solver
    failed) and clips its torque into the box (the QP's rounding: DAQP's tolerance is 1e-6 N m),
    ``"allocation"`` (and a failed QP) allocates (:func:`box_allocate`). The one torque map of
    every ID-MPC, with or without the drives' rate box (the box is ``(-limit, limit)`` without).
    ``plan_always``: the QP runs even while the torque fits (the drives' rate rows: a plan that
    fits now can still ask for a ramp the drives cannot give later; docs/robustness.md, section 6).

    A torque after the QP counts as saturated within ``tight`` of a bound, ``tight`` the fraction
    :data:`SATURATION_TOLERANCE` of the box's larger bound ``b`` written ``b - b (1 - 1e-9)`` (both
    steps exact: Sterbenz), so that in the box ``(-limit, limit)`` the bound less ``tight`` is
    ``limit (1 - 1e-9)`` exactly, the flag ``|tau| >= limit (1 - 1e-9)``."""
    tau = _matvec(mass, acceleration) + bias
    fits = np.all((tau >= lower) & (tau <= upper))  # |tau| <= limit in (-limit, limit); a NaN does not fit
    if fits and not (plan_always and limits == "qp"):
        return tau, acceleration, np.zeros(tau.shape[0], dtype=bool)
    if limits == "clip":
        clipped = np.clip(tau, lower, upper)
        return clipped, acceleration, clipped != tau
    if limits == "qp":
        a = constrained()
        if a is not None:
            tau = _matvec(mass, a) + bias
            span = np.maximum(np.abs(lower), np.abs(upper))
            tight = span - span * (1.0 - SATURATION_TOLERANCE)
            return np.clip(tau, lower, upper), a, (tau <= lower + tight) | (tau >= upper - tight)
    return box_allocate(mass, bias, acceleration, lower, upper)


def condensed_problem(period, horizon, q_pos, q_vel, r_acc, p_mats):
    """The horizon's problem of all n joints in the stacked moves U (N n,), step-major:
    ``min 1/2 U' H U + U' (F_e e0 + F_c c)``.

    Returns ``H`` (N n, N n), ``F_e`` (N n, n, 2) and ``F_c`` (N n, N, n, 2): the gradient's
    maps from the errors e0 (n, 2) and the defects c (N, n, 2)."""
    n = q_pos.shape[0]
    a_mat, b_vec = double_integrator(period)
    size = horizon * n
    hessian = np.zeros((size, size))
    grad_e0 = np.zeros((size, n, 2))
    grad_c = np.zeros((size, horizon, n, 2))
    for j in range(n):
        # e_k = S_e[k] e0 + S_u[k] u + S_c[k] c (k = 0..N), one joint
        s_e = np.zeros((horizon + 1, 2, 2))
        s_u = np.zeros((horizon + 1, 2, horizon))
        s_c = np.zeros((horizon + 1, 2, 2 * horizon))
        s_e[0] = np.eye(2)
        for k in range(horizon):
            s_e[k + 1] = _matmul(a_mat, s_e[k])
            s_u[k + 1] = _matmul(a_mat, s_u[k])
            s_u[k + 1][:, k] += b_vec
            s_c[k + 1] = _matmul(a_mat, s_c[k])
            s_c[k + 1][:, 2 * k : 2 * k + 2] += np.eye(2)
        weights = [np.diag([q_pos[j], q_vel[j]])] * horizon + [p_mats[j]]
        h_j = r_acc[j] * np.eye(horizon)
        fe_j = np.zeros((horizon, 2))
        fc_j = np.zeros((horizon, 2 * horizon))
        for k in range(horizon + 1):
            h_j += _matmul(_matmul(s_u[k].T, weights[k]), s_u[k])
            fe_j += _matmul(_matmul(s_u[k].T, weights[k]), s_e[k])
            fc_j += _matmul(_matmul(s_u[k].T, weights[k]), s_c[k])
        rows = np.arange(horizon) * n + j
        hessian[np.ix_(rows, rows)] = h_j
        grad_e0[rows, j, :] = fe_j
        grad_c[rows, :, j, :] = fc_j.reshape(horizon, horizon, 2)
    return hessian, grad_e0, grad_c


@numba.njit(cache=True)
def predicted_plan(e0, c, moves, q_r, v_r, a_r, period):  # pragma: no cover - compiled
    """The plan's states and accelerations ``(q, v, a)``, each (N, n), at steps k = 0..N-1 for
    the moves (N, n), the errors e0 (n, 2), the defects c (N, n, 2) and the reference
    ``q_r, v_r`` (>= N, n), ``a_r`` (N, n) (module idmpc: e+ = A e + B u + c)."""
    horizon, n = moves.shape
    q = np.empty((horizon, n))
    v = np.empty((horizon, n))
    a = np.empty((horizon, n))
    half = 0.5 * period * period
    for j in range(n):
        e_q, e_v = e0[j, 0], e0[j, 1]
        for k in range(horizon):
            q[k, j] = q_r[k, j] + e_q
            v[k, j] = v_r[k, j] + e_v
            a[k, j] = a_r[k, j] + moves[k, j]
            e_q, e_v = e_q + period * e_v + half * moves[k, j] + c[k, j, 0], e_v + period * moves[k, j] + c[k, j, 1]
    return q, v, a


@numba.njit(cache=True)
def fill_linearised_rows(d_q, d_v, mass, period, rows):  # pragma: no cover - compiled
    """The linearised torque rows (N n, N n) from the inverse dynamics' derivatives d_q, d_v and
    the mass matrices (N, n, n) along the plan: block (k, k) = M_k, block (k, i < k) =
    ``d_q[k] (k - i - 1/2) T^2 + d_v[k] T``, blocks above the diagonal 0."""
    horizon, n = mass.shape[0], mass.shape[1]
    rows[:, :] = 0.0
    for k in range(horizon):
        for r in range(n):
            for col in range(n):
                rows[k * n + r, k * n + col] = mass[k, r, col]
            for i in range(k):
                lag = (k - i - 0.5) * period * period
                for col in range(n):
                    rows[k * n + r, i * n + col] = d_q[k, r, col] * lag + d_v[k, r, col] * period


class HorizonQP:
    """The constrained horizon problem of ``limits = "qp"`` (module docstring).

    ``hessian`` (N n, N n), ``grad_e0`` (N n, 2 n), ``grad_c`` (N n, 2 N n) as flat maps;
    ``torque_limit`` (n,) N m; ``sqp_iterations`` relinearisations after the frozen solve;
    ``solver`` (:data:`QP_SOLVERS`): DAQP, or the compiled dual active set on the problem's
    structure (:func:`~hydroarm.control.plan_qp.solve_plan_qp`, the same solution to rounding).
    """

    def __init__(
        self, arm, period, horizon, q_pos, q_vel, r_acc, p_mats, torque_limit, sqp_iterations, solver="daqp",
        rate_solver=None,
    ):  # fmt: skip
        rate_solver = RATE_SOLVER if rate_solver is None else rate_solver
        for name, value in (("solver", solver), ("rate_solver", rate_solver)):
            if value not in QP_SOLVERS:
                raise ValueError(f"{name} = {value!r}: must be one of {', '.join(QP_SOLVERS)}")
        self.arm = arm
        self.n = n = arm.n_joints
        self.period = float(period)
        self.horizon = horizon
        self.sqp_iterations = sqp_iterations
        hessian, grad_e0, grad_c = condensed_problem(period, horizon, q_pos, q_vel, r_acc, p_mats)
        self.hessian = hessian
        self.solver = solver
        self.rate_solver = rate_solver
        self.rate_warm = RATE_WARM  # rate solves start from the last one's working set, a step on
        self._rate_lams: dict[int, np.ndarray] = {}  # the last step's rate multipliers (2 N n,) by solve (0: frozen)
        self._factors = joint_factors(hessian, n) if "structured" in (solver, rate_solver) else None
        self.grad_e0 = grad_e0.reshape(horizon * n, 2 * n)
        self.grad_c = grad_c.reshape(horizon * n, 2 * horizon * n)
        self.limit = np.tile(np.asarray(torque_limit, dtype=float), horizon)
        self.nominal = NominalModel(arm, inner_step=None)  # own workspace
        self._sense = np.zeros(horizon * n, dtype=np.int32)
        self._sense_rate = np.zeros(2 * horizon * n, dtype=np.int32)  # the torque and the rate rows
        self._base = np.zeros(horizon * n)  # the torque rows' affine part: tau(U) = rows U + base
        self.rate_solves = 0  # solves with the rate rows (DAQP)
        self._rows = np.zeros((horizon * n, horizon * n))
        self._d_q = np.empty((horizon, n, n))
        self._d_v = np.empty((horizon, n, n))
        self._mass = np.empty((horizon, n, n))
        self.last_iterations = 0  # SQP steps the last solve took (0: the frozen rows' solution)
        self.fallbacks = 0  # structured solves handed to DAQP (iteration limit)
        self.disturbance_model = None  # optional (q, v, a) (N, n) each -> (w (N, n), M_A (N, n, n))
        self.iteration_budget: int | None = None  # active-set iterations per solve (structured; module docstring)
        self.last_qp_iterations = 0  # the last structured QP's active-set iterations
        self.last_spent = 0  # the last solve's active-set iterations over its QPs (structured)
        # load the compiled kernels now, not in the first saturated step
        zeros = np.zeros((horizon, n))
        predicted_plan(np.zeros((n, 2)), np.zeros((horizon, n, 2)), zeros, zeros, zeros, zeros, self.period)
        fill_linearised_rows(self._d_q, self._d_v, self._mass, self.period, self._rows)
        if self._factors is not None:
            size = horizon * n
            for rows in (size, 2 * size):  # the torque rows, and with the rate rows
                solve_plan_qp(
                    self._factors, np.zeros(size), np.eye(size), np.ones(rows), -np.ones(rows),
                    np.zeros(rows, dtype=np.int64), PRIMAL_TOL, DUAL_TOL, 1,
                )  # fmt: skip

    def _solve_qp(self, gradient, rows, upper, lower, lam=None, limit=None):
        """``(moves (N n,), lam, ok)`` of one QP by the configured solver, warm-started from the
        multipliers ``lam`` of the last solve (None: cold). ``rows``: the torque rows (N n, N n);
        ``upper``, ``lower``: their bounds (N n,), or with the rate rows' below them (2 N n,:
        :meth:`rate_bounds`; DAQP gets the rate rows formed, the structured solver forms them itself).
        The structured solver hands a problem it does not settle within as many iterations as rows
        (:data:`RATE_ITERATIONS` per row with the rate rows) to DAQP (counted in ``fallbacks``):
        measured on the iiwa14 (245 rows, up to 240 active), its cost per iteration grows with the
        working set and the longest solves took 3x DAQP's; on the paper arm no torque-row solve
        takes more than 112. ``limit``: at most this many iterations (``iteration_budget``'s share;
        the structured solver only) and no fallback: a QP not settled within it fails."""
        size = gradient.shape[0]
        rated = upper.shape[0] > size
        if (self.rate_solver if rated else self.solver) == "structured":
            cap = RATE_ITERATIONS * upper.shape[0] if rated else size
            self.last_qp_iterations = iterations = 0
            try:
                moves, new_lam, flag, iterations = solve_plan_qp(
                    self._factors, gradient, rows, upper, lower, warm_set(lam, upper.shape[0]),
                    PRIMAL_TOL, DUAL_TOL, cap if limit is None else min(cap, limit),
                )  # fmt: skip
            except ZeroDivisionError:  # a zero pivot: met on the paper arm with the UR5's limits, a plan 2 steps ahead
                flag = 0
            self.last_qp_iterations = int(iterations)
            if int(flag) == 1 and np.all(np.isfinite(moves)) and np.all(np.isfinite(new_lam)):
                return moves, new_lam, True
            if limit is not None:
                return None, None, False  # within a budget: no fallback
            self.fallbacks += 1  # not settled, or a working set too close to dependent rows
        if rated:
            rows = np.vstack([rows, difference_rows(rows, self.n)])
        sense = self._sense if rows.shape[0] == self._sense.shape[0] else self._sense_rate
        if lam is None:
            moves, _, flag, info = daqp.solve(self.hessian, gradient, rows, upper, lower, sense)
        else:
            moves, _, flag, info = daqp.solve(self.hessian, gradient, rows, upper, lower, sense, dual_start=lam)
        return np.asarray(moves), np.asarray(info["lam"]), int(flag) == 1

    def _rate_warm_start(self, solve, fallback):
        """The working set rate solve ``solve`` (0 the first, 1.. the SQP steps) starts from: the
        last step's same solve's multipliers a step on (each block of N n rows shifted by n, the
        last step free); ``fallback`` (this step's last multipliers, or None: cold) when
        ``rate_warm`` is off, the rate solver is DAQP or there was none."""
        last = self._rate_lams.get(solve)
        if not self.rate_warm or self.rate_solver != "structured" or last is None:
            return fallback
        n, size = self.n, self.horizon * self.n
        shifted = np.zeros(2 * size)
        shifted[: size - n] = last[n:size]
        shifted[size : 2 * size - n] = last[size + n :]
        return shifted

    def forget(self) -> None:
        """Drop the last rate solve's working set (a new run starts cold)."""
        self._rate_lams.clear()

    def gradient(self, e0: np.ndarray, c: np.ndarray) -> np.ndarray:
        """``F_e vec(e0) + F_c vec(c)`` (N n,) for the errors e0 (n, 2) and defects c (N, n, 2)."""
        return _matvec(self.grad_e0, e0.ravel()) + _matvec(self.grad_c, c.ravel())

    def frozen_rows(self, mass: np.ndarray, bias: np.ndarray, a_r: np.ndarray):
        """``(rows, upper, lower)`` with M, bias = h - w_hat of the current state at every step."""
        horizon = self.horizon
        rows = np.kron(np.eye(horizon), mass)
        base = _matmul(a_r, mass.T).ravel() + np.tile(bias, horizon)  # M a_r,k + bias, step-major
        self._base = base
        return rows, self.limit - base, -self.limit - base

    def linearised_rows(self, moves, e0, c, q_r, v_r, a_r, w_hat):
        """``(rows, upper, lower)`` of the inverse dynamics linearised along the plan of ``moves``
        (N, n) (module docstring); ``rows`` is a buffer reused by the next call."""
        period = self.period
        q, v, a = predicted_plan(e0, c, moves, q_r, v_r, a_r, period)
        base = np.empty(self.horizon * self.n)
        n = self.n
        for k in range(self.horizon):
            tau, d_q, d_v, mass = self.nominal.inverse_dynamics_derivatives(q[k], v[k], a[k])
            self._d_q[k], self._d_v[k], self._mass[k] = d_q, d_v, mass
            base[k * n : (k + 1) * n] = tau
        if self.disturbance_model is not None:  # the disturbance at the planned states, step by step
            w_plan, added_mass = self.disturbance_model(q, v, a)
            base -= w_plan.ravel()
            self._mass += added_mass  # the row's inertia M_k + M_A,k (the model's added mass answers du_k)
        else:
            base -= np.tile(w_hat, self.horizon)
        fill_linearised_rows(self._d_q, self._d_v, self._mass, period, self._rows)
        shift = _matvec(self._rows, moves.ravel()) - base
        self._base = -shift  # tau(U) = base + rows (U - moves)
        return self._rows, self.limit + shift, -self.limit + shift

    def rate_rows(self, rows, upper, lower, rate):
        """The torque rows ``(rows, upper, lower)`` of the last :meth:`frozen_rows` or
        :meth:`linearised_rows` with the rate rows below them (module docstring): ``rate`` =
        ``(previous (n,), step (n,))``, the drives' output before the first command acts (N m) and
        ``r T`` (N m); ``(2 N n, N n)``, ``(2 N n,)`` twice."""
        upper, lower = self.rate_bounds(upper, lower, rate)
        return np.vstack([rows, difference_rows(rows, self.n)]), upper, lower

    def rate_bounds(self, upper, lower, rate):
        """The bounds ``(upper, lower)`` (2 N n,) of :meth:`rate_rows`: the torque rows' and below
        them the rate rows' (the torque rows themselves are not copied)."""
        previous, step = rate
        n = self.n
        change = self._base.copy()
        change[n:] -= self._base[:-n]
        change[:n] -= previous
        bound = np.tile(np.asarray(step, dtype=float), self.horizon)
        return np.concatenate([upper, bound - change]), np.concatenate([lower, -bound - change])

    def solve(
        self, e0, c, q_r, v_r, a_r, mass, bias, w_hat, initial_moves=None, initial_lam=None, rate=None
    ) -> np.ndarray | None:
        """The first acceleration (n,) rad/s^2 of the constrained horizon problem, or None.

        ``e0`` (n, 2), ``c`` (N, n, 2), ``q_r, v_r`` (>= N, n), ``a_r`` (N, n): the outer
        problem; ``mass`` (n, n), ``bias`` = h - w_hat (n,) at the current state; ``w_hat`` (n,).
        ``initial_moves`` (N, n): a plan to linearise about first (a warm start: the frozen
        solve is skipped), or None. ``initial_lam`` (N n,; 2 N n with the rate rows, each block
        shifted): the working set to start the first solve from (the signs of a last plan's
        multipliers, shifted; the structured solver only: DAQP's path starts cold as it always
        did); with the rate rows and none given, the last step's own (``rate_warm``). The whole
        plan's moves (N n) are left in ``last_moves``, its multipliers in ``last_lam``, whether a
        torque row is active in ``last_active``. ``rate``: ``(previous (n,), step (n,))`` N m, the drives' rate rows
        (:meth:`rate_rows`), or None (none: the torque rows alone, as without a rate limit)."""
        gradient = self.gradient(e0, c)
        self.last_iterations = 0
        given = False
        if initial_moves is None:
            rows, upper, lower = self.frozen_rows(mass, bias, a_r)
        else:
            rows, upper, lower = self.linearised_rows(
                np.asarray(initial_moves, dtype=float), e0, c, q_r, v_r, a_r, w_hat
            )
        if rate is not None:
            upper, lower = self.rate_bounds(upper, lower, rate)
            given = initial_lam is not None and initial_lam.shape[0] == upper.shape[0]  # a caller's, shifted
            initial_lam = initial_lam if given and self.rate_solver == "structured" else self._rate_warm_start(0, None)
            self.rate_solves += 1
        elif self.solver != "structured":
            initial_lam = None  # DAQP's path starts cold, as it always did
        budget = self.iteration_budget if "structured" in (self.solver, self.rate_solver) else None
        moves, lam, ok = self._solve_qp(gradient, rows, upper, lower, initial_lam, limit=budget)
        self.last_spent = self.last_qp_iterations
        if not ok:
            return None
        if rate is not None:
            self._rate_lams[0] = lam  # the next step's first solve starts from this one's working set
        for _ in range(self.sqp_iterations):
            left = None if budget is None else budget - self.last_spent
            if left is not None and left <= 0:
                break  # the budget is spent: the last settled solve's plan
            plan = np.asarray(moves).reshape(self.horizon, self.n)
            rows, upper, lower = self.linearised_rows(plan, e0, c, q_r, v_r, a_r, w_hat)
            if rate is not None:
                upper, lower = self.rate_bounds(upper, lower, rate)
                self.rate_solves += 1
            start = lam if rate is None or given else self._rate_warm_start(self.last_iterations + 1, lam)
            new, new_lam, ok = self._solve_qp(gradient, rows, upper, lower, start, limit=left)
            self.last_spent += self.last_qp_iterations
            if ok and rate is not None:
                self._rate_lams[self.last_iterations + 1] = new_lam
            if not ok:
                break
            moves, lam = new, new_lam
            self.last_iterations += 1
        self.last_moves = np.asarray(moves).reshape(self.horizon, self.n)
        self.last_lam = lam
        self.last_active = bool(np.any(lam != 0.0))
        return a_r[0] + np.asarray(moves[: self.n])
