"""The one controller interface shared by SMC, MPC and GP-MPC.

One control step, as data: the runner gives the measured state ``y_k`` and the
reference to ``controller.compute(t_k, y_k, reference)``, which returns a
:class:`ControlOutput`; after the plant has moved, the runner calls
``controller.observe(t_k, y_k, u_k, y_next)`` so learning controllers can add
the new sample (a no-op for the others).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np


class Reference(Protocol):
    """A reference trajectory: what every controller and the runner ask of one.

    It must provide ``sample(t) -> (q, v, a)``: the joint positions (rad), velocities (rad/s)
    and accelerations (rad/s^2) at time ``t`` (s, a Python float), each a shape (n,) array
    (n = the arm's joints). ``a`` must be the derivative of ``v`` and ``v`` of ``q`` (the MPCs
    linearise about the reference and the computed-torque controllers feed ``a`` forward).
    Times are the control instants ``k * control_period`` and, for the predictive controllers,
    up to one horizon beyond the run's end.

    Optionally, a reference that also accepts an array of times (shape (m,)) and then returns
    (m, n) arrays declares it with a class attribute ``vectorised = True``
    (:class:`~hydroarm.model.task.references.SinusoidReference` does): controllers that need a whole
    horizon then sample it in one call. Without it, :func:`sample_times` calls ``sample`` once
    per time.
    """

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


def sample_times(reference: Reference, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(q, v, a)`` of ``reference`` at each of ``times`` (m,) s: (m, n) arrays each; one
    vectorised call if the reference declares ``vectorised = True``, else one call per time."""
    times = np.asarray(times, dtype=float)
    if getattr(reference, "vectorised", False):
        q, v, a = reference.sample(times)
        return np.asarray(q, dtype=float), np.asarray(v, dtype=float), np.asarray(a, dtype=float)
    rows = [reference.sample(float(t)) for t in times]
    return tuple(np.array([np.asarray(row[i], dtype=float) for row in rows]) for i in range(3))


@dataclass
class ControlOutput:
    """The result of one control step.

    ``tau`` (n,) N m, within the torque limits; ``status``: ``"ok"`` or what
    fallback was used (e.g. ``"qp_failed_lqr"``); ``timings``: seconds per
    phase (``"gp"``, ``"linearise"``, ``"qp_update"``, ``"qp_solve"``,
    ``"total"``); ``disturbance_mean``/``disturbance_var`` (n,): the learned
    disturbance estimate (N m, (N m)^2) fed forward, None if the controller
    has none; ``terminal_violation``: slack of the soft terminal set (0 if off);
    ``events``: the faults met and recovered from since the previous step
    (names from :data:`FAULT_EVENTS`), counted by the runner; ``acceleration`` (n,)
    rad/s^2: the joint acceleration the controller commands, when it plans in
    accelerations (a state estimator is driven by it), else None; ``record``: further
    per-step values the runner keeps as ``Trajectory.extra`` arrays (name -> array of a fixed
    shape; e.g. the station keeper's thrust command), empty for most controllers.
    """

    tau: np.ndarray
    status: str = "ok"
    timings: dict[str, float] = field(default_factory=dict)
    disturbance_mean: np.ndarray | None = None
    disturbance_var: np.ndarray | None = None
    terminal_violation: float = 0.0
    events: tuple[str, ...] = ()
    acceleration: np.ndarray | None = None
    record: dict[str, np.ndarray] = field(default_factory=dict)


FAULT_EVENTS: dict[str, str] = {
    "measurement_held": "non-finite measurement: the last valid one was used (runner)",
    "gp_jittered": "GP Cholesky needed extra diagonal jitter (one per factorisation and output)",
    "gp_cholesky_fallback": "GP Cholesky failed even with jitter: previous hyperparameters kept",
    "gp_prior_prediction": "GP had no factor for an output: its prior (zero) was predicted",
    "gp_nonfinite_prediction": "GP predicted a non-finite mean: zero fed forward on that joint",
    "gp_sample_rejected": "a non-finite residual or input was not added to the GP window",
    "qp_iteration_limit": "QP solver hit its iteration limit: fallback torque used",
    "qp_infeasible": "QP reported infeasible: fallback torque used",
    "qp_invalid_solution": "QP returned a non-finite or out-of-box solution: fallback torque used",
    "qp_failed": "QP solver failed otherwise (e.g. raised): fallback torque used",
    "terminal_soft_fallback": "hard terminal set infeasible: soft terminal set used",
    "torque_clipped": "last guard clipped a torque beyond its limit (or non-finite)",
    "controller_error": "the controller raised: the run was stopped (runner)",
    "diverged": "the plant state blew up: the run was stopped (runner)",
}
"""Every fault a run can meet, and how it was handled (``Trajectory.meta["faults"]``
counts each one; docs/reliability.md)."""


DEFAULT_CONTROL_PERIOD = 0.01
"""T (s): the paper's control period, every controller's default (SPEC)."""

CONTROL_PERIOD_RANGE = (1e-4, 1.0)
"""The control periods (s) a controller and an experiment accept, inclusive."""


class StepLog:
    """What a controller sent at each of its recent steps, keyed by the step's time t (s): a
    transition handed to ``observe`` behind a loop delay of d periods carries the time of the step
    that commanded it (t_k - d T, :class:`~hydroarm.control.estimator.FilteredController`), so the
    value sent then is found by that time, not by the state (which the filter has revised since)."""

    def __init__(self, control_period: float, steps: int = 64):
        self.control_period = float(control_period)
        self._entries: deque[tuple[float, np.ndarray]] = deque(maxlen=steps)

    def clear(self) -> None:
        self._entries.clear()

    def record(self, t: float, value: np.ndarray) -> None:
        self._entries.append((float(t), np.array(value, dtype=float)))

    def at(self, t: float) -> np.ndarray | None:
        """The value recorded at the step within half a period of ``t``; None if none is (newest first:
        steps are a period apart, so at most one is)."""
        half = 0.5 * self.control_period
        for recorded, value in reversed(self._entries):
            if abs(recorded - t) < half:
                return value
            if recorded < t - half:
                break
        return None


def require_period(control_period: float) -> float:
    """``control_period`` (s) as a float, checked to lie in :data:`CONTROL_PERIOD_RANGE` (raises
    ValueError otherwise).

    The period is a setting of the experiment (``ExperimentConfig.control_period``), not of
    any one controller: the builder hands the same value to the controller and the runner.
    """
    period = float(control_period)
    low, high = CONTROL_PERIOD_RANGE
    if not low <= period <= high:
        raise ValueError(f"control_period = {control_period!r}: must be >= {low:g} and <= {high:g} (s)")
    return period


@runtime_checkable
class Controller(Protocol):
    """What every controller implements."""

    name: str
    control_period: float

    def reset(self) -> None:
        """Forget all state (warm starts, learned data)."""

    def compute(self, t: float, y: np.ndarray, reference: Reference) -> ControlOutput:
        """Torque for measured state ``y = [q, v]`` (2n,) at time t (s)."""

    def observe(self, t: float, y: np.ndarray, u: np.ndarray, y_next: np.ndarray) -> None:
        """The step from ``y`` under ``u`` ended at ``y_next`` (measured)."""


FEEDFORWARD_PORTS: dict[str, str] = {
    "torque": "feedforward_torque",
    "acceleration": "feedforward_acceleration",
}
"""The feed-forward ports a controller's ``compute`` may declare: port -> keyword. ``torque``:
a generalised force w (n,) N m acting with the input (SMC, MPC, IDMPC; what
:class:`~hydroarm.control.observers.ObservedController` feeds); ``acceleration``: d (n,) rad/s^2
added to the prediction model's acceleration (MPC; what GP-MPC feeds with ``gpmpc.feedforward =
"acceleration"``). None means zero."""


@runtime_checkable
class TorqueFeedforward(Protocol):
    """A controller with the ``torque`` feed-forward port (:data:`FEEDFORWARD_PORTS`): what a
    disturbance observer or learner wraps. ``torque_limit`` (n,) N m: its actuators' box."""

    name: str
    control_period: float
    torque_limit: np.ndarray

    def reset(self) -> None: ...

    def compute(
        self, t: float, y: np.ndarray, reference: Reference, feedforward_torque: np.ndarray | None = None
    ) -> ControlOutput: ...

    def observe(self, t: float, y: np.ndarray, u: np.ndarray, y_next: np.ndarray) -> None: ...


@runtime_checkable
class AccelerationFeedforward(Protocol):
    """A controller with both feed-forward ports (:data:`FEEDFORWARD_PORTS`): the linear MPC."""

    name: str
    control_period: float

    def reset(self) -> None: ...

    def compute(
        self,
        t: float,
        y: np.ndarray,
        reference: Reference,
        feedforward_acceleration: np.ndarray | None = None,
        feedforward_torque: np.ndarray | None = None,
    ) -> ControlOutput: ...

    def observe(self, t: float, y: np.ndarray, u: np.ndarray, y_next: np.ndarray) -> None: ...


def has_port(controller: object, port: str) -> bool:
    """Whether ``controller.compute`` declares the feed-forward ``port`` ("torque" or
    "acceleration", :data:`FEEDFORWARD_PORTS`) as a keyword parameter."""
    import inspect

    keyword = FEEDFORWARD_PORTS[port]
    compute = getattr(controller, "compute", None)
    if compute is None:
        return False
    parameter = inspect.signature(compute).parameters.get(keyword)
    return parameter is not None and parameter.kind in (parameter.POSITIONAL_OR_KEYWORD, parameter.KEYWORD_ONLY)


def require_port(controller: object, port: str, user: str) -> None:
    """TypeError naming ``user``, the controller and the keyword unless ``controller`` declares
    the feed-forward ``port`` (:func:`has_port`): a wrapper checks its inner controller once,
    when it is built, rather than failing at its first step."""
    if not has_port(controller, port):
        name = getattr(controller, "name", type(controller).__name__)
        raise TypeError(
            f"{user} feeds a {port} forward: controller {name}'s compute must take "
            f"{FEEDFORWARD_PORTS[port]}= (the {port} port, hydroarm.control.interface.FEEDFORWARD_PORTS)"
        )


@runtime_checkable
class WrapsController(Protocol):
    """A controller that runs another one: ``controller`` is the wrapped controller (the
    Kalman filter's, an observer's, the vehicle's arm controller)."""

    controller: Controller


@runtime_checkable
class DisturbanceEstimator(Protocol):
    """What every disturbance learner implements: the sliding-window GP
    (:class:`~hydroarm.control.gp.SlidingWindowGP`, GP-MPC's, GP-IDMPC's and the vehicle
    controller's), PI-IDMPC's water model (:class:`~hydroarm.control.learned_water.PhysicsInformedModel`)
    and the observers (:class:`~hydroarm.control.observers.DisturbanceObserver`).

    The disturbance w (n,) N m (the force the dry model misses) is learned as a function of an
    input x (d,): the learner's own features (the GP's, say the state; the water model's
    ``[q, v, a]`` (3n,)); an observer is input-free (it ignores x: its estimate is the filtered
    last residual). Per control step: :meth:`update` with the newest sample, then :meth:`mean`
    and :meth:`variance` where the estimate is needed.
    """

    @property
    def n_samples(self) -> int:
        """The samples taken since the last :meth:`reset` (the GP: in its window)."""

    def reset(self) -> None:
        """Forget every sample (back to the prior)."""

    def update(self, x: np.ndarray, r: np.ndarray) -> bool:
        """Take one sample: the disturbance r (n,) N m seen at input x (d,); False if it was
        refused (non-finite, or the learner could not take it) and nothing changed."""

    def mean(self, x: np.ndarray) -> np.ndarray:
        """The estimated disturbance (n,) N m at input x (d,)."""

    def variance(self, x: np.ndarray) -> np.ndarray:
        """Its variance (n,) (N m)^2 at input x (d,); NaN where the learner has no variance model."""


@runtime_checkable
class LearnsDisturbance(Protocol):
    """A controller whose disturbance learner is ``estimator`` (:class:`DisturbanceEstimator`)."""

    estimator: DisturbanceEstimator


def estimator_of(controller: Controller) -> DisturbanceEstimator | None:
    """The disturbance learner of the outermost controller of ``controller``'s chain
    (:func:`controller_chain`) that has one (:class:`LearnsDisturbance`), or None."""
    for inner in controller_chain(controller):
        estimator = getattr(inner, "estimator", None)
        if estimator is not None and isinstance(estimator, DisturbanceEstimator):
            return estimator
    return None


@runtime_checkable
class ModelLearner(Protocol):
    """A controller whose learned model can be saved and loaded (PI-IDMPC's water model)."""

    def load_model(self, path: str | Path) -> None: ...

    def save_model(self, path: str | Path) -> None: ...


def controller_chain(controller: Controller) -> list[Controller]:
    """``controller`` and the controllers it wraps, outermost first (:class:`WrapsController`)."""
    chain = [controller]
    while isinstance(chain[-1], WrapsController) and len(chain) < 64:
        chain.append(chain[-1].controller)
    return chain


def learner_of(controller: Controller) -> ModelLearner | None:
    """The outermost controller of ``controller``'s chain (:func:`controller_chain`) whose learned
    model can be saved and loaded (:class:`ModelLearner`), or None."""
    return next((inner for inner in controller_chain(controller) if isinstance(inner, ModelLearner)), None)
