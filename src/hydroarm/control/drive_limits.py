"""The drives' rate limit told to the controller (issue 32; the loop's ``actuator.rate_limit`` r,
N m/s): before each step an ID-MPC is told the drives' output before its command acts and r T
(``drive_limits``: :class:`~hydroarm.control.idmpc.InverseDynamicsMPC` holds its torque in that
box, planning a ramp with the rate rows of :class:`~hydroarm.control.idmpc_limits.HorizonQP`).
The state estimator's copy of the drives tells it (:class:`~hydroarm.control.estimator.FilteredController`);
without a filter :class:`DrivesTold` keeps a copy of its own.

Here: telling it (:func:`tell_drive_limits`), the rate-limited horizon's length
(:func:`rate_horizon`), the GP's estimate under the rate limit (below) and :class:`DrivesTold`. The
torque within the box is the ID-MPC's one torque map over its ``torque_box()`` (the limits when no
rate is told): :func:`~hydroarm.control.idmpc_limits.held_torque`, :func:`~hydroarm.control.idmpc_limits.box_allocate`.

**The GP's estimate under the rate limit.** With acceleration inputs the estimate answers the
acceleration it is asked at (the water's added mass), and the drives rarely give the planned a_0.
So the estimate is linearised in the acceleration, ``w_hat(a) ~ w_hat(a_0) - M_A (a - a_0)`` with
``M_A`` the diagonal of its slope (:func:`learned_added_mass`, floored at 0), and both the torque
map and the rate QP's rows take it that way (M + M_A; :func:`linearised_disturbance`); the window's
sample pairs the residual with the acceleration the torque realises, not the planned one. Frozen
at a_0, the iiwa14's GP-IDMPC under 1000 N m/s ran 50 rad off its reference in 10 s
(docs/robustness.md, section 6); either half alone left it 0.63 rad off after 2 s, both 0.23 rad.
"""

from __future__ import annotations

import numpy as np

from hydroarm.control.interface import Controller, ControlOutput, Reference
from hydroarm.model.real_loop.sensing import Actuator, ActuatorConfig

__all__ = [
    "ADDED_MASS_STEP",
    "RATE_HORIZON_CAP",
    "DrivesTold",
    "learned_added_mass",
    "linearised_disturbance",
    "rate_horizon",
    "tell_drive_limits",
]

ADDED_MASS_STEP = 1.0
"""rad/s^2: the central-difference step of the GP's added mass (:func:`learned_added_mass`)."""

RATE_HORIZON_CAP = 100
"""The most steps (-) of the rate-limited horizon QP (:func:`rate_horizon`)."""


def rate_horizon(horizon: int, torque_limit: np.ndarray, step: np.ndarray) -> int:
    """The horizon (steps) of the QP with the drives' rate rows: the steps the slowest drive needs
    to bring its full torque to zero, ``ceil(max_j tau_max,j / (r_j T))`` (``step`` = r T (n,) N m),
    at least ``horizon`` (the MPC's N) and at most :data:`RATE_HORIZON_CAP`. A plan that cannot
    see its braking ramp does not brake in time: on the paper arm (500 N m at 1000 N m/s, 50 steps)
    the 5-step plan overshot by 6 rad within 1 s (docs/robustness.md, section 6)."""
    ramp = int(np.ceil(np.max(np.asarray(torque_limit, dtype=float) / np.asarray(step, dtype=float))))
    return int(min(max(horizon, ramp), max(horizon, RATE_HORIZON_CAP)))


def learned_added_mass(gp, gp_input: np.ndarray, n: int, acceleration_scale: float) -> np.ndarray:
    """The GP's added mass (n,) kg m^2 at ``gp_input`` (3n,: state and scaled acceleration):
    ``-d w_hat_j / d a_j``, the diagonal of the estimate's slope in the acceleration (central
    differences of :data:`ADDED_MASS_STEP` rad/s^2, one batched prediction of ``gp``, the input's
    acceleration divided by ``acceleration_scale``), floored at 0 (the water's added mass is
    positive semi-definite; a non-finite slope gives 0)."""
    step = ADDED_MASS_STEP / acceleration_scale
    shifted = np.tile(gp_input, (2 * n, 1))
    joints = np.arange(n)
    shifted[joints, 2 * n + joints] += step
    shifted[n + joints, 2 * n + joints] -= step
    mean, _ = gp.predict(shifted, include_noise=False)
    slope = (mean[joints, joints] - mean[n + joints, joints]) / (2.0 * ADDED_MASS_STEP)
    return np.where(np.isfinite(slope), np.maximum(-slope, 0.0), 0.0)


def linearised_disturbance(w_free: np.ndarray, added_mass: np.ndarray):
    """The rate-limited horizon QP's ``disturbance_model`` (:class:`~hydroarm.control.idmpc_limits.HorizonQP`):
    ``(q, v, a) -> (w_k = w_free - M_A a_k (N, n), M_A (N, n, n))``, the estimate linearised in
    each planned acceleration, ``M_A = diag(added_mass)`` (n,) kg m^2, ``w_free`` (n,) N m."""
    mass = np.diag(added_mass)

    def disturbance(q, v, a):
        return w_free - a * added_mass, np.broadcast_to(mass, (a.shape[0], added_mass.shape[0], added_mass.shape[0]))

    return disturbance


def tell_drive_limits(controller: Controller, drives: Actuator | None) -> None:
    """Tell ``controller`` the drives' rate limit for its next command, from ``drives`` (a copy of
    the loop's drives fed its commands): their output before the command acts and ``rate_limit T``
    (``controller.drive_limits``). Nothing when there is no copy, no rate limit, or the controller
    takes none."""
    if drives is None or drives.max_step is None:
        return
    tell = getattr(controller, "drive_limits", None)
    if tell is not None:
        tell(drives.pending_output(), drives.max_step)


class DrivesTold:
    """A controller told the drives' rate limit without a state estimator in front of it
    (``estimator.kind = "none"``): a copy of the drives (:class:`Actuator`) is fed its commands,
    and before each step it is told their output before the command acts and ``rate_limit T``
    (``controller.drive_limits``), as :class:`FilteredController` tells it from its own copy.
    ``drives``: the loop's actuator settings (with a rate limit); ``n`` joints; ``period`` (s)."""

    def __init__(self, controller: Controller, drives: ActuatorConfig, n: int, period: float):
        self.controller = controller
        self.name = controller.name
        self.control_period = controller.control_period
        self.drives = drives
        self._n, self._period = n, float(period)
        self._copy = Actuator(drives, n, self._period)

    def reset(self) -> None:
        self.controller.reset()
        self._copy = Actuator(self.drives, self._n, self._period)

    def compute(self, t: float, y: np.ndarray, reference: Reference) -> ControlOutput:
        tell_drive_limits(self.controller, self._copy)
        out = self.controller.compute(t, y, reference)
        self._copy.apply(np.asarray(out.tau, dtype=float))
        return out

    def observe(self, t: float, y: np.ndarray, u: np.ndarray, y_next: np.ndarray) -> None:
        self.controller.observe(t, y, u, y_next)
