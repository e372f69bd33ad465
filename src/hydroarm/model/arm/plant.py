"""The true underwater plant: rigid body + water + current (+ friction), integrated by RK4.

State x = [q, v] (rad, rad/s), shape (2n,); input tau (N m), shape (n,), held
constant over a control period (zero-order hold). The plant integrates
``(M + M_A) (q'' - d_c(t)) = tau - C v - G - h_A + drag + buoyancy - b v`` with
classic RK4 in inner steps of at most ``PlantConfig.inner_step``; the measured
state adds seeded Gaussian noise to q and v only; the true state is never touched.
The dry model the controllers know is :class:`hydroarm.model.dynamics.nominal.NominalModel`.

``UnderwaterPlant.step`` runs everything but three Pinocchio calls per RK4 stage in
one compiled kernel; :meth:`UnderwaterPlant.step_numpy` is its plain-NumPy twin
(:func:`hydroarm.model.dynamics.integrator.rk4_step` over :meth:`WaterModel.dynamics`), the
same operations in the same order (bit-identical; a test compares them; the speed
ratio is in ``bench/results``). ``StepInfo.disturbance`` is the generalised force
the dry model lacks, ``M(q) q'' + C v + G - tau``.

The real loop (issue 23) is held by the plant too: the joint friction of a geared arm
(:class:`~hydroarm.model.real_loop.friction.FrictionConfig`, Coulomb + Stribeck + viscous, inside the
RK4 stages), and, per run, the sensor and the drives (:meth:`UnderwaterPlant.new_sensor`,
:meth:`UnderwaterPlant.new_actuator`; :mod:`hydroarm.model.real_loop.sensing`). With their defaults
(all off) every number is the idealised loop's, bit for bit.
"""

from __future__ import annotations

import numba
import numpy as np
import pinocchio as pin
import pydantic
import scipy.linalg
from numba.core import types
from numba.experimental import structref

from hydroarm.config import ConfigError, FrozenModel, per_joint
from hydroarm.model.arm.description import Arm
from hydroarm.model.dynamics.integrator import (
    StepInfo,
    inner_step_setting,
    inner_steps,
    rk4_disturbance_stage,
    rk4_step,
)
from hydroarm.model.real_loop.friction import FrictionConfig, friction_torque
from hydroarm.model.real_loop.sensing import Actuator, ActuatorConfig, Sensor, SensorConfig
from hydroarm.model.water.current import current_at
from hydroarm.model.water.effects import DRAG_REYNOLDS
from hydroarm.model.water.morison import Water, WaterModel, added_mass_matrix
from hydroarm.model.water.strips import solve_underwater, water_terms

STIFFNESS_LIMIT = 2.5
"""Bound on ``friction * inner_step / lambda_min(M + M_A)`` (classic RK4 is stable on the
negative real axis up to 2.785; the smallest joint-space inertia is taken at q = 0)."""


class PlantConfig(FrozenModel):
    """Integration and sensing of the true plant.

    ``inner_step`` (s, in [1e-5, 0.1]): the RK4 step (the control period is divided into equal
    steps no longer than this); ``friction`` (N m s/rad): joint viscous friction,
    0 = off (the paper reading's default); it must also be soft enough for explicit RK4 on the
    arm (:class:`UnderwaterPlant` checks ``friction * inner_step`` against the
    arm's smallest joint-space inertia); ``noise_variance`` (rad^2 and (rad/s)^2): variance of
    the zero-mean Gaussian measurement noise on q and v (0.001 in the paper's
    Table 2).
    """

    inner_step: float = inner_step_setting(1e-3, "the fixed-base plant")
    friction: float = pydantic.Field(0.0, ge=0.0, le=1e4, description="joint viscous friction, 0 = off (N m s/rad)")
    noise_variance: float = pydantic.Field(
        0.0, ge=0.0, le=10.0, description="variance of the Gaussian measurement noise on q and v (rad^2, (rad/s)^2)"
    )
    compiled: bool = pydantic.Field(
        False, description="step with the compiled plant (hydroarm.model.arm.fast: one call per control period)"
    )
    drag_points: int | None = pydantic.Field(
        None, ge=1, le=16, description="Gauss points per drag piece of the compiled plant; unset = water's (-)"
    )

    @pydantic.model_validator(mode="after")
    def _drag_points_need_compiled(self) -> PlantConfig:
        if self.drag_points is not None and not self.compiled:
            raise ValueError("plant.drag_points applies to the compiled plant only: set plant.compiled = true")
        return self


def _live_views(model: pin.Model, data: pin.Data):
    """``(data.M, data.J, data.dJ)`` as arrays that follow later Pinocchio calls, or None.

    eigenpy (Pinocchio's bindings) returns these members as views of the Eigen
    storage, so fetching them once per plant step instead of once per stage saves
    three attribute look-ups (and, for the Jacobians, a reshape copy) per stage.
    Checked on this workspace: the view fetched before two CRBA calls at different
    configurations must show the second result; if not (other bindings), None and
    the caller fetches the members after every call.
    """
    view = data.M
    q = pin.neutral(model)
    pin.crba(model, data, q)
    first = data.M.copy()
    pin.crba(model, data, pin.integrate(model, q, np.full(model.nv, 0.5)))
    live = bool(not np.array_equal(view, first) and np.array_equal(view, data.M))
    return (data.M, data.J, data.dJ) if live else None


class UnderwaterPlant:
    """The true plant (see the module docstring). Owns its Pinocchio workspace and its
    :class:`~hydroarm.model.water.morison.WaterModel`: one plant per thread."""

    def __init__(
        self,
        arm: Arm,
        water: Water | None = None,
        config: PlantConfig | None = None,
        friction: FrictionConfig | None = None,
        sensor: SensorConfig | None = None,
        actuator: ActuatorConfig | None = None,
    ):
        self.arm = arm
        self.water = water if water is not None else Water()
        self.config = config if config is not None else PlantConfig()
        self.friction = friction if friction is not None else FrictionConfig()
        self.sensor = sensor if sensor is not None else SensorConfig()
        self.actuator = actuator if actuator is not None else ActuatorConfig()
        self.water_model = WaterModel(arm, self.water)
        self.inner_step = self.config.inner_step
        self.n = arm.n_joints
        self.data = arm.create_data()
        self._views = _live_views(arm.model, self.data)
        self.joint_friction = self.friction.active
        if self.joint_friction:
            self._friction_arrays = self.friction.arrays(self.n)
        else:
            zero = np.zeros(self.n)
            self._friction_arrays = (zero, zero, zero, np.ones(self.n), np.ones(self.n))
        self._joints = _new_joint_friction(float(self.config.friction), self.joint_friction, self._friction_arrays)
        self._work_arrays = (np.empty(2 * self.n), np.empty(2 * self.n), np.empty((4, 2 * self.n)),
                             np.empty((4, self.n)), np.empty(self.n))  # fmt: skip
        self._work = _new_rk4_work(self._work_arrays)
        for name, values in (("actuator.torque_limit", self.actuator.torque_limit),
                             ("actuator.rate_limit", self.actuator.rate_limit),
                             ("actuator.bandwidth", self.actuator.bandwidth)):  # fmt: skip
            if values is not None:
                per_joint(values, self.n, name)
        self._check_friction()
        self.fast = None
        if self.config.compiled:
            from hydroarm.model.arm.fast import FastArmDynamics

            self.fast = FastArmDynamics(arm, self.water, float(self.config.friction), self.friction,
                                        self.config.drag_points)  # fmt: skip

    def _inertia(self) -> np.ndarray:
        q = pin.neutral(self.arm.model)
        inertia = self.arm.mass_matrix(q, data=self.data)
        if self.water.added_mass:
            inertia = inertia + added_mass_matrix(self.arm, self.water, q)
        return inertia

    def _check_friction(self) -> None:
        """Raise :class:`ConfigError` if the joint friction is too stiff for RK4 at ``inner_step``:
        ``friction * inner_step / lambda_min(M(0) + M_A(0)) <= STIFFNESS_LIMIT`` for the uniform
        viscous ``plant.friction``; with the joint friction model, ``inner_step *
        lambda_max(M^-1 D) <= STIFFNESS_LIMIT`` where D = diag(plant.friction + the model's largest
        slope per joint, F_s / w + F_v) and M = M(0) + M_A(0): there the plant shortens its RK4
        step (``self.inner_step``) to meet the bound instead (the friction model is stiff by
        design near v = 0; ``plant.inner_step`` stays the longest step)."""
        if self.joint_friction:
            slopes = self.config.friction + self.friction.max_slope(self.n)
            rate = float(scipy.linalg.eigh(np.diag(slopes), self._inertia(), eigvals_only=True)[-1])
            self.inner_step = min(self.inner_step, STIFFNESS_LIMIT / rate)
            return
        friction = self.config.friction
        if friction == 0.0:
            return
        inertia = self._inertia()
        smallest = float(np.linalg.eigvalsh(inertia)[0])
        limit = STIFFNESS_LIMIT * smallest / self.inner_step
        if friction > limit:
            raise ConfigError(
                f"plant.friction = {friction!r}: too stiff for RK4 with plant.inner_step = {self.inner_step!r} s "
                f"on arm '{self.arm.name}': must be <= {limit:.3g} N m s/rad (smallest joint-space inertia "
                f"{smallest:.3g} kg m^2), or use a smaller inner_step"
            )

    # --- the dynamics at one instant ------------------------------------------------------
    def friction_torque(self, v: np.ndarray) -> np.ndarray:
        """The joint friction model's torque (N m, (n,)) at joint velocities v (rad/s, (n,)):
        :func:`~hydroarm.model.real_loop.friction.friction_torque` (zeros when it is off); ``plant.friction``
        not included."""
        if not self.joint_friction:
            return np.zeros(self.n)
        return friction_torque(np.asarray(v, dtype=float), *self._friction_arrays)

    def dynamics(self, t: float, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """True ``(q'' (rad/s^2), disturbance (N m))`` at (t, q, v, tau), each (n,)."""
        if not self.joint_friction:
            return self.water_model.dynamics(q, v, tau, t, self.config.friction)
        friction = self.friction_torque(v)
        acc, disturbance = self.water_model.dynamics(q, v, tau - friction, t, self.config.friction)
        return acc, disturbance - friction

    def acceleration(self, t: float, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """True q'' (rad/s^2), shape (n,)."""
        return self.dynamics(t, q, v, tau)[0]

    def disturbance(self, t: float, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Generalised force (N m) beyond the dry model at (t, q, v, tau), shape (n,)."""
        return self.dynamics(t, q, v, tau)[1]

    # --- integration ------------------------------------------------------------------
    def step(self, t: float, x: np.ndarray, tau: np.ndarray, dt: float) -> tuple[np.ndarray, StepInfo]:
        """Integrate from (t, x) over dt (s) under constant tau: ``(x_next (2n,), StepInfo)``.

        Classic RK4 in ``ceil(dt / inner_step)`` equal steps, everything but the
        three Pinocchio calls per stage (CRBA, NLE, Jacobians and their time
        variation) in one compiled call (:func:`rk4_stage_kernel`). A state that
        stops being finite (a diverging run) gives an all-NaN ``x_next`` and
        disturbance instead of an exception from the solve; the runner reports it
        as ``diverged``. With ``plant.compiled`` the whole period is one call of
        :class:`~hydroarm.model.arm.fast.FastArmDynamics` instead.
        """
        if self.fast is not None:
            x_next, average, start = self.fast.step(t, x, tau, dt, self.inner_step)
            return x_next, StepInfo(disturbance=average, disturbance_start=start)
        n = self.n
        steps, h = inner_steps(dt, self.inner_step)
        state, stage_state, _, disturbances, average = self._work_arrays
        state[:] = x  # the kernel updates the state in place
        stage_state[:] = state
        average[:] = 0.0
        tau = np.ascontiguousarray(tau, dtype=float)
        q, v = stage_state[:n], stage_state[n:]
        start = None
        model, data = self.arm.model, self.data
        strips, joints, work = self.water_model.strips, self._joints, self._work
        live = self._views
        time = t
        for _ in range(steps):
            half = time + 0.5 * h
            for stage, stage_time in enumerate((time, half, half, time + h)):
                pin.crba(model, data, q)
                nonlinear = pin.nonLinearEffects(model, data, q, v)
                pin.computeJointJacobiansTimeVariation(model, data, q, v)
                mass, jac, djac = live if live is not None else (data.M, data.J, data.dJ)
                try:
                    rk4_stage_kernel(stage, stage_time, h, tau, mass, nonlinear, jac, djac, strips, joints, work)
                except np.linalg.LinAlgError:  # the solve met an infinite force: diverged
                    stage_state[:] = np.nan
                    break
            if not np.all(np.isfinite(stage_state)):  # diverged: NaN out, the caller reports it
                nan = np.full(n, np.nan)
                return np.full(2 * n, np.nan), StepInfo(disturbance=nan, disturbance_start=nan.copy())
            if start is None:
                start = disturbances[0].copy()
            time += h
        return state.copy(), StepInfo(disturbance=average / (6.0 * steps), disturbance_start=start)

    def step_numpy(self, t: float, x: np.ndarray, tau: np.ndarray, dt: float) -> tuple[np.ndarray, StepInfo]:
        """:meth:`step` in plain NumPy: :func:`~hydroarm.model.dynamics.integrator.rk4_step` over
        :meth:`WaterModel.dynamics` (the twin tests compare :meth:`step` with)."""
        n = self.n
        steps, h = inner_steps(dt, self.inner_step)
        x = np.asarray(x, dtype=float)
        average = np.zeros(n)
        start = None
        time = t
        stages: list[np.ndarray] = []

        def f(s: float, y: np.ndarray) -> np.ndarray:
            acc, dist = self.dynamics(s, y[:n], y[n:], tau)
            stages.append(dist)
            return np.concatenate([y[n:], acc])

        for _ in range(steps):
            stages.clear()
            x = rk4_step(f, time, x, h)
            if start is None:
                start = stages[0]
            average += stages[0] + 2.0 * stages[1] + 2.0 * stages[2] + stages[3]
            time += h
        average /= 6.0 * steps
        return x, StepInfo(disturbance=average, disturbance_start=start)

    # --- the plant protocol (hydroarm.sim.plant_protocol.Plant), sensing and actuation ----------------
    @property
    def n_inputs(self) -> int:
        """Length of the input ``tau`` of :meth:`step` (the joint torques)."""
        return self.n

    @property
    def state_size(self) -> int:
        """Length of the state x = [q, v]."""
        return 2 * self.n

    def joint_state(self, x: np.ndarray) -> np.ndarray:
        """The joints' [q, v] (2n,) of a state: the state itself."""
        return x

    def state_record(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """What a trajectory records of a state beyond the joints: nothing on a fixed base."""
        return {}

    def new_sensor(self, period: float, rng: np.random.Generator, seed: int) -> Sensor | None:
        """A fresh :class:`~hydroarm.model.real_loop.sensing.Sensor` for one run with control period T (s):
        its noise from ``rng`` (the run's), its dropout from the run ``seed``; None for the ideal
        sensor (``sensor`` at its defaults: :meth:`measure` is the sensor)."""
        if self.sensor.ideal:
            return None
        return Sensor(self.sensor, self.n, period, self.config.noise_variance, rng, seed)

    def new_actuator(self, period: float) -> Actuator | None:
        """Fresh :class:`~hydroarm.model.real_loop.sensing.Actuator` drives for one run (period T, s); None
        for ideal drives (``actuator`` at its defaults: the torque acts as commanded, at once)."""
        if self.actuator.ideal:
            return None
        return Actuator(self.actuator, self.n, period)

    def measure(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The paper's sensor: x plus N(0, noise_variance) on every entry (q and v)
        (``plant.sensor`` is applied by :meth:`new_sensor`'s sensor, not here)."""
        variance = self.config.noise_variance
        if variance == 0.0:
            return np.array(x, dtype=float)
        return x + rng.normal(0.0, np.sqrt(variance), size=x.shape)

    def energy(self, x: np.ndarray) -> float:
        """Dry kinetic + gravity potential energy (J) of state x."""
        n = self.n
        return self.arm.kinetic_energy(x[:n], x[n:], data=self.data) + self.arm.potential_energy(x[:n], data=self.data)


@structref.register
class JointFrictionType(types.StructRef):
    """numba type of the plant's joint friction constants (:func:`_new_joint_friction`)."""


@structref.register
class RK4WorkType(types.StructRef):
    """numba type of the plant's RK4 workspace (:func:`_new_rk4_work`)."""


class JointFriction(structref.StructRefProxy):
    """The joint friction of one plant, as :func:`rk4_stage_kernel` reads it: ``uniform`` the
    viscous ``plant.friction`` (N m s/rad), ``on`` and the five (n,) arrays of
    :func:`~hydroarm.model.real_loop.friction.friction_torque` (``coulomb``, ``breakaway``, ``viscous``,
    ``stribeck_velocity``, ``width``)."""


class RK4Work(structref.StructRefProxy):
    """The workspace of one plant's RK4 step: the state ``x`` (2n,), the stage state ``xs``
    (2n,), the stage slopes ``ks`` (4, 2n), the stage disturbances ``dists`` (4, n) and their
    weighted sum ``average`` (n,)."""


structref.define_boxing(JointFrictionType, JointFriction)
structref.define_boxing(RK4WorkType, RK4Work)
_F1, _F2 = types.float64[::1], types.float64[:, ::1]
JOINT_FRICTION_TYPE = JointFrictionType([
    ("uniform", types.float64), ("on", types.boolean), ("coulomb", _F1), ("breakaway", _F1), ("viscous", _F1),
    ("stribeck_velocity", _F1), ("width", _F1),
])  # fmt: skip
RK4_WORK_TYPE = RK4WorkType([("x", _F1), ("xs", _F1), ("ks", _F2), ("dists", _F2), ("average", _F1)])


@numba.njit(cache=True)
def _new_joint_friction(uniform, on, arrays):  # pragma: no cover - compiled
    s = structref.new(JOINT_FRICTION_TYPE)
    s.uniform, s.on = uniform, on
    s.coulomb, s.breakaway, s.viscous, s.stribeck_velocity, s.width = arrays
    return s


@numba.njit(cache=True)
def _new_rk4_work(arrays):  # pragma: no cover - compiled
    s = structref.new(RK4_WORK_TYPE)
    s.x, s.xs, s.ks, s.dists, s.average = arrays
    return s


@numba.njit(cache=True)
def rk4_stage_kernel(stage, t, h, tau, mass_upper, nonlinear, jac, djac, strips, joints, work):  # pragma: no cover
    """One stage of a classic RK4 step of the true plant, everything but Pinocchio compiled.

    The caller evaluates Pinocchio (CRBA -> ``mass_upper``, NLE -> ``nonlinear``,
    Jacobians and their time variation -> ``jac``, ``djac``) at the stage state
    ``work.xs = [q, v]`` (2n,) and time ``t``; this evaluates the current at ``t``, the water
    (:func:`~hydroarm.model.water.strips.water_terms` on ``strips``) and the solve
    (:func:`~hydroarm.model.water.strips.solve_underwater`), stores the disturbance ``work.dists[stage]``
    and leaves the RK4 bookkeeping to :func:`hydroarm.model.dynamics.integrator.rk4_disturbance_stage`
    (``work.ks[stage] = [v, q'']``, ``work.xs`` the next stage's state); after the last stage
    (3) ``work.x`` itself becomes ``x + h/6 (k1 + 2 k2 + 2 k3 + k4)`` (``xs`` too) and
    ``work.average`` gets ``d1 + 2 d2 + 2 d3 + d4``. Same operations, in the same order,
    as :meth:`UnderwaterPlant.step_numpy` (a test compares them bit for bit).
    ``joints``: :class:`JointFriction`; the joint friction model's torque is subtracted from tau
    and the disturbance then includes it. The Reynolds drag joins tau before the friction and
    the disturbance after the average's update (the order the numbers were first made in).
    """
    n = tau.shape[0]
    x, xs, dists, average = work.x, work.xs, work.dists, work.average
    joint_acceleration = np.empty(n)
    water_velocity = np.empty(3)
    current_at(t, strips.current_joint, strips.current_world, joint_acceleration, water_velocity)
    q, v = xs[:n], xs[n:]
    added, bias, force, tau_force = water_terms(strips, q, v, water_velocity, jac, djac)
    reynolds = strips.drag_model == DRAG_REYNOLDS
    applied = tau + tau_force if reynolds else tau
    joint_friction = tau  # a placeholder of the same type, replaced when the friction model is on
    if joints.on:
        joint_friction = friction_torque(v, joints.coulomb, joints.breakaway, joints.viscous,
                                         joints.stribeck_velocity, joints.width)  # fmt: skip
        applied = applied - joint_friction
    rigid = (mass_upper, nonlinear, jac, djac)
    acc, disturbance = solve_underwater(v, applied, joint_acceleration, joints.uniform, rigid, added, bias, force)
    if joints.on:
        disturbance = disturbance - joint_friction
    rk4_disturbance_stage(stage, h, x, xs, work.ks, acc, disturbance, dists, average, tau_force, reynolds)
