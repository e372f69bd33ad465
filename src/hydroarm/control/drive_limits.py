"""The drives' rate limit told to the controller (issue 32; the loop's ``actuator.rate_limit`` r,
N m/s): before each step an ID-MPC is told the drives' output before its command acts and r T
(``drive_limits``: :class:`~hydroarm.control.idmpc.InverseDynamicsMPC` holds its torque in that
box, planning a ramp with the rate rows of :class:`~hydroarm.control.idmpc_limits.HorizonQP`).
The state estimator's copy of the drives tells it (:class:`~hydroarm.control.estimator.FilteredController`);
without a filter :class:`DrivesTold` keeps a copy of its own.

Here: telling it (:func:`tell_drive_limits`), the rate-limited horizon's length
(:func:`rate_horizon`), the allocation in a torque box (:func:`box_allocate`) and :class:`DrivesTold`.
"""

from __future__ import annotations

import numpy as np

from hydroarm.control.idmpc_limits import allocate
from hydroarm.control.interface import Controller, ControlOutput, Reference
from hydroarm.model.real_loop.sensing import Actuator, ActuatorConfig

__all__ = ["RATE_HORIZON_CAP", "DrivesTold", "box_allocate", "rate_horizon", "tell_drive_limits"]

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


def box_allocate(mass: np.ndarray, bias: np.ndarray, acceleration: np.ndarray, lower: np.ndarray, upper: np.ndarray):
    """:func:`~hydroarm.control.idmpc_limits.allocate` in the box ``lower <= tau <= upper`` (n,)
    N m: about its centre c the box is the symmetric one of half-width ``(upper - lower) / 2`` on
    ``tau - c = M a + (bias - c)``. Returns ``(tau (n,), a (n,), saturated (n,) bool)``."""
    centre = 0.5 * (lower + upper)
    tau, a, saturated = allocate(mass, bias - centre, acceleration, 0.5 * (upper - lower))
    return np.clip(tau + centre, lower, upper), a, saturated


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
