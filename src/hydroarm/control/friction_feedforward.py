"""The arm's joint friction fed forward under the inverse-dynamics MPCs (issue 32).

A geared joint's Coulomb friction (:mod:`hydroarm.model.real_loop.friction`) is a force that flips with the
velocity. The ID-MPCs' learners and observers (GP-IDMPC's GP, the TDE/NDOB under IDMPC, PI-IDMPC's
remainder) estimate it from past transitions; behind a loop delay they see transitions d periods
old, and a force that flips with the velocity is then fed forward stale (docs/robustness.md,
section 6). The friction model of the arm is known to the user, so the controller is given it:

    tau = tau_c + f_hat(v_r(t)),    f_hat = what the controller is told of the friction model  (N m, (n,))

``tau_c`` is the wrapped controller's torque, ``v_r(t)`` the reference velocity of the step, the
sum clipped to the torque limits. Why the reference velocity and not the measured, filtered or
planned one: near v = 0 the friction law is a viscous term of slope ``F_s / w`` (N m s/rad), and
fed back through a velocity that lags the true one (the filter, the loop delay) it is a negative
damping of that slope: on the Alpha 5's wrist (0.64 N m over w = 0.36 rad/s on 6.0e-5 kg m^2) a
loop gain of about 300 per period. The reference velocity closes no loop: the feed-forward is a
function of time. It is right only while the joint follows the reference, so each joint's
feed-forward is gated: it starts once the joint's position error (of the state the controller is
handed) is at most :data:`GATE_ON` and stops when it exceeds :data:`GATE_OFF` (hysteresis: no
switching with every step). The paper task starts 1.4-2 rad off its reference, where a joint
moves against the reference velocity. Measured (Alpha 5, the issue's command: 16-bit encoder,
one period of delay, published friction; IDMPC, 10 s, seed 0, 2026-12-04): ungated 4.51 rad^2
of E_p, gated 0.073 (without the feed-forward 0.068: that wrist limit-cycles either way,
docs/robustness.md section 6); at the planned velocity (``v + a_0 T / 2``, ungated) 0.114.

The wrapped controller observes each transition with ``u - f_hat`` of the step that commanded
``u`` (behind a loop delay the filter passes that step's time), the torque it commanded itself,
so what its learner or observer estimates (GP-IDMPC's GP, an observer under IDMPC, PI-IDMPC's
water model and remainder) is only what the friction model leaves.

What the controller is told (``idmpc.friction_feedforward``): the ``friction`` section's per-joint
values (the arm's friction model: Coulomb and breakaway levels, Stribeck velocities, viscous
terms and widths; by default Gaz et al. 2019's published ones) at a scale of its own, never the
plant's ``friction.scale``. ``"arm"`` (the default) is the nominal model, scale 1, whenever the arm
has joint friction (``friction.scale > 0``) and none otherwise: a frictionless arm (the paper's)
gets no feed-forward and runs exactly as without this wrapper; a plant with twice the
published friction is compensated for the published values and the learners see the rest.
"""

from __future__ import annotations

import time

import numpy as np

from hydroarm.control.interface import Controller, ControlOutput, Reference, StepLog
from hydroarm.model.real_loop.friction import FrictionConfig, friction_torque


def told_friction(friction: FrictionConfig | None, setting: float | str) -> FrictionConfig | None:
    """The friction model the controller is told (module docstring): ``friction``'s values at the
    scale ``setting`` (``"arm"``: 1 when ``friction.scale > 0``, else none); None when that scale is 0."""
    if friction is None:
        return None
    scale = (1.0 if friction.active else 0.0) if setting == "arm" else float(setting)
    if scale == 0.0:
        return None
    return friction.model_copy(update={"scale": scale})


GATE_ON = 0.05
"""A joint's feed-forward starts once its position error is at most this (rad)."""

GATE_OFF = 0.2
"""... and stops once its position error exceeds this (rad); the span between is the hysteresis
that keeps the gate from switching with every step. Measured (paper arm, GP-IDMPC, 16-bit encoder,
published friction, 10 s, seed 0, 2026-12-04): with 0.5 instead the wrist keeps a feed-forward
it lags behind and limit-cycles in the target world (one period of delay: E_p 0.0437, worst error
after 2 s 0.52 rad, against 0.0304 and 0.27 rad with 0.2), though with two periods of delay 0.5
held the wrist and 0.2 did not (0.32 against 0.57 rad): the light wrist against its friction
is marginal either way (docs/robustness.md, section 6)."""


class FrictionFeedforward:
    """``controller`` with the told friction model fed forward at the reference velocity (module
    docstring). ``friction``: the told :class:`FrictionConfig` (its scale applied); ``n`` joints;
    ``torque_limit`` (n,) N m: the box the sum is clipped to (the wrapped controller's, if it has
    one)."""

    def __init__(self, controller: Controller, friction: FrictionConfig, n: int, torque_limit: np.ndarray):
        self.controller = controller
        self.name = controller.name
        self.control_period = controller.control_period
        self.torque_limit = np.asarray(torque_limit, dtype=float)
        self.friction = friction
        self._arrays = tuple(np.ascontiguousarray(a, dtype=float) for a in friction.arrays(n))
        self.n = n
        self._sent = StepLog(self.control_period)
        self._on = np.zeros(n, dtype=bool)
        self._rate: tuple[np.ndarray, np.ndarray] | None = None

    def reset(self) -> None:
        self.controller.reset()
        self._sent.clear()
        self._on = np.zeros(self.n, dtype=bool)
        self._rate = None

    def drive_limits(self, output: np.ndarray, step: np.ndarray) -> None:
        """The drives' rate limit for the next command (``output``, ``step`` (n,) N m:
        :meth:`~hydroarm.control.idmpc.InverseDynamicsMPC.drive_limits`): the wrapped controller
        is told the drives' output less this step's feed-forward, so that its torque plus the
        feed-forward stays within ``step`` of ``output`` (the clip to the limits keeps it there)."""
        self._rate = (np.asarray(output, dtype=float), np.asarray(step, dtype=float))

    def torque(self, velocity: np.ndarray) -> np.ndarray:
        """f_hat (n,) N m at joint velocities (n,) rad/s."""
        return friction_torque(np.ascontiguousarray(velocity, dtype=float), *self._arrays)

    def compute(self, t: float, y: np.ndarray, reference: Reference) -> ControlOutput:
        start = time.perf_counter()
        q_r, v_r, _ = reference.sample(t)
        error = np.abs(np.asarray(y[: self.n], dtype=float) - q_r)
        self._on = np.where(self._on, error <= GATE_OFF, error <= GATE_ON)
        feedforward = np.where(self._on, self.torque(v_r), 0.0)
        self._sent.record(t, feedforward)
        if self._rate is not None:
            self.controller.drive_limits(self._rate[0] - feedforward, self._rate[1])
        elapsed = time.perf_counter() - start
        out = self.controller.compute(t, y, reference)
        start = time.perf_counter()
        out.tau = np.clip(np.asarray(out.tau, dtype=float) + feedforward, -self.torque_limit, self.torque_limit)
        elapsed += time.perf_counter() - start
        out.timings["friction"] = elapsed
        out.timings["total"] = out.timings.get("total", 0.0) + elapsed
        return out

    def observe(self, t: float, y: np.ndarray, u: np.ndarray, y_next: np.ndarray) -> None:
        """The wrapped controller observes the transition under ``u`` less the feed-forward of the
        step that commanded it (time t: behind a loop delay the filter passes that step's time)."""
        sent = self._sent.at(t)
        if sent is not None:
            u = np.asarray(u, dtype=float) - sent
        self.controller.observe(t, y, u, y_next)
