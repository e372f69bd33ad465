"""Adaptive GP-MPC (Liu et al. 2023, Algorithm 2): an MPC and a sliding-window GP, composed.

Each control step k:

1. ``observe`` (after the plant moved): the nominal (dry) model predicts the
   state reached from the measured ``y_{k-1}`` under ``u_{k-1}`` (one RK4 step of
   the control period); the residual of the measured velocity, mapped to a
   generalised force, ``w_{k-1} = M(q_{k-1}) (v_k - v_nominal) / T`` (N m), is
   the disturbance the dry model missed. The GP window gets
   ``(features_{k-1}, w_{k-1})``.
2. ``compute``: a bounded number of hyperparameter steps, then the GP predicts
   the disturbance ``w_hat`` at the current features; it enters the MPC's
   prediction model as the joint acceleration ``M(q_k)^-1 w_hat`` (the affine
   term of the linearised model, so the QP still enforces the torque limits).

GP input features (``GPMPCConfig.features``):

* ``"state"``: the measured state [q, v] (the paper's 12 inputs, 14 hyperparameters);
* ``"state+nominal"``: [q, v] and the nominal prediction of the current state
  from the previous step (the paper's text also names it);
* ``"state+torque"``: [q, v] and the previous torque (scaled by ``torque_scale``).

``variance_aware`` (off by default, as in the paper): the feed-forward of each
joint is scaled by ``w^2 / (w^2 + var)``, so estimates the GP is unsure of are
trusted less.
"""

from __future__ import annotations

import time
from typing import Literal

import numpy as np
import pydantic

from hydroarm.config import FrozenModel
from hydroarm.control.gp import GPConfig, SlidingWindowGP
from hydroarm.control.interface import AccelerationFeedforward, ControlOutput, Reference, require_port
from hydroarm.model.arm.description import Arm
from hydroarm.model.dynamics import fixed_order
from hydroarm.model.dynamics.nominal import NominalModel

Features = Literal["state", "state+nominal", "state+torque"]


class GPMPCConfig(FrozenModel):
    """How the GP is wired into the MPC (the GP's own settings are a :class:`GPConfig`)."""

    features: Features = pydantic.Field(
        "state", description="GP inputs: the measured state, plus the nominal prediction or the previous torque"
    )
    feedforward: Literal["acceleration", "torque"] = pydantic.Field(
        "torque",
        description="where the estimate enters the MPC: the model's affine term (paper) or the input reference",
    )
    torque_scale: float = pydantic.Field(
        100.0, ge=1e-3, le=1e6, description="torque per GP input unit for the torque inputs (N m)"
    )
    min_samples: int = pydantic.Field(
        2, ge=1, le=10_000, description="GP window samples before the estimate is fed forward (-)"
    )
    variance_aware: bool = pydantic.Field(
        False, description="scale each joint's feed-forward by w^2 / (w^2 + var): trust unsure estimates less"
    )


def feature_size(features: Features, n: int) -> int:
    """Length of the GP input vector for ``features`` on an n-joint arm."""
    return {"state": 2 * n, "state+nominal": 4 * n, "state+torque": 3 * n}[features]


class GPMPC:
    """Adaptive MPC with a sliding-window GP disturbance model (see the module docstring).

    Holds a :class:`LinearMPC` (any controller with both feed-forward ports,
    :class:`~hydroarm.control.interface.AccelerationFeedforward`) and a :class:`SlidingWindowGP`;
    no inheritance.
    """

    name = "GP-MPC"

    def __init__(
        self,
        arm: Arm,
        mpc: AccelerationFeedforward,
        gp_config: GPConfig | None = None,
        config: GPMPCConfig | None = None,
    ):
        self.arm = arm
        self.config = config if config is not None else GPMPCConfig()
        require_port(mpc, self.config.feedforward, "GP-MPC (gpmpc.feedforward)")
        self.mpc = mpc
        self.n = arm.n_joints
        self.gp = SlidingWindowGP(feature_size(self.config.features, self.n), self.n, gp_config)
        self.estimator = self.gp  # interface.DisturbanceEstimator
        self.control_period = mpc.control_period
        self.nominal = NominalModel(arm, inner_step=None)  # own workspace; one RK4 step per period
        self.reset()

    def reset(self) -> None:
        self.mpc.reset()
        self.gp.reset()
        self._last_u = np.zeros(self.n)
        self._nominal_now = None  # nominal prediction of the current state
        self._features_now = None
        self._pending_events: list[str] = []  # faults met in observe, reported by the next compute

    def _features(self, y: np.ndarray, u_prev: np.ndarray, nominal: np.ndarray | None) -> np.ndarray:
        kind = self.config.features
        if kind == "state":
            return y.copy()
        if kind == "state+torque":
            return np.concatenate([y, u_prev / self.config.torque_scale])
        return np.concatenate([y, y if nominal is None else nominal])

    # --- the controller interface ---------------------------------------------------------
    def compute(self, t: float, y: np.ndarray, reference: Reference) -> ControlOutput:
        start = time.perf_counter()
        n = self.n
        features = self._features(y, self._last_u, self._nominal_now)
        self._features_now = features
        mean = np.zeros(n)
        var = np.full(n, np.nan)
        acceleration = torque = None  # the MPC's feed-forward ports (interface.FEEDFORWARD_PORTS)
        gp_events: tuple[str, ...] = ()  # the GP's faults of this step, as its calls return them
        if self.gp.n_samples >= self.config.min_samples:
            _, update_events = self.gp.update_hyperparameters(return_events=True)
            mean, var, predict_events = self.gp.predict(features, return_events=True)
            gp_events = update_events + predict_events
            if not np.all(np.isfinite(mean)):  # cannot happen with finite data; guarded anyway
                self._pending_events.append("gp_nonfinite_prediction")
                mean = np.where(np.isfinite(mean), mean, 0.0)
            scaled = mean
            if self.config.variance_aware:
                scaled = mean * mean**2 / (mean**2 + var + 1e-12)
            if self.config.feedforward == "acceleration":
                # M^-1 w by a fixed-order Cholesky (LAPACK's solve rounds by its CPU kernel)
                solved, _ = fixed_order.cholesky_solve(self.nominal.mass_matrix(y[:n]), np.ascontiguousarray(scaled))
                acceleration = solved
            else:
                torque = scaled
        gp_time = time.perf_counter() - start
        self._pending_events.extend(gp_events)
        out = self.mpc.compute(t, y, reference, feedforward_acceleration=acceleration, feedforward_torque=torque)
        out.events = (*self._pending_events, *out.events)
        self._pending_events = []
        out.disturbance_mean = mean
        out.disturbance_var = var
        out.timings["gp"] = gp_time
        out.timings["total"] = time.perf_counter() - start
        self._last_u = out.tau.copy()
        return out

    def observe(self, t: float, y: np.ndarray, u: np.ndarray, y_next: np.ndarray) -> None:
        """Add the disturbance seen over the last step to the GP window."""
        residual, nominal = self.nominal.residual(y, u, y_next, self.control_period)
        features = self._features_now if self._features_now is not None else self._features(y, u, None)
        self._nominal_now = nominal
        if not (np.all(np.isfinite(residual)) and np.all(np.isfinite(features))):
            self._pending_events.append("gp_sample_rejected")  # e.g. a blown-up step: not learned
            return
        self.gp.update(features, residual)  # meets no GP fault (SlidingWindowGP.update)
