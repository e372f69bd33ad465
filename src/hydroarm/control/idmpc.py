"""Inverse-dynamics MPC (hydroarm's own controller): an MPC in acceleration space, computed torque
underneath, an optional GP disturbance estimate fed forward, and the torque limits held.

Units: SI (rad, rad/s, rad/s^2, N m, s); n joints, control period T, horizon N steps.

Outer loop, per joint j, on the exact zero-order-hold double integrator (no linearisation
error; nothing to go unstable on a light wrist)::

    x_{k+1} = A x_k + B a_k,   x = [q_j, v_j],   A = [[1, T], [0, 1]],   B = [T^2/2, T]

minimising ``sum_{k<N} (x_k - x_r,k)' Q (x_k - x_r,k) + R_a,j (a_k - a_r,k)^2 + e_N' P_j e_N``
with ``Q = diag(q_position, q_velocity)``, ``R_a,j`` the joint's acceleration weight
(s^4/rad^2) and P_j (2, 2) the joint's discrete algebraic Riccati solution (the LQR's).

Acceleration weights (``r_scaling``). ``"authority"`` (default): every joint pays the same for
the same fraction of its torque. With ``m_j = M_jj(0) / tau_max,j`` (s^2/rad, the inverse of
the acceleration the joint's limit gives at q = 0)::

    R_a,j = max(r_acceleration * (m_j / max_i m_i)^2, r_floor)

The joint of least authority (typically the base) keeps ``r_acceleration``; a light wrist gets
a weight near ``r_floor``. As the weight goes to 0 the joint's LQR tends to the two-step
deadbeat law of the sampled double integrator (both closed-loop poles at 0), which has no
margin for a plant lighter than the model: ``r_floor`` keeps the lightest joints short of it.
``"uniform"``: ``R_a,j = r_acceleration``.

Delay margin (``delay_margin`` = m > 0, off by default): every ``R_a,j`` is floored at
:func:`~hydroarm.control.delay_design.delay_margin_weight`, the smallest weight whose LQR keeps
the joint's loop at a spectral radius of at most
:data:`~hydroarm.control.delay_design.MARGIN_RADIUS` (0.9) when its moves act m periods later than the loop
was told (the filter predicts across the told delay only): a closed-loop bandwidth chosen for a
stated margin (docs/robustness.md, section 6: what it buys and what it costs).

The told loop delay (``loop_delay`` = d, on by default; ``"plant"``: the filter's, resolved by
the registry): with d > 0 every ``R_a,j`` is floored at
:func:`~hydroarm.control.delay_design.told_delay_weight`, the smallest
weight whose loop, predicted across d periods on the dry model, keeps a spectral radius of at most
0.95 on a plant up to ``inertia_margin`` times heavier than the dry arm plus its own added mass
(:mod:`hydroarm.control.delay_design`). At d = 0 nothing changes.

Joint friction (``friction_feedforward``, issue 32): the arm's friction model (the ``friction``
section's values at the scale the controller is told: ``"arm"``, the nominal model whenever the
arm has joint friction, never the plant's ``friction.scale``) is fed forward at the reference
velocity by :class:`~hydroarm.control.friction_feedforward.FrictionFeedforward`, which the
registry puts around every ID-MPC (IDMPC, GP-IDMPC, PI-IDMPC and the observer variants); a
frictionless arm gets none, so the ideal loop and the paper mode are unchanged.

In the error e = x - x_r and move u = a - a_r the model is ``e_{k+1} = A e_k + B u_k + c_k``
with the reference's one-step defect ``c_k = x_r,k+1 - A x_r,k - B a_r,k`` (zero for a
reference of constant acceleration). With the DARE terminal weight, the unconstrained optimum
is the LQR law plus a preview of the defects::

    u_0 = -K e_0 - G (P c_0 + s_1),   s_N = 0,   s_k = (A - B K)' (P c_k + s_{k+1}),
    K = (R_a + B' P B)^-1 B' P A,    G = (R_a + B' P B)^-1 B'

Inner loop: computed torque ``tau = M(q) a_0 + h(q, v) - w_hat`` (n,) (one CRBA, one
nonlinear-effects call), with w_hat (n,) the disturbance estimate (sign: ``M q'' + h = tau +
w``) and zero without a GP.

Torque limits (``limits``, :mod:`hydroarm.control.idmpc_limits`; nothing changes while the
unconstrained torque fits): ``"qp"`` (default) the horizon's QP of all joints (DAQP) with the
torque rows at every step, frozen then SQP-linearised along the plan; ``"allocation"`` the joints
that fit keep their acceleration; ``"clip"`` each torque clipped alone (for comparison).

The drives' rate limit (issue 32; the loop's ``actuator.rate_limit`` r, N m/s): told it with the
drives' output before each command acts (:meth:`InverseDynamicsMPC.drive_limits`, called by the
state estimator's copy of the drives every step), the torque is held in the box
``tau_{-1} - r T <= tau <= tau_{-1} + r T`` (within the torque limits) as it is held within the
limits: nothing changes while the unconstrained torque fits the box; else the horizon QP with the
rate rows (:class:`~hydroarm.control.idmpc_limits.HorizonQP`) plans a torque ramp from the
drives' output, or the allocation (``limits``) holds the box. The command is what the drives
give. Never told (no rate limit): every path as before.

The GP's estimate under the rate limit is linearised in the acceleration the drives leave
(:mod:`hydroarm.control.drive_limits`, "The GP's estimate under the rate limit").

The GP (:class:`~hydroarm.control.gp.SlidingWindowGP`) learns a one-step residual of the dry
model (below), n outputs, from the state y (2n,) and, with ``gp_features = "state+acceleration"``
(default), the planned acceleration a_0 (n,) divided by ``acceleration_scale``: the water's added
mass answers the acceleration, which the state alone does not tell. The outer plan does not
depend on w_hat (only the torque rows do), so each step plans a_0 first, then asks the GP at (y,
a_0), then maps to torques; the sample added pairs that input with the residual the step showed.

The GP's target (``gp_residual``): the torque map holds tau over the period, so the estimate giving
the planned mean acceleration is the Euler residual ``M(q) (v+ - v) / T + h(q, v) - tau`` (``"euler"``,
``NominalModel.tde_residual``: the TDE's and PI-IDMPC's). ``"rk4"`` (the default, GP-IDMPC's published
numbers) is GP-MPC's target, the dry RK4 prediction's miss (``NominalModel.residual``), off by how the
dry acceleration turns within the period (docs/controllers.md, "The GP's target").

Behind a told loop delay d the filter hands ``observe`` a transition d steps old, from its revised
state: each sample takes the acceleration of the step that commanded it, found by its time
(:class:`~hydroarm.control.interface.StepLog`). What the estimate then feeds forward
(``gp_feedforward_delayed``, :class:`~hydroarm.control.delay_design.DelayedEstimate`): ``"none"``
(default; the loop is IDMPC's, bit for bit) or ``"designed"``, at the delayed observer's bandwidth;
at d = 0 all of it, as before. ``ControlOutput.disturbance_mean`` is the GP's estimate either way
(docs/robustness.md, "GP-IDMPC behind a delay").
"""

from __future__ import annotations

import time
from typing import Annotated, Literal

import numpy as np
import pydantic

from hydroarm.config import FrozenModel, per_joint
from hydroarm.control.delay_design import (
    INERTIA_MARGIN,
    DelayedEstimate,
    delay_margin_weight,
    told_delay_weight,
    wet_inertia_ratio,
)
from hydroarm.control.drive_limits import learned_added_mass, linearised_disturbance, rate_horizon
from hydroarm.control.gp import GPConfig, SlidingWindowGP
from hydroarm.control.idmpc_limits import HorizonQP, allocate, held_torque  # noqa: F401 (allocate: public here too)
from hydroarm.control.interface import (
    DEFAULT_CONTROL_PERIOD,
    ControlOutput,
    Reference,
    StepLog,
    require_period,
    sample_times,
)
from hydroarm.control.linear import joint_lqr, reference_defects, unconstrained_move  # noqa: F401 (public here too)
from hydroarm.model.arm.description import Arm
from hydroarm.model.dynamics.nominal import NominalModel

PositiveFloat = Annotated[float, pydantic.Field(gt=0.0, le=1e8)]
NonNegativeFloat = Annotated[float, pydantic.Field(ge=0.0, le=1e8)]
PositiveList = Annotated[list[PositiveFloat], pydantic.Field(min_length=1, max_length=12)]
NonNegativeList = Annotated[list[NonNegativeFloat], pydantic.Field(min_length=1, max_length=12)]


class IDMPCConfig(FrozenModel):
    """Settings of :class:`InverseDynamicsMPC`; per-joint fields take one value or a list of n."""

    horizon: int = pydantic.Field(5, ge=1, le=500, description="prediction horizon N (steps)")
    q_position: PositiveFloat | PositiveList = pydantic.Field(
        300.0, description="Q weight on the joint position error (1/rad^2)"
    )
    q_velocity: NonNegativeFloat | NonNegativeList = pydantic.Field(
        0.01, description="Q weight on the joint velocity error (s^2/rad^2)"
    )
    r_acceleration: PositiveFloat | PositiveList = pydantic.Field(
        1e-5, description="R_a weight on the acceleration move a - a_r (s^4/rad^2)"
    )
    r_scaling: Literal["uniform", "authority"] = pydantic.Field(
        "authority", description="per-joint R_a: r_acceleration, or scaled by the torque authority (docstring)"
    )
    delay_margin: int = pydantic.Field(
        0,
        ge=0,
        le=5,
        description="periods of loop delay beyond the told one each joint's loop must stay stable with "
        "(delay_margin_weight); 0 = off, the ideal loop's weights (0-5)",
    )
    loop_delay: int | Literal["plant"] = pydantic.Field(
        "plant",
        description="loop delay (periods, 0-1000) the bandwidth is designed for (told_delay_weight); plant = the one "
        "the state estimator predicts across (sensor.delay + actuator.delay behind the filter, else 0)",
    )
    inertia_margin: float = pydantic.Field(
        INERTIA_MARGIN,
        ge=1.0,
        le=10.0,
        description="at the told loop delay each joint stays stable on a plant up to this many times heavier than "
        "the dry arm plus its own Morison added mass (1-10; docs/robustness.md)",
    )
    friction_feedforward: NonNegativeFloat | Literal["arm"] = pydantic.Field(
        "arm",
        description="scale (0-1e8) of the arm's friction model (the friction section's values) fed forward at the "
        "reference velocity; arm = 1 when the arm has joint friction (friction.scale > 0), else 0: never the "
        "plant's scale (hydroarm.control.friction_feedforward)",
    )
    r_floor: PositiveFloat = pydantic.Field(
        1e-6, description="lower bound of the authority-scaled R_a (s^4/rad^2), in (0, 1e8]"
    )
    limits: Literal["allocation", "qp", "clip"] = pydantic.Field(
        "qp", description="how a torque beyond its limit is handled (module docstring)"
    )
    sqp_iterations: int = pydantic.Field(
        1, ge=0, le=10, description="limits = 'qp': relinearisations of the torque rows along the plan (0-10)"
    )
    min_samples: int = pydantic.Field(2, ge=1, le=10_000, description="GP window samples before feeding forward")
    gp_features: Literal["state", "state+acceleration"] = pydantic.Field(
        "state+acceleration", description="GP inputs: the state, or the state and the planned acceleration a_0"
    )
    acceleration_scale: PositiveFloat = pydantic.Field(
        100.0, description="divisor of a_0 in the GP's inputs (rad/s^2 per input unit)"
    )
    gp_residual: Literal["euler", "rk4"] = pydantic.Field(
        "rk4",
        description="the GP's target: euler, the torque map's residual M(q)(v+ - v)/T + h - u, or rk4, "
        "the dry RK4 prediction's miss (module docstring)",
    )
    gp_feedforward_delayed: Literal["none", "designed"] = pydantic.Field(
        "none",
        description="behind a told loop delay, what the GP's estimate feeds forward: none (the GP learns, "
        "the loop is IDMPC's) or designed (at the delayed observer's bandwidth; module docstring)",
    )

    @pydantic.field_validator("loop_delay", mode="before")
    @classmethod
    def _loop_delay_in_range(cls, value):
        if value == "plant":
            return value
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 1000:
            raise ValueError(f"must be 'plant' or a whole number of periods 0 <= x <= 1000, got {value!r}")
        return value


def gp_input_size(features: str, n_joints: int) -> int:
    """The GP's input count d for ``gp_features`` on n joints: 2n (state) or 3n (+ a_0)."""
    return 3 * n_joints if features == "state+acceleration" else 2 * n_joints


def authority_weights(inertia: np.ndarray, torque_limit: np.ndarray, r_acceleration: np.ndarray, r_floor: float):
    """The authority-scaled ``R_a`` (n,) (module docstring) from the diagonal ``inertia`` M_jj (n,)
    kg m^2, the ``torque_limit`` (n,) N m and the unscaled ``r_acceleration`` (n,) s^4/rad^2."""
    inverse_authority = np.asarray(inertia, dtype=float) / np.asarray(torque_limit, dtype=float)  # s^2/rad
    return np.maximum(r_acceleration * (inverse_authority / inverse_authority.max()) ** 2, r_floor)


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
        control_period: float = DEFAULT_CONTROL_PERIOD,
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
        self.torque_limit = per_joint(arm.torque_limit, n, "torque_limit")  # the arm's actuators
        if cfg.r_scaling == "authority":
            r_acc = authority_weights(np.diag(arm.mass_matrix(np.zeros(n))), self.torque_limit, r_acc, cfg.r_floor)
        if cfg.delay_margin > 0:  # each joint's bandwidth capped for the stated margin
            floor = [delay_margin_weight(self.control_period, q_pos[j], q_vel[j], cfg.delay_margin) for j in range(n)]
            r_acc = np.maximum(r_acc, floor)
        delay = 0 if cfg.loop_delay == "plant" else int(cfg.loop_delay)
        if delay > 0:  # each joint's bandwidth for the told delay on the heavier wet arm (delay_design)
            low = wet_inertia_ratio(arm) / cfg.inertia_margin
            r_acc = np.array(
                [told_delay_weight(self.control_period, q_pos[j], q_vel[j], r_acc[j], delay, low[j]) for j in range(n)]
            )
        self.r_acceleration = r_acc
        self.P = np.empty((n, 2, 2))
        self.K = np.empty((n, 2))
        self._g = np.empty((n, 2))
        for j in range(n):
            self.P[j], self.K[j], self._g[j] = joint_lqr(self.control_period, q_pos[j], q_vel[j], r_acc[j])
        self._offsets = np.arange(cfg.horizon + 1) * self.control_period
        self.qp = None
        self.rate_qp = None  # the horizon QP with the drives' rate rows (built when the rate is told)
        self.rate_solver: str | None = None  # its solver (None: idmpc_limits.RATE_SOLVER; PI-IDMPC sets its own)
        if cfg.limits == "qp":
            self.qp = HorizonQP(
                arm,
                self.control_period,
                cfg.horizon,
                q_pos,
                q_vel,
                r_acc,
                self.P,
                self.torque_limit,
                cfg.sqp_iterations,
            )
        self.n_gp_inputs = gp_input_size(cfg.gp_features, n)
        self.gp = SlidingWindowGP(self.n_gp_inputs, n, gp_config) if gp_config is not None else None
        self.estimator = self.gp  # interface.DisturbanceEstimator (None: no GP)
        self._gp_samples = StepLog(self.control_period)  # each step's sample acceleration, by the step's time
        self._gp_fed = DelayedEstimate(delay, cfg.gp_feedforward_delayed)  # what of it is fed forward
        # load the compiled code now, not in the first control steps (a throwaway GP: same config)
        unconstrained_move(np.zeros((n, 2)), np.zeros((1, n, 2)), self.P, self.K, self._g, self.control_period)
        if gp_config is not None:
            warm = SlidingWindowGP(self.n_gp_inputs, n, gp_config)
            for k in range(2):
                warm.update(np.full(self.n_gp_inputs, 0.1 * k), np.full(n, 0.1 * k))
            warm.update_hyperparameters()
            warm.predict(np.zeros(self.n_gp_inputs))
        self.reset()

    def reset(self) -> None:
        """Forget the GP window, the counters and the rate QP's last working set."""
        if self.gp is not None:
            self.gp.reset()
        if self.rate_qp is not None:  # the last run's working set and linearised estimate
            self.rate_qp.forget()
            if self.gp is not None:
                self.rate_qp.disturbance_model = self.qp.disturbance_model
        self.saturated_steps = 0
        self.drive_rate: tuple[np.ndarray, np.ndarray] | None = None  # the drives' (output, r T) for the next command
        self._pending_events: list[str] = []
        self._gp_input: np.ndarray | None = None  # the GP input of the last compute
        self._gp_samples.clear()
        self._gp_fed.reset()

    def drive_limits(self, output: np.ndarray, step: np.ndarray) -> None:
        """Tell the drives' rate limit for the next command: ``output`` (n,) N m, the torque the
        drives give in the period before it acts, and ``step`` (n,) N m, the most it may differ
        from it (``rate_limit T``): the torque is held in that box (module docstring)."""
        self.drive_rate = (np.asarray(output, dtype=float), np.asarray(step, dtype=float))
        horizon = rate_horizon(self.config.horizon, self.torque_limit, self.drive_rate[1])
        if self.qp is not None and (self.rate_qp is None or self.rate_qp.horizon != horizon):
            cfg, n = self.config, self.n
            self.rate_qp = HorizonQP(
                self.arm, self.control_period, horizon,
                per_joint(cfg.q_position, n, "q_position"), per_joint(cfg.q_velocity, n, "q_velocity"),
                self.r_acceleration, self.P, self.torque_limit, cfg.sqp_iterations, rate_solver=self.rate_solver,
            )  # fmt: skip
            self.rate_qp.disturbance_model = self.qp.disturbance_model
            self._rate_offsets = np.arange(horizon + 1) * self.control_period

    def torque_box(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lower, upper)`` (n,) N m: the torque limits, within ``output -+ step`` when the drives'
        rate limit is told (:meth:`drive_limits`; never empty: the rate box is clipped into the limits)."""
        if self.drive_rate is None:
            return -self.torque_limit, self.torque_limit
        output, step = self.drive_rate
        lower = np.clip(output - step, -self.torque_limit, self.torque_limit)
        return lower, np.clip(output + step, -self.torque_limit, self.torque_limit)

    # --- pieces (public for tests) ------------------------------------------------------
    def planned_acceleration(
        self, t: float, y: np.ndarray, reference: Reference, *, remember: bool = True
    ) -> np.ndarray:
        """The outer MPC's first acceleration a_0 (n,) rad/s^2 at measured state y (2n,).

        ``remember``: keep this step's horizon problem for :meth:`constrained_acceleration` (the
        torque rows of this step); False for a look-ahead at another state or time (e.g. PI-IDMPC's
        rollout of this MPC along a plan), which leaves the step's problem as it was."""
        if remember and self.drive_rate is not None and self.rate_qp is not None:  # the rate QP's longer horizon
            q_r, v_r, a_r = sample_times(reference, t + self._rate_offsets)  # (N_r + 1, n) each
            n, period, horizon = self.n, self.control_period, self.config.horizon
            e0 = np.stack([y[:n] - q_r[0], y[n:] - v_r[0]], axis=1)
            c = reference_defects(q_r, v_r, a_r, period)  # (N_r, n, 2)
            self._last_problem = (e0, c, a_r[:-1], q_r, v_r)
            return a_r[0] + unconstrained_move(e0, c[:horizon], self.P, self.K, self._g, period)
        q_r, v_r, a_r = sample_times(reference, t + self._offsets)  # (N + 1, n) each
        return self.acceleration_from_samples(y, q_r, v_r, a_r, remember=remember)

    def acceleration_from_samples(
        self, y: np.ndarray, q_r: np.ndarray, v_r: np.ndarray, a_r: np.ndarray, *, remember: bool = True
    ) -> np.ndarray:
        """:meth:`planned_acceleration` with the reference already sampled at ``t + k T``,
        k = 0..N: ``q_r, v_r, a_r`` (N + 1, n) each (a look-ahead samples many steps in one call)."""
        n, period = self.n, self.control_period
        e0 = np.stack([y[:n] - q_r[0], y[n:] - v_r[0]], axis=1)
        c = reference_defects(q_r, v_r, a_r, period)  # (N, n, 2)
        if remember:
            self._last_problem = (e0, c, a_r[:-1], q_r, v_r)
        return a_r[0] + unconstrained_move(e0, c, self.P, self.K, self._g, period)

    def constrained_acceleration(self, mass: np.ndarray, bias: np.ndarray, w_hat: np.ndarray) -> np.ndarray | None:
        """The first acceleration (n,) of the horizon's QP with the torque rows (``limits =
        "qp"``, :class:`~hydroarm.control.idmpc_limits.HorizonQP`) for the problem of the last
        :meth:`planned_acceleration` that kept it (``remember``); ``bias`` = h - w_hat (n,); None if
        DAQP fails."""
        e0, c, a_r, q_r, v_r = self._last_problem
        if self.drive_rate is not None and self.rate_qp is not None and c.shape[0] == self.rate_qp.horizon:
            return self.rate_qp.solve(e0, c, q_r, v_r, a_r, mass, bias, w_hat, rate=self.drive_rate)
        return self.qp.solve(e0, c, q_r, v_r, a_r, mass, bias, w_hat)

    def torque_map(
        self, q: np.ndarray, v: np.ndarray, acceleration: np.ndarray, w_hat: np.ndarray,
        added_mass: np.ndarray | None = None,
    ):  # fmt: skip
        """``(tau, a, saturated)``: the torques (n,) realising ``acceleration`` on the dry model
        minus the estimate ``w_hat`` (n,), within the limits (``config.limits``). ``added_mass``
        (n, n) kg m^2: a model's added-mass inertia, added to M(q) (the estimate is then
        ``w_hat - M_A a`` at whatever acceleration the limits leave)."""
        mass, bias = self.dynamics_terms(q, v, w_hat, added_mass)
        return self.limited_torque(mass, bias, acceleration, w_hat)

    def dynamics_terms(
        self, q: np.ndarray, v: np.ndarray, w_hat: np.ndarray, added_mass: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(M, bias)``: the dry model's mass matrix (n, n) at q, plus ``added_mass`` if given,
        and ``h(q, v) - w_hat`` (n,) N m."""
        mass = self.nominal.mass_matrix(q)
        if added_mass is not None:
            mass = mass + added_mass
        return mass, self.nominal.nonlinear_effects(q, v) - w_hat

    def limited_torque(self, mass: np.ndarray, bias: np.ndarray, acceleration: np.ndarray, w_hat: np.ndarray):
        """:meth:`torque_map` on given :meth:`dynamics_terms`: the torque held in :meth:`torque_box`
        (:func:`~hydroarm.control.idmpc_limits.held_torque`; told the drives' rate, the QP runs every step)."""
        lower, upper = self.torque_box()
        return held_torque(
            self.config.limits, mass, bias, acceleration, lower, upper,
            lambda: self.constrained_acceleration(mass, bias, w_hat), plan_always=self.drive_rate is not None,
        )  # fmt: skip

    def gp_input(self, y: np.ndarray, acceleration: np.ndarray) -> np.ndarray:
        """The GP's input (2n,) or (3n,) for the state y (2n,) and planned acceleration a_0 (n,)."""
        if self.n_gp_inputs == 2 * self.n:
            return y.copy()
        return np.concatenate([y, acceleration / self.config.acceleration_scale])

    # --- the controller interface ---------------------------------------------------------
    def compute(
        self, t: float, y: np.ndarray, reference: Reference, feedforward_torque: np.ndarray | None = None
    ) -> ControlOutput:
        """The torque (n,) N m at measured state y (2n,). ``feedforward_torque`` (n,) N m: an
        outside disturbance estimate (an observer's, :mod:`hydroarm.control.observers`) added to
        the GP's (zero without a GP) in the torque map and the torque rows."""
        start = time.perf_counter()
        n = self.n
        y = np.asarray(y, dtype=float)
        acceleration = self.planned_acceleration(t, y, reference)
        t_plan = time.perf_counter()
        mean = np.zeros(n)
        var = None
        if self.gp is not None:
            var = np.full(n, np.nan)
            self._gp_input = self.gp_input(y, acceleration)
            if self.gp.n_samples >= self.config.min_samples:
                _, events = self.gp.update_hyperparameters(return_events=True)
                mean, var, predicted = self.gp.predict(self._gp_input, return_events=True)
                self._pending_events.extend((*events, *predicted))
                if not np.all(np.isfinite(mean)):
                    self._pending_events.append("gp_nonfinite_prediction")
                    mean = np.where(np.isfinite(mean), mean, 0.0)
        fed = self._gp_fed.feed(mean) if self.gp is not None else mean  # behind a delay: what of it acts
        if feedforward_torque is not None:
            mean, fed = mean + feedforward_torque, fed + feedforward_torque
        t_gp = time.perf_counter()
        added_mass = self._learned_added_mass() if self.gp is not None and self.drive_rate is not None else None
        if added_mass is None:
            tau, realised, saturated = self.torque_map(y[:n], y[n:], acceleration, fed)
        else:  # the estimate linearised in the acceleration the drives leave (module docstring)
            w_free = fed + added_mass * acceleration
            if self.rate_qp is not None:  # the rate QP's rows take it linearised too
                self.rate_qp.disturbance_model = linearised_disturbance(w_free, added_mass)
            tau, realised, saturated = self.torque_map(y[:n], y[n:], acceleration, w_free, np.diag(added_mass))
            if self.n_gp_inputs == 3 * n:  # the sample pairs the residual with the acceleration given
                acceleration = realised
        if self.gp is not None:
            self._gp_samples.record(t, acceleration)
        self.saturated_steps += bool(saturated.any())
        end = time.perf_counter()
        events, self._pending_events = tuple(self._pending_events), []
        return ControlOutput(
            tau=tau,
            status="saturated" if saturated.any() else "ok",
            timings={"plan": t_plan - start, "gp": t_gp - t_plan, "torque": end - t_gp, "total": end - start},
            disturbance_mean=mean if self.gp is not None else None,
            disturbance_var=var,
            events=events,
            acceleration=realised,
        )

    def _learned_added_mass(self) -> np.ndarray | None:
        """The GP's added mass (n,) kg m^2 at the last GP input (:func:`learned_added_mass`); None
        without acceleration inputs, before the GP feeds forward or while it feeds nothing (behind a delay)."""
        if self.n_gp_inputs != 3 * self.n or self.gp.n_samples < self.config.min_samples or self._gp_fed.off:
            return None
        return learned_added_mass(self.gp, self._gp_input, self.n, self.config.acceleration_scale)

    def gp_target(self, y: np.ndarray, u: np.ndarray, y_next: np.ndarray) -> np.ndarray:
        """The GP's target (n,) N m of the step y -> y_next (2n,) under u (n,) N m (``gp_residual``)."""
        if self.config.gp_residual == "euler":
            return self.nominal.tde_residual(y, u, y_next, self.control_period)
        return self.nominal.residual(y, u, y_next, self.control_period)[0]

    def observe(self, t: float, y: np.ndarray, u: np.ndarray, y_next: np.ndarray) -> None:
        """Add the disturbance seen over the last step to the GP window (no-op without a GP): the
        input of the last :meth:`compute` (at ``y``) with the residual of the step to ``y_next``."""
        if self.gp is None:
            return
        y = np.asarray(y, dtype=float)
        residual = self.gp_target(y, u, y_next)
        planned = self._gp_samples.at(t)  # behind a delay, y is the filter's revised state: found by time
        gp_input = self.gp_input(y, planned if planned is not None else np.zeros(self.n))
        if not (np.all(np.isfinite(residual)) and np.all(np.isfinite(gp_input))):
            self._pending_events.append("gp_sample_rejected")
            return
        self.gp.update(gp_input, residual)
