"""The true underwater plant and the nominal (dry) model, with one interface.

State x = [q, v] (rad, rad/s), shape (2n,); input tau (N m), shape (n,),
held constant over a control period (zero-order hold).

* :class:`UnderwaterPlant`: rigid body + water (drag, added mass, buoyancy),
  the current, optional joint viscous friction, integrated by RK4 with inner
  steps of at most ``PlantConfig.inner_step``. The measured state adds seeded
  Gaussian noise to q and v only; the true state is never touched.
* :class:`NominalModel`: the dry rigid body (what the controllers know: the
  arm "tuned once on land"), same interface.

Both expose ``acceleration(t, q, v, tau)``, ``derivative(t, x, tau)`` and
``step(t, x, tau, dt) -> (x_next, StepInfo)``. ``step_reference`` is the plain
Python RK4 (:func:`hydroarm.model.integrator.rk4_step` over ``_dynamics``);
``UnderwaterPlant.step`` does the same operations in the same order with all but
the Pinocchio calls compiled (bit-identical, ~3x faster; a test compares them). ``StepInfo.disturbance`` is the
generalised force the nominal model lacks, ``M(q) q'' + C v + G - tau`` (zero
for the nominal model).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
import pydantic

from hydroarm.model.arm import Arm
from hydroarm.config import ConfigError, FrozenModel
from hydroarm.model.integrator import rk4_step
from hydroarm.model.water import Water, WaterModel, added_mass_matrix, rk4_stage_kernel

STIFFNESS_LIMIT = 2.5
"""Bound on ``friction * inner_step / lambda_min(M + M_A)`` (classic RK4 is stable on the
negative real axis up to 2.785; the smallest joint-space inertia is taken at q = 0)."""


class PlantConfig(FrozenModel):
    """Integration and sensing of the true plant.

    ``inner_step`` (s, in [1e-5, 0.1]): the RK4 step (the control period is divided into equal
    steps no longer than this); ``friction`` (N m s/rad): joint viscous friction,
    0 = off (SPEC default); it must also be soft enough for explicit RK4 on the
    arm (:class:`UnderwaterPlant` checks ``friction * inner_step`` against the
    arm's smallest joint-space inertia: about 0.3 N m s/rad for the paper arm at
    1 ms); ``noise_variance`` (rad^2 and (rad/s)^2): variance of
    the zero-mean Gaussian measurement noise on q and v (0.001 in the paper's
    Table 2).
    """

    inner_step: float = pydantic.Field(1e-3, ge=1e-5, le=0.1)
    friction: float = pydantic.Field(0.0, ge=0.0, le=1e4)
    noise_variance: float = pydantic.Field(0.0, ge=0.0, le=10.0)


@dataclass(frozen=True)
class StepInfo:
    """What happened inside one plant step.

    ``disturbance`` (N m, (n,)): the generalised force beyond the dry model,
    averaged over the step with the RK4 weights (what a one-step residual can
    see); ``disturbance_start``: its value at the start of the step.
    """

    disturbance: np.ndarray
    disturbance_start: np.ndarray


class _RK4Model:
    """Shared stepping: subclasses define ``_dynamics(t, q, v, tau) -> (q'', disturbance)``."""

    arm: Arm
    inner_step: float
    n: int

    def _dynamics(self, t: float, q: np.ndarray, v: np.ndarray, tau: np.ndarray):
        raise NotImplementedError

    def acceleration(self, t: float, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """q'' (rad/s^2), shape (n,)."""
        return self._dynamics(t, q, v, tau)[0]

    def disturbance(self, t: float, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Generalised force (N m) beyond the dry model at (t, q, v, tau), shape (n,)."""
        return self._dynamics(t, q, v, tau)[1]

    def derivative(self, t: float, x: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """x' = [v, q''], shape (2n,)."""
        n = self.n
        return np.concatenate([x[n:], self._dynamics(t, x[:n], x[n:], tau)[0]])

    def step(self, t: float, x: np.ndarray, tau: np.ndarray, dt: float) -> tuple[np.ndarray, StepInfo]:
        """Integrate from (t, x) over dt (s) under constant tau: ``(x_next (2n,), StepInfo)``.

        Classic RK4 with ``ceil(dt / inner_step)`` equal steps.
        """
        n = self.n
        steps = max(1, int(np.ceil(dt / self.inner_step - 1e-9)))
        h = dt / steps
        x = np.asarray(x, dtype=float)
        average = np.zeros(n)
        start = None
        time = t
        stages: list[np.ndarray] = []

        def f(s: float, y: np.ndarray) -> np.ndarray:
            acc, dist = self._dynamics(s, y[:n], y[n:], tau)
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

    # The generic Python formulation: the reference that faster overrides are tested against.
    step_reference = step


_VIEWS_ARE_LIVE: bool | None = None


def _live_views(model: pin.Model, data: pin.Data):
    """``(data.M, data.J, data.dJ)`` as arrays that follow later Pinocchio calls, or None.

    eigenpy (Pinocchio's bindings) returns these members as views of the Eigen
    storage, so fetching them once per plant step instead of once per stage saves
    three attribute look-ups (and, for the Jacobians, a reshape copy) per stage.
    Checked once per process on a scratch Data: the view fetched before two CRBA
    calls at different configurations must show the second result; if not (other
    bindings), None and the caller fetches the members after every call.
    """
    global _VIEWS_ARE_LIVE
    if _VIEWS_ARE_LIVE is None:
        scratch = model.createData()
        view = scratch.M
        q = pin.neutral(model)
        pin.crba(model, scratch, q)
        first = scratch.M.copy()
        pin.crba(model, scratch, pin.integrate(model, q, np.full(model.nv, 0.5)))
        _VIEWS_ARE_LIVE = bool(not np.array_equal(view, first) and np.array_equal(view, scratch.M))
    return (data.M, data.J, data.dJ) if _VIEWS_ARE_LIVE else None


class NominalModel(_RK4Model):
    """The dry rigid-body model: q'' = M^-1 (tau - C v - G) (Pinocchio ABA)."""

    def __init__(self, arm: Arm, inner_step: float = 1e-3):
        self.arm = arm
        self.inner_step = inner_step
        self.n = arm.n_joints
        self._zero = np.zeros(self.n)

    def _dynamics(self, t: float, q: np.ndarray, v: np.ndarray, tau: np.ndarray):
        return pin.aba(self.arm.model, self.arm.data, q, v, tau).copy(), self._zero


class UnderwaterPlant(_RK4Model):
    """The true plant: rigid body + water + current (+ friction).

    ``(M + M_A) (q'' - d_c(t)) = tau - C v - G - h_A + drag + buoyancy - b v``,
    with d_c the paper current's joint acceleration (zero for other current
    models; the uniform current acts through the drag instead).
    """

    def __init__(self, arm: Arm, water: Water | None = None, config: PlantConfig | None = None):
        self.arm = arm
        self.water = water if water is not None else Water()
        self.config = config if config is not None else PlantConfig()
        self.water_model = WaterModel(arm, self.water)
        self.inner_step = self.config.inner_step
        self.n = arm.n_joints
        self._check_friction()

    def _check_friction(self) -> None:
        """Raise :class:`ConfigError` if the joint friction is too stiff for RK4 at ``inner_step``:
        ``friction * inner_step / lambda_min(M(0) + M_A(0)) <= STIFFNESS_LIMIT``."""
        friction = self.config.friction
        if friction == 0.0:
            return
        q = pin.neutral(self.arm.model)
        inertia = self.arm.mass_matrix(q)
        if self.water.added_mass:
            inertia = inertia + added_mass_matrix(self.arm, self.water, q)
        smallest = float(np.linalg.eigvalsh(inertia)[0])
        limit = STIFFNESS_LIMIT * smallest / self.inner_step
        if friction > limit:
            raise ConfigError(
                f"plant.friction = {friction!r}: too stiff for RK4 with plant.inner_step = {self.inner_step!r} s "
                f"on arm '{self.arm.name}': must be <= {limit:.3g} N m s/rad (smallest joint-space inertia "
                f"{smallest:.3g} kg m^2), or use a smaller inner_step"
            )

    def _dynamics(self, t: float, q: np.ndarray, v: np.ndarray, tau: np.ndarray):
        return self.water_model.dynamics(q, v, tau, t, self.config.friction)

    def step(self, t: float, x: np.ndarray, tau: np.ndarray, dt: float) -> tuple[np.ndarray, StepInfo]:
        """Integrate from (t, x) over dt (s) under constant tau: ``(x_next (2n,), StepInfo)``.

        The same RK4 as :meth:`step_reference` (``ceil(dt / inner_step)`` equal
        steps, the same operations in the same order), with everything but the
        three Pinocchio calls per stage (CRBA, NLE, Jacobians and their time
        variation) in one compiled call (:func:`hydroarm.model.water.rk4_stage_kernel`):
        ~2.5x faster than the reference, whose per-stage NumPy and closure calls
        cost more than the water itself. A state that stops being finite (a
        diverging run) gives an all-NaN ``x_next`` and disturbance instead of an
        exception from the solve; :func:`hydroarm.studies.runner.run_closed_loop`
        reports it as ``diverged``.
        """
        n = self.n
        steps = max(1, int(np.ceil(dt / self.inner_step - 1e-9)))
        h = dt / steps
        state = np.array(x, dtype=float)  # a copy: the kernel updates it in place
        tau = np.ascontiguousarray(tau, dtype=float)
        stage_state = state.copy()
        q, v = stage_state[:n], stage_state[n:]
        derivatives = np.empty((4, 2 * n))
        disturbances = np.empty((4, n))
        average = np.zeros(n)
        start = None
        model, data = self.arm.model, self.arm.data
        wm, water = self.water_model, self.water_model.water
        constants = wm._constants
        friction = float(self.config.friction)
        drag, added_mass, buoyancy = water.drag, water.added_mass, water.buoyancy
        live = _live_views(model, data)
        time = t
        for _ in range(steps):
            half = time + 0.5 * h
            for stage, stage_time in enumerate((time, half, half, time + h)):
                pin.crba(model, data, q)
                nonlinear = pin.nonLinearEffects(model, data, q, v)
                pin.computeJointJacobiansTimeVariation(model, data, q, v)
                mass, jac, djac = live if live is not None else (data.M, data.J, data.dJ)
                try:
                    rk4_stage_kernel(
                        stage, stage_time, h, state, stage_state, derivatives, disturbances, average, tau,
                        friction, mass, nonlinear, jac, djac,
                        wm.current_joint, wm.current_world, *constants, drag, added_mass, buoyancy,
                    )  # fmt: skip
                except np.linalg.LinAlgError:  # the solve met an infinite force: diverged
                    stage_state[:] = np.nan
                    break
            if not np.all(np.isfinite(stage_state)):  # diverged: NaN out, the caller reports it
                nan = np.full(n, np.nan)
                return np.full(2 * n, np.nan), StepInfo(disturbance=nan, disturbance_start=nan.copy())
            if start is None:
                start = disturbances[0].copy()
            time += h
        average /= 6.0 * steps
        return state, StepInfo(disturbance=average, disturbance_start=start)

    def measure(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Measured state: x plus N(0, noise_variance) on every entry (q and v)."""
        variance = self.config.noise_variance
        if variance == 0.0:
            return np.array(x, dtype=float)
        return x + rng.normal(0.0, np.sqrt(variance), size=x.shape)

    def energy(self, x: np.ndarray) -> float:
        """Dry kinetic + gravity potential energy (J) of state x."""
        n = self.n
        return self.arm.kinetic_energy(x[:n], x[n:]) + self.arm.potential_energy(x[:n])
