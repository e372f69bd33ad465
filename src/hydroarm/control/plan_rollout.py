"""PI-IDMPC's planner kernels. The rollout, compiled: the IDMPC's closed loop run on the dry model
plus the water model (:meth:`~hydroarm.control.pi_idmpc.PhysicsInformedIDMPC._rollout`), the
first linearisation point of a plan and the scale of its plausibility check.

One step of the rollout from (q, v) (n,) each, given Pinocchio's CRBA (upper triangle) and
nonlinear effects at that state and the arm's joint Jacobian and its time variation (6, n):

1. the IDMPC's unconstrained first acceleration ``a = a_r,0 + u_0(e0, c)``
   (:func:`~hydroarm.control.linear.unconstrained_move`, the defects c of its own horizon);
2. the water model's terms ``(M_A, f)`` (:func:`~hydroarm.model.water.strips.water_terms` with the
   model's coefficients), ``M = M_dry + M_A``, ``bias = h - f - w_rest``;
3. the torque allocation of :func:`~hydroarm.control.idmpc_limits.allocate`
   (:func:`allocate_fixed`), the acceleration bounded by ``max(|a|, 100)``;
4. the double integrator's step.

:func:`water_along_plan`: the model's force at a plan's states from its terms there (the
planner's torque rows, :meth:`~hydroarm.control.pi_idmpc.PhysicsInformedIDMPC._along_plan`).

Each function sums in a fixed order and solves by a Cholesky factor (no BLAS / LAPACK, whose
kernels round per CPU: issue 29's rule for paths a closed loop amplifies), compiled without
``fastmath``. The Python around it (35 steps of NumPy calls, :func:`allocate`'s index sets and
``np.linalg.solve``) took about half of a replan (bench ``planner``, ``replan_breakdown``).
"""

from __future__ import annotations

import numba
import numpy as np

from hydroarm.control.linear import unconstrained_move
from hydroarm.model.water.strips import water_terms

__all__ = ["allocate_fixed", "rollout_step", "water_along_plan"]


@numba.njit(cache=True)
def _solve_saturated(mass, rhs, saturated):  # pragma: no cover - compiled
    """``M_SS^-1 rhs_S`` (n,) written at S (other entries 0), by the Cholesky factor of M_SS
    (M symmetric positive definite, so is every principal block); NaN if a pivot is not > 0."""
    n = mass.shape[0]
    index = np.empty(n, dtype=np.int64)
    m = 0
    for i in range(n):
        if saturated[i]:
            index[m] = i
            m += 1
    chol = np.zeros((m, m))
    for j in range(m):
        s = mass[index[j], index[j]]
        for p in range(j):
            s -= chol[j, p] * chol[j, p]
        if not s > 0.0:
            return np.full(n, np.nan)
        chol[j, j] = np.sqrt(s)
        for i in range(j + 1, m):
            s = mass[index[i], index[j]]
            for p in range(j):
                s -= chol[i, p] * chol[j, p]
            chol[i, j] = s / chol[j, j]
    z = np.empty(m)
    for i in range(m):
        s = rhs[index[i]]
        for p in range(i):
            s -= chol[i, p] * z[p]
        z[i] = s / chol[i, i]
    out = np.zeros(n)
    for i in range(m - 1, -1, -1):
        s = z[i]
        for p in range(i + 1, m):
            s -= chol[p, i] * out[index[p]]
        out[index[i]] = s / chol[i, i]
    return out


@numba.njit(cache=True)
def _torque(mass, a, bias):  # pragma: no cover - compiled
    """``M a + bias`` (n,), each row summed in column order."""
    n = a.shape[0]
    tau = np.empty(n)
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += mass[i, j] * a[j]
        tau[i] = s + bias[i]
    return tau


@numba.njit(cache=True)
def allocate_fixed(mass, bias, acceleration, limit):  # pragma: no cover - compiled
    """:func:`~hydroarm.control.idmpc_limits.allocate` in fixed-order compiled algebra (the same
    rounds; M_SS by its Cholesky factor instead of LAPACK's LU): ``(tau, a, saturated)``."""
    n = acceleration.shape[0]
    tau = _torque(mass, acceleration, bias)
    saturated = np.abs(tau) > limit
    if not saturated.any():
        return tau, acceleration.copy(), saturated
    a = acceleration.copy()
    for _ in range(n):
        target = np.minimum(np.maximum(tau, -limit), limit)
        rhs = np.zeros(n)
        for i in range(n):
            if saturated[i]:
                s = 0.0
                for j in range(n):
                    if not saturated[j]:
                        s += mass[i, j] * acceleration[j]
                rhs[i] = target[i] - bias[i] - s
        solved = _solve_saturated(mass, rhs, saturated)
        for i in range(n):
            a[i] = solved[i] if saturated[i] else acceleration[i]
        tau = _torque(mass, a, bias)
        over = False
        for i in range(n):
            if saturated[i]:
                tau[i] = target[i]
            elif np.abs(tau[i]) > limit[i] * (1.0 + 1e-12):
                saturated[i] = True
                over = True
        if not over:
            break
    return np.minimum(np.maximum(tau, -limit), limit), a, saturated


@numba.njit(cache=True)
def rollout_step(
    q, v, q_r0, v_r0, a_r0, c, p_mats, gains, gs, period, a_ref, strips, still, jac, djac, mass_upper, nle, rest,
    limit,
):  # pragma: no cover - compiled  # fmt: skip
    """One step of the rollout (module docstring): ``(q_next, v_next, move)`` (n,) each.

    ``q_r0, v_r0, a_r0`` (n,): the IDMPC's reference now, ``c`` (N_I, n, 2) its horizon's
    defects; ``p_mats, gains, gs``: its per-joint LQR terms; ``a_ref`` (n,): the planner's
    reference acceleration at this step (move = a - a_ref); ``strips``, ``still``: the water
    model's compiled strips (its coefficients written in) and the still water; ``jac``, ``djac``
    (6, n); ``mass_upper`` (n, n): CRBA's upper triangle; ``nle`` (n,): h(q, v); ``rest`` (n,):
    the remainder observer's estimate; ``limit`` (n,) N m."""
    n = q.shape[0]
    e0 = np.empty((n, 2))
    for j in range(n):
        e0[j, 0] = q[j] - q_r0[j]
        e0[j, 1] = v[j] - v_r0[j]
    a = a_r0 + unconstrained_move(e0, c, p_mats, gains, gs, period)
    added, water_bias, force, _ = water_terms(strips, q, v, still, jac, djac)
    mass = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            mass[i, j] = (mass_upper[j, i] if i > j else mass_upper[i, j]) + added[i, j]
    bias = np.empty(n)
    for i in range(n):
        bias[i] = nle[i] - (force[i] - water_bias[i]) - rest[i]  # the drag unclipped: it damps
    allocated = allocate_fixed(mass, bias, a, limit)[1]
    q_next = np.empty(n)
    v_next = np.empty(n)
    move = np.empty(n)
    for i in range(n):
        bound = max(abs(a[i]), 100.0)  # explicit steps of a light joint in strong drag overshoot
        acc = min(max(allocated[i], -bound), bound)
        move[i] = acc - a_ref[i]
        q_next[i] = q[i] + period * v[i] + 0.5 * period * period * acc
        v_next[i] = v[i] + period * acc
    return q_next, v_next, move


@numba.njit(cache=True)
def water_along_plan(added, rest, a, remainder, limit):  # pragma: no cover - compiled
    """The model's force at the plan's N states, ``clip(f_k - M_A,k a_k + w_rest, +-limit)``
    (N, n), from its terms ``added`` (N, n, n), ``rest`` = f (N, n), the planned accelerations
    ``a`` (N, n), the remainder's estimate (n,) and the torque limits (n,): each product summed
    in column order (:func:`hydroarm.model.dynamics.fixed_order.matvec`'s)."""
    horizon, n = rest.shape
    w = np.empty((horizon, n))
    for k in range(horizon):
        for i in range(n):
            s = 0.0
            for j in range(n):
                s += added[k, i, j] * a[k, j]
            w[k, i] = min(max(rest[k, i] - s + remainder[i], -limit[i]), limit[i])
    return w
