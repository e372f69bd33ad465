"""PI-IDMPC: the inverse-dynamics MPC with a physics-informed water model, and an observer on the rest.

Each step, at the (filtered) state y = [q, v] (2n,):

1. the outer MPC plans the acceleration a_0 (n,) (:class:`~hydroarm.control.idmpc.InverseDynamicsMPC`;
   the plan does not depend on the disturbance);
2. the water model (:class:`~hydroarm.control.learned_water.PhysicsInformedModel`) predicts the
   water's generalised force at (q, v, a_0): drag, added mass (it answers a_0) and buoyancy;
3. the remainder observer (``remainder``: TDE or NDOB, :mod:`hydroarm.control.observers`) adds
   what the state model cannot know (the paper's time-varying current, a plant mismatch): it
   filters the part of the TDE residual the model did not predict;
4. computed torque ``tau = (M + M_A) a + h - f - w_rest``, with the model's force split as
   ``f - M_A a`` (its added mass joins the inertia, so it answers whatever acceleration the torque
   limits leave) and w_rest the remainder's estimate; the limits are held by the horizon QP
   (``idmpc.limits``) whose SQP rows take the model's prediction at every planned state of the
   horizon (:class:`~hydroarm.control.idmpc_limits.HorizonQP`), so a
   saturated start-up plans with the water it will meet, not the water of now.

The planner (the ``pi_idmpc`` section, :class:`PIIDMPCConfig`: ``planner``; ``"auto"``: while the
torque limits bind). Instead of the IDMPC's disturbance-blind 5-step plan, a
``planner_horizon``-step plan (35) of the same cost: the horizon QP
(:class:`~hydroarm.control.idmpc_limits.HorizonQP`) with the model's water at every planned state
in its torque rows, ``planner_iterations`` SQP steps (3), linearised first about the
IDMPC's own closed loop run on the dry model plus the water model (:meth:`_rollout`), then about the
last plan shifted. A plan is refused (the step is the IDMPC's) when its first acceleration leaves
the IDMPC's own first move ``a_I`` by more than ``|a_I| + planner_deviation`` on a joint (without
this check 31 of the 200 stress-study worlds diverged; under the drives' rate limit, below, when it
also leaves the IDMPC's move within the rate box so), or its accelerations exceed
:data:`PLAN_TRUST` of that closed loop's. The plan is followed ``planner_hold`` steps (1) with the
IDMPC's LQR gains on the deviation from it; ``"auto"`` stops at the first plan with no active
torque row. Measured: docs/controllers.md, "PI-IDMPC".

Beside the loop (``plan_latency`` L > 0): the plan of step k is solved at step k - L from the state
predicted for step k, in the step (``plan_worker = "inline"``) or by a forked worker process
(``"process"``) whose answer step k takes: the same run either way
(:class:`~hydroarm.control.plan_worker.LatentPlanner`). Its cost: ``plan_prediction_steps`` RK4 steps a
period for the predicted start state, and ``planner_budget`` (the structured solver) bounds the
active-set iterations of a plan, counted, so that the plan's time is bounded the same way on every machine.
Measured (2026-12-04, 2 loaded cores, CPU time per plan after the first; L = 1, structured, budget 120,
2 SQP steps, 2 prediction steps): paper task median 4.5 ms, p99 7.4, max 7.5, mean E_p 0.025699; the
UR5's limits 6.6 / 10.0 / 11.2 ms, 0.079868 (without the budget: 13.7 / 31 / 53 ms, 0.025636 / 0.081199).

The drives' rate limit (issue 32, :meth:`PhysicsInformedIDMPC.drive_limits`): its IDMPC holds the
box of the drives' rate (:meth:`~hydroarm.control.idmpc.InverseDynamicsMPC.torque_box`), the
planner's QP takes the rate rows from the drives' output, a plan is followed within the box
(:func:`~hydroarm.control.idmpc_limits.box_allocate`) and ``"auto"`` plans while the box binds. The
deviation check (:func:`plan_refused`) refuses a plan only when it is far from both the IDMPC's
unconstrained move and its move within the box (its rate QP, solved every step). Against the
first alone the iiwa 14 under 1000 N m/s diverged at 3.63 s (218 plans refused in 360 steps, each
handing a ramp in progress to the 5-step plan); against the second alone the paper arm diverged at
1.10 s (63 in 110 steps: its early ramps); far from both (10 s, seed 0, 2026-12-05): the iiwa 14
0.0270 rad^2, 0.01 rad after 2 s, the paper arm 0.0710 (0.0711 before). A plan solved beside the
loop (``plan_latency`` > 0) starts from a state L steps ahead, whose drives' output is not known
yet: it has no rate rows, and is followed within the box.

After the step (``observe``) the model learns the transition (recursive least squares) and the
remainder observer takes ``r - model(midpoint)``. A model saved by :meth:`save_model` and given
back with :meth:`load_model` (``hydroarm run --model FILE``) starts a run knowing the water;
``reset`` goes back to the loaded model (or the prior).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Literal

import numpy as np
import pydantic

from hydroarm.config import FrozenModel, per_joint
from hydroarm.control.idmpc import IDMPCConfig, InverseDynamicsMPC
from hydroarm.control.idmpc_limits import HorizonQP, box_allocate, predicted_plan
from hydroarm.control.interface import ControlOutput, Reference, sample_times
from hydroarm.control.learned_water import PhysicsInformedModel, WaterModelConfig
from hydroarm.control.linear import reference_defects
from hydroarm.control.observers import DisturbanceObserver
from hydroarm.control.plan_rollout import rollout_step, water_along_plan
from hydroarm.control.plan_worker import LatentPlanner
from hydroarm.model.arm.description import Arm
from hydroarm.model.dynamics import fixed_order

PLAN_TRUST = (20.0, 1000.0)
"""A plan is followed only if its accelerations over the held steps are within ``20 x`` the largest
of the IDMPC's own closed loop on the model (per joint) ``+ 1000 rad/s^2``; measured on the paper
task: without the check one SQP in ~20 left its basin (7e5 rad/s^2 on the wrist) and the run
diverged; a trust region in the QP itself (within 1-10 x) removed the planner's gain (0.0254-0.0288)."""


def plan_refused(first: np.ndarray, moves, deviation: float) -> bool:
    """Whether a plan whose first acceleration is ``first`` (n,) rad/s^2 is refused: on some joint it
    leaves every given IDMPC move ``m`` (n,) each, None skipped, by more than ``|m| + deviation``
    (module docstring: the IDMPC's unconstrained move, and under the drives' rate limit also its
    move within the rate box). False when no move is given."""
    far = None
    for move in moves:
        if move is not None:
            off = np.abs(first - move) > np.abs(move) + deviation
            far = off if far is None else far & off
    return far is not None and bool(np.any(far))


class PIIDMPCConfig(FrozenModel):
    """Settings of :class:`PhysicsInformedIDMPC` beyond its IDMPC's (``idmpc``) and its water
    model's (``water_model``): the planner (module docstring), the ``pi_idmpc`` section."""

    planner: Literal["off", "auto", "always"] = pydantic.Field(
        "auto",
        description="the long plan with the model's water and the torque limits: off, auto (while the limits "
        "bind) or always",
    )
    planner_horizon: int = pydantic.Field(
        35, ge=2, le=200, description="the planner's preview in control steps, 2 <= x <= 200"
    )
    planner_hold: int = pydantic.Field(
        1, ge=1, le=200, description="control steps a plan is followed before the next, 1 <= x <= 200"
    )
    planner_iterations: int = pydantic.Field(
        3, ge=0, le=10, description="the planner's SQP steps along the plan per replan, 0 <= x <= 10"
    )
    planner_solver: Literal["structured", "daqp"] = pydantic.Field(
        "daqp",
        description="the planner's QP solver: daqp (dense; the default: its runs hold across BLAS kernels) or "
        "structured (compiled, per-joint factors, hydroarm.control.plan_qp: 32x faster a solve, the same plan to "
        "rounding, but its active-set decisions turn a kernel's last bit into another noisy run); under the drives' "
        "rate limit also the solver of its IDMPC's rate-limited QPs",
    )
    planner_budget: int = pydantic.Field(
        0,
        ge=0,
        le=100000,
        description="active-set iterations a plan may spend over its SQP's QPs, counted (the structured solver: "
        "a QP not settled within what is left fails, the SQP stops at the last settled plan); 0: no budget, "
        "0 <= x <= 100000",
    )
    planner_deviation: float = pydantic.Field(
        500.0,
        ge=0.0,
        le=1e8,
        description="a plan is followed only while its first acceleration is within |a_IDMPC| + this of the "
        "IDMPC's own on every joint (rad/s^2), 0 <= x <= 1e8",
    )

    plan_latency: int = pydantic.Field(
        0,
        ge=0,
        le=10,
        description="control periods between a plan's start state and the step that follows it: the plan of "
        "step k is solved at step k - x from the state predicted for k (beside the loop); 0: solved at step k, "
        "0 <= x <= 10",
    )
    plan_prediction_steps: int = pydantic.Field(
        10,
        ge=1,
        le=100,
        description="RK4 steps per control period of the state a plan of plan_latency > 0 starts from (the model "
        "carried plan_latency periods on; 10: 1 ms at 10 ms, 2: a fifth of the cost), 1 <= x <= 100",
    )
    plan_worker: Literal["inline", "process"] = pydantic.Field(
        "inline",
        description="where a plan of plan_latency > 0 is solved: inline (in the control step) or process (a worker "
        "process beside the loop; the same numbers)",
    )

    @pydantic.model_validator(mode="after")
    def _hold_within_horizon(self) -> PIIDMPCConfig:
        if self.planner_hold > self.planner_horizon:
            raise ValueError(
                f"planner_hold ({self.planner_hold}) must be at most planner_horizon ({self.planner_horizon}) steps"
            )
        if self.plan_latency + self.planner_hold > self.planner_horizon:
            raise ValueError(
                f"plan_latency ({self.plan_latency}) + planner_hold ({self.planner_hold}) must be at most "
                f"planner_horizon ({self.planner_horizon}) steps"
            )
        if self.planner_budget > 0 and self.planner_solver != "structured":
            raise ValueError(
                f"planner_budget ({self.planner_budget}) needs planner_solver 'structured' (DAQP's iterations are not "
                "counted here)"
            )
        if self.planner_budget > 0 and self.planner == "off":
            raise ValueError(f"planner_budget ({self.planner_budget}) needs a planner (planner 'auto' or 'always')")
        if self.plan_worker == "process" and self.plan_latency == 0:
            raise ValueError("plan_worker 'process' needs plan_latency >= 1 (a plan solved beside the loop)")
        default_steps = type(self).model_fields["plan_prediction_steps"].default
        if self.plan_prediction_steps != default_steps and self.plan_latency == 0:
            raise ValueError(
                f"plan_prediction_steps ({self.plan_prediction_steps}) needs plan_latency >= 1 (only a plan solved "
                "beside the loop predicts the state it starts from)"
            )
        return self


class PhysicsInformedIDMPC:
    """IDMPC + physics-informed water model + remainder observer (module docstring).

    ``model_config.remainder``: the observer on what the model leaves (``kind = "none"``: the model alone);
    ``planner_config``: the planner (:class:`PIIDMPCConfig`, the ``pi_idmpc`` section).
    Attributes: ``mpc`` (the IDMPC), ``model``, ``remainder`` (a DisturbanceObserver or None),
    ``config`` (the :class:`PIIDMPCConfig`), ``planner`` (its HorizonQP, None with ``planner = "off"``).
    """

    name = "PI-IDMPC"

    def __init__(
        self,
        arm: Arm,
        config: IDMPCConfig | None = None,
        model_config: WaterModelConfig | None = None,
        control_period: float = 0.01,
        planner_config: PIIDMPCConfig | None = None,
    ):
        self.arm = arm
        self.config = planner_config if planner_config is not None else PIIDMPCConfig()
        self.n = arm.n_joints
        self.mpc = InverseDynamicsMPC(arm, config, control_period=control_period)
        self.control_period = self.mpc.control_period
        self.torque_limit = self.mpc.torque_limit
        self.model = PhysicsInformedModel(arm, model_config)
        self.estimator = self.model  # interface.DisturbanceEstimator
        remainder = self.model.config.remainder
        self.remainder = None if remainder.kind == "none" else DisturbanceObserver(arm, self.control_period, remainder)
        self._loaded: tuple[np.ndarray, np.ndarray, int] | None = None
        if self.mpc.qp is not None:
            self.mpc.qp.disturbance_model = self._along_plan
        cfg, pcfg = self.mpc.config, self.config
        self.planner = None
        # its IDMPC's rate-limited solves too: with the structured solver the target world with the rate
        # limit and the 20 Hz bandwidth diverged (DAQP: E_p 0.2980; real_loop_campaign.py, 2026-12-04)
        self.mpc.rate_solver = pcfg.planner_solver
        if pcfg.planner != "off":
            self.planner = HorizonQP(
                arm,
                self.control_period,
                pcfg.planner_horizon,
                per_joint(cfg.q_position, self.n, "q_position"),
                per_joint(cfg.q_velocity, self.n, "q_velocity"),
                self.mpc.r_acceleration,
                self.mpc.P,
                self.torque_limit,
                pcfg.planner_iterations,
                solver=pcfg.planner_solver,
                rate_solver=pcfg.planner_solver,  # measured: the planner's 35-step rate QPs, ~200 of 210 rows
            )  # active, hit the structured solver's iteration limit (docs/controllers.md)
            self.planner.disturbance_model = self._along_plan
            self.planner.iteration_budget = pcfg.planner_budget or None
            self._plan_offsets = np.arange(pcfg.planner_horizon + 1) * self.control_period
        self._saturated = False
        self.latent = LatentPlanner(self)
        self.reset()

    # --- memory -------------------------------------------------------------------
    def load_model(self, path: str | Path) -> None:
        """Start from the water model saved in ``path`` (now and after every ``reset``)."""
        self.model.load(path)
        self._loaded = (self.model.theta.copy(), self.model.covariance.copy(), self.model.samples)

    def save_model(self, path: str | Path) -> None:
        """Save the water model learned so far (JSON, :meth:`PhysicsInformedModel.save`)."""
        self.model.save(path)

    def reset(self) -> None:
        """Forget the run: the model goes back to the loaded one (or its prior), the observer to zero."""
        self.mpc.reset()
        if self.planner is not None:
            self.planner.forget()  # the rate solves' last working set
        self.model.reset()
        if self._loaded is not None:
            theta, covariance, samples = self._loaded
            self.model.theta, self.model.covariance, self.model.samples = theta.copy(), covariance.copy(), samples
        if self.remainder is not None:
            self.remainder.reset()
        self._saturated = False
        self._rest = np.zeros(self.n)
        self._commanded: np.ndarray | None = None
        self._learn_time = 0.0
        self._plan: tuple | None = None  # q, v, a (N, n), moves (N, n), multipliers (N n,), active (_replan)
        self._plan_step = 0
        self.plans = 0  # replans this run
        self.rejected = 0  # plans refused (planner_deviation, PLAN_TRUST)
        self.latent.reset()  # last: a worker process forks a copy of the controller as reset here

    # --- the controller interface ---------------------------------------------------
    def drive_limits(self, output: np.ndarray, step: np.ndarray) -> None:
        """The drives' rate limit for the next command (``output``, ``step`` (n,) N m:
        :meth:`~hydroarm.control.idmpc.InverseDynamicsMPC.drive_limits`; module docstring)."""
        self.mpc.drive_limits(output, step)

    def _fits(self, tau: np.ndarray) -> bool:
        """Whether the torque ``tau`` (n,) is within the limits, or the drives' rate box when told
        (:meth:`~hydroarm.control.idmpc.InverseDynamicsMPC.torque_box`; a NaN does not fit)."""
        lower, upper = self.mpc.torque_box()
        return bool(np.all((tau >= lower) & (tau <= upper)))

    def _held(self, mass, bias, a):
        """``(tau, a, saturated)`` realising ``a`` (n,) within the limits, or the drives' rate box
        when told (:func:`~hydroarm.control.idmpc_limits.box_allocate`: about a zero centre, the
        symmetric allocation bit for bit, tests/test_held_torque.py)."""
        return box_allocate(mass, bias, a, *self.mpc.torque_box())

    def _along_plan(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(w (N, n), M_A (N, n, n))`` at the planned states and accelerations (N, n) each:
        the model's force (+ the remainder's estimate), clipped to the torque limits, and its
        added-mass inertia."""
        added, rest = self.model.terms_along(q, v)  # one compiled pass over the plan
        # a plan far from feasible (light joints, long horizons) reaches speeds where |v| v drag
        # explodes; a force beyond the torque limit cannot be compensated anyway: hold it there
        w = water_along_plan(added, rest, np.ascontiguousarray(a, dtype=float), self._rest, self.torque_limit)
        return w, added

    # --- the planner ------------------------------------------------------------------
    def _replan(self, t, y, reference, idmpc_acceleration, warm, boxed=None) -> tuple | None:
        """The plan ``(q, v, a (N, n) each, moves (N, n), multipliers (N n,), active)`` from state y
        (2n,) at time t, or None (DAQP failed; refused by :func:`plan_refused` against the IDMPC's move
        ``idmpc_acceleration`` (n,) and ``boxed`` (its move in the rate box, or None), or by :data:`PLAN_TRUST`).
        ``warm``: ``(moves, multipliers, shift)`` of a last plan, started ``shift`` steps before, or None."""
        n, period = self.n, self.control_period
        q_r, v_r, a_r = sample_times(reference, t + self._plan_offsets)
        e0 = np.stack([y[:n] - q_r[0], y[n:] - v_r[0]], axis=1)
        c = reference_defects(q_r, v_r, a_r, period)  # (N, n, 2)
        # the IDMPC's own closed loop on the model, within the limits: the first plan's linearisation
        # point, and the scale of the plausibility check on every plan (PLAN_TRUST)
        rollout = self._rollout(t, y, reference, a_r)
        bound = PLAN_TRUST[0] * np.abs(rollout + a_r[:-1]).max(axis=0) + PLAN_TRUST[1]
        initial, initial_lam = rollout, None
        if warm is not None:  # warm start: the last plan's moves and working set, shifted by the steps between
            moves, lam, shift = warm
            initial = np.zeros_like(moves)
            initial[: moves.shape[0] - shift] = moves[shift:]
            initial_lam = np.zeros_like(lam)
            size = moves.size
            for start in range(0, lam.shape[0], size):  # the torque rows, and the rate rows below them
                initial_lam[start : start + size - shift * n] = lam[start + shift * n : start + size]
        rate = self.mpc.drive_rate if self.config.plan_latency == 0 else None  # beside the loop: not known yet
        if self.planner.solve(e0, c, q_r, v_r, a_r[:-1], None, None, None, initial, initial_lam, rate=rate) is None:
            return None
        moves = self.planner.last_moves
        q_p, v_p, a_p = predicted_plan(e0, c, moves, q_r, v_r, a_r[:-1], period)
        if plan_refused(a_p[0], (idmpc_acceleration, boxed), self.config.planner_deviation):
            self.rejected += 1  # far from the IDMPC's own move: a lighter plant than the model diverged
            return None
        if not (np.all(np.isfinite(a_p)) and np.all(np.abs(a_p[: self.config.planner_hold]) <= bound)):
            self.rejected += 1  # far outside the model's closed loop: the SQP left its basin
            return None
        self.plans += 1
        lam = np.asarray(self.planner.last_lam, dtype=float).copy()
        return q_p, v_p, a_p, moves.copy(), lam, self.planner.last_active

    def _rollout(self, t, y, reference, a_r) -> np.ndarray:
        """The moves (N, n) of the IDMPC with the torque allocation, run N steps on the double
        integrator from y with the dry model plus the water model (a plan within the limits):
        Pinocchio's terms per step, the rest compiled (:func:`~hydroarm.control.plan_rollout.rollout_step`)."""
        n, period, horizon = self.n, self.control_period, self.planner.horizon
        nominal, mpc = self.planner.nominal, self.mpc
        regressor = self.model.regressor
        strips, still = regressor.compiled_terms(self.model.theta)
        q, v = y[:n].copy(), y[n:].copy()
        moves = np.empty((horizon, n))
        # the IDMPC's reference at (t + k T) + i T for every rollout step k, in one call (the same times),
        # and its defects (as acceleration_from_samples forms them)
        times = (t + np.arange(horizon) * period)[:, None] + mpc._offsets[None, :]
        q_s, v_s, a_s = (x.reshape(times.shape + (n,)) for x in sample_times(reference, times.ravel()))
        c = reference_defects(q_s, v_s, a_s, period)  # (N, N_mpc, n, 2)
        a_ref = np.ascontiguousarray(a_r)
        for k in range(horizon):
            jac, djac = regressor.joint_jacobians(q, v)
            mass_upper = nominal.mass_matrix_upper(q)
            nle = nominal.nonlinear_effects(q, v)
            q, v, moves[k] = rollout_step(
                q, v, q_s[k, 0], v_s[k, 0], a_s[k, 0], c[k], mpc.P, mpc.K, mpc._g, period, a_ref[k], strips, still,
                jac, djac, mass_upper, nle, self._rest, self.torque_limit,
            )  # fmt: skip
        return moves

    def _follow_plan(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The plan's acceleration at this step plus the IDMPC's LQR feedback on the deviation from it."""
        return self._plan_acceleration(self._plan, self._plan_step, q, v)

    def _plan_acceleration(self, plan: tuple, k: int, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Step k of ``plan``'s acceleration plus the IDMPC's LQR feedback on the deviation from it."""
        q_p, v_p, a_p = plan[:3]
        gains = self.mpc.K
        return a_p[k] - gains[:, 0] * (q - q_p[k]) - gains[:, 1] * (v - v_p[k])

    def compute(self, t: float, y: np.ndarray, reference: Reference) -> ControlOutput:
        """The torque at state y (2n,). ``timings["learn"]`` (s): the last ``observe``'s learning
        (basis, RLS step, remainder), reported here (the runner records compute's timings only);
        ``"total"`` is this compute's, as for every controller (the benchmark adds ``observe``)."""
        learn_time, self._learn_time = self._learn_time, 0.0
        start = time.perf_counter()
        n = self.n
        y = np.asarray(y, dtype=float)
        q, v = y[:n], y[n:]
        acceleration = self.mpc.planned_acceleration(t, y, reference)
        t_plan = time.perf_counter()
        self._rest = self.remainder.feedforward() if self.remainder is not None else np.zeros(n)
        w_free, added_mass = self.water_terms(q, v)
        t_model = time.perf_counter()
        tau = None
        mass, bias = self.mpc.dynamics_terms(q, v, w_free, added_mass)  # M (+ M_A) and h - w, once per step
        latency = self.config.plan_latency if self.planner is not None else 0
        if latency > 0:
            tau, realised, saturated = self._latent_planned_torque(q, v, mass, bias)
        elif self.planner is not None:
            own = self.mpc.limited_torque(mass, bias, acceleration, w_free) if self.mpc.drive_rate is not None else None
            tau, realised, saturated = self._planned_torque(t, y, reference, acceleration, mass, bias, own)
            if tau is None and own is not None:
                tau, realised, saturated = own
        if tau is None:
            tau, realised, saturated = self.mpc.limited_torque(mass, bias, acceleration, w_free)
        t_torque = time.perf_counter()
        if latency > 0:  # the plan of step k + latency, from the state this step's move leads to
            fits = bool(np.all(np.abs(mass @ acceleration + bias) <= self.torque_limit))
            self.latent.launch(t, y, reference, tau, fits)
        self._saturated = bool(saturated.any())
        self._commanded = realised
        w_hat = w_free
        if added_mass is not None:
            w_hat = w_free - fixed_order.matvec(added_mass, np.ascontiguousarray(realised))
        end = time.perf_counter()
        timings = {
            "plan": t_plan - start,
            "model": t_model - t_plan,
            "torque": end - t_model,
            "learn": learn_time,
            "total": end - start,
        }
        if latency > 0:  # the plan's solve (LatentPlanner.timings); the torque's without it
            timings.update(self.latent.timings())
            timings["torque"] = t_torque - t_model
        return ControlOutput(
            tau=tau,
            status="saturated" if self._saturated else "ok",
            timings=timings,
            disturbance_mean=w_hat,
            acceleration=realised,
        )

    def water_terms(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """``(w_free (n,) N m, M_A (n, n) or None)`` at (q, v): the water model's force apart from its
        added mass plus the remainder's estimate of now (the estimate is ``w_free - M_A a``: the added
        mass joins the inertia), and the added mass; a non-finite force term is left out, and a
        non-finite term drops the added mass (None)."""
        added_mass, rest = self.model.terms(q, v)
        w_free = rest + self._rest
        if not (np.all(np.isfinite(w_free)) and np.all(np.isfinite(added_mass))):
            return np.where(np.isfinite(w_free), w_free, 0.0), None
        return w_free, added_mass

    def _planned_torque(self, t, y, reference, acceleration, mass, bias, own=None):
        """``(tau, a, saturated)`` from the planner, or ``(None, None, None)`` when it has nothing to
        say (``planner = "auto"``: the limits do not bind and no plan is running); ``mass``, ``bias``:
        the step's :meth:`~hydroarm.control.idmpc.InverseDynamicsMPC.dynamics_terms`; ``own``: the
        IDMPC's ``(tau, a, saturated)`` within the drives' rate box when told (the move a plan's
        deviation check compares with, module docstring), else None (its unconstrained
        ``acceleration``)."""
        n, mode, hold = self.n, self.config.planner, self.config.planner_hold
        q, v = y[:n], y[n:]
        if self._plan is not None:
            self._plan_step += 1
        if self._plan is None or self._plan_step >= hold:
            if mode == "auto" and (self._plan is None or not self.planner.last_active):
                self._plan = None
                if self._fits(mass @ acceleration + bias):
                    return None, None, None  # the IDMPC's own plan fits the limits
            warm = None if self._plan is None else (self._plan[3], self._plan[4], self._plan_step)
            boxed = None if own is None else own[1]
            self._plan, self._plan_step = self._replan(t, y, reference, acceleration, warm, boxed), 0
            if self._plan is None:
                return None, None, None
        a = self._follow_plan(q, v)
        return self._held(mass, bias, a)

    # --- the planner beside the loop (plan_latency > 0: hydroarm.control.plan_worker) -------
    def _latent_planned_torque(self, q, v, mass, bias):
        """``(tau, a, saturated)`` following the plan solved ``plan_latency`` steps ago for this
        step (or the one before it, within ``planner_hold`` steps; :meth:`LatentPlanner.take`), or
        ``(None, None, None)``."""
        self._plan, self._plan_step = self.latent.take(self._plan, self._plan_step)
        if self._plan is None:
            return None, None, None
        return self._held(mass, bias, self._follow_plan(q, v))

    def close(self) -> None:
        """Stop the planner's worker process, if one runs (``plan_worker = "process"``)."""
        latent = getattr(self, "latent", None)
        if latent is not None:
            latent.close()

    def observe(self, t: float, y: np.ndarray, u: np.ndarray, y_next: np.ndarray) -> None:
        """Learn the transition (the basis's added mass at the commanded acceleration, free of the
        sensor's noise); the remainder observer takes what the model does not predict."""
        start = time.perf_counter()
        commanded, self._commanded = self._commanded, None
        residual = self.model.learn(y, u, y_next, self.control_period, acceleration=commanded)
        if residual is not None and self.remainder is not None:
            y, y_next = np.asarray(y, dtype=float), np.asarray(y_next, dtype=float)
            q_mid, v_mid, a = self.model.transition_features(y, y_next, self.control_period)
            self.remainder.update(None, residual - self.model.predict(q_mid, v_mid, a), self._saturated)
        self._learn_time = time.perf_counter() - start
