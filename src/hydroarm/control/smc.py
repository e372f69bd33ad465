"""Sliding-mode computed-torque control on the nominal (dry) model: the baseline.

Slotine's boundary-layer law, per joint, with e = q - q_r:

    s   = (v - v_r) + lambda e                                  (sliding surface, rad/s)
    a   = a_r - lambda (v - v_r) - k_s s - k sat(s / phi)         (rad/s^2)
    tau = clip(M(q) a + C(q, v) v + G(q), -tau_max, tau_max)    (one RNEA call)

``k`` is the robustness gain against the unmodelled part (water, current) in
acceleration units, ``phi`` the boundary-layer width that trades chattering for
a residual error, ``k_s`` an optional linear term. The defaults are the best of a
72-point grid on the paper task with the true underwater plant, scored on the
mean E_p of a clean and a noisy run (``scripts/tune_smc.py``, results in
``docs/data/smc_tuning.json``): an honest, well-tuned baseline, not the
paper's poor one.
"""

from __future__ import annotations

import time
from typing import Annotated

import numpy as np
import pydantic

from hydroarm.config import FrozenModel, per_joint
from hydroarm.control.interface import DEFAULT_CONTROL_PERIOD, ControlOutput, Reference, require_period
from hydroarm.model.arm.description import Arm
from hydroarm.model.dynamics.nominal import NominalModel

Gain = Annotated[float, pydantic.Field(gt=0.0, le=1e6)]
GainOrList = Gain | list[Gain]
NonNegativeGain = Annotated[float, pydantic.Field(ge=0.0, le=1e6)]


class SMCConfig(FrozenModel):
    """Sliding-mode gains (scalars or one per joint, each in (0, 1e6]; ``linear_gain`` from 0,
    ``boundary_layer`` from 1e-6)."""

    surface_slope: GainOrList = pydantic.Field(
        40.0, description="lambda, the sliding surface's slope s = de + lambda e (1/s)"
    )
    switching_gain: GainOrList = pydantic.Field(50.0, description="k, the switching gain (rad/s^2)")
    boundary_layer: (
        Annotated[float, pydantic.Field(ge=1e-6, le=1e6)] | list[Annotated[float, pydantic.Field(ge=1e-6, le=1e6)]]
    ) = pydantic.Field(2.0, description="phi, the boundary layer's width on s (rad/s)")
    linear_gain: NonNegativeGain | list[NonNegativeGain] = pydantic.Field(
        30.0, description="k_s, the linear gain on s (1/s)"
    )


class SlidingModeController:
    """Boundary-layer sliding-mode computed torque on the dry model (see module docstring)."""

    name = "SMC"

    def __init__(self, arm: Arm, config: SMCConfig | None = None, control_period: float = DEFAULT_CONTROL_PERIOD):
        self.arm = arm
        self.config = config if config is not None else SMCConfig()
        n = arm.n_joints
        self.control_period = require_period(control_period)
        self.nominal = NominalModel(arm)  # own workspace
        self.slope = per_joint(self.config.surface_slope, n, "surface_slope")
        self.gain = per_joint(self.config.switching_gain, n, "switching_gain")
        self.layer = per_joint(self.config.boundary_layer, n, "boundary_layer")
        self.linear = per_joint(self.config.linear_gain, n, "linear_gain")
        self.torque_limit = per_joint(arm.torque_limit, n, "torque_limit")  # the arm's actuators

    def reset(self) -> None:
        """Stateless: nothing to forget."""

    def compute(
        self, t: float, y: np.ndarray, reference: Reference, feedforward_torque: np.ndarray | None = None
    ) -> ControlOutput:
        """The torque (n,) N m at measured state y (2n,); ``feedforward_torque`` w_hat (n,) N m: a
        disturbance estimate compensated before the clip (``tau = ID(q, v, a) - w_hat``)."""
        start = time.perf_counter()
        n = self.arm.n_joints
        q, v = y[:n], y[n:]
        q_r, v_r, a_r = reference.sample(t)
        error_v = v - v_r
        surface = error_v + self.slope * (q - q_r)
        acc = a_r - self.slope * error_v - self.linear * surface - self.gain * np.clip(surface / self.layer, -1.0, 1.0)
        tau = self.nominal.inverse_dynamics(q, v, acc)
        if feedforward_torque is not None:
            tau = tau - feedforward_torque
        tau = np.clip(tau, -self.torque_limit, self.torque_limit)
        return ControlOutput(tau=tau, timings={"total": time.perf_counter() - start})

    def observe(self, t: float, y: np.ndarray, u: np.ndarray, y_next: np.ndarray) -> None:
        """No learning."""
