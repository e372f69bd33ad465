"""The whole vehicle-manipulator system's controller: an arm controller + a station keeper.

* The arm: any controller of the registry (default ``SMC``) built on the arm alone, fixed-base,
  seeing joint states only (on :func:`hydroarm.model.vehicle.system.mounted_arm`: the arm's dry model
  with gravity turned into its base frame as mounted on a level vehicle; the vehicle's motion
  is a disturbance to it).
* The vehicle: :class:`~hydroarm.control.vehicle_control.VehiclePID` or ``VehicleMPC``, blind
  to the arm, or coupling-aware: a :class:`~hydroarm.control.gp.SlidingWindowGP` learns what
  the vehicle-only model misses (the arm's reaction, weight and buoyancy, its water, and the
  current's drag) and the station keeper feeds its mean forward.

The GP's sample at step k: input ``[q_arm, v_arm, a_ref_arm]`` (what drives the arm's force on
the vehicle), target the body wrench residual ``M_v (nu_{k+1} - nu_k) / T - (B f + g_v(R) -
D(nu_k) nu_k)`` with M_v = M_RB + M_A and the vehicle's own restoring wrench g_v and damping
(the current unknown: relative velocity = nu).

:class:`UVMSController` follows the :class:`~hydroarm.control.interface.Controller` protocol on
the floating plant's state ``y = [q (7 + n), v (6 + n), thrust (n_thr)]``: its output ``tau`` is
the plant's whole input ``[tau_arm, thrust command]``, its ``events`` those of the arm
controller and of the GP, its ``record`` the station keeper's ``thrust_command``,
``wrench``, ``vehicle_disturbance_estimate`` and ``saturated`` (kept by the runner).
"""

from __future__ import annotations

import time

import numpy as np

from hydroarm.control.gp import GPConfig, SlidingWindowGP
from hydroarm.control.interface import DEFAULT_CONTROL_PERIOD, Controller, ControlOutput, Reference, require_period
from hydroarm.control.vehicle_control import VehicleControlConfig, make_vehicle_controller, restoring_wrench
from hydroarm.model.vehicle.description import body_rotation
from hydroarm.model.vehicle.system import UVMS


class UVMSController:
    """Arm controller + station keeper (+ GP) (module docstring).

    ``arm_controller``: a controller of the arm's n joints (built on the mounted arm);
    ``target`` (7,): the vehicle pose to hold (position m, quaternion x y z w); ``vehicle``:
    the station keeper's settings; ``gp`` the feed-forward GP's (when ``aware``)."""

    def __init__(
        self,
        uvms: UVMS,
        arm_controller: Controller,
        target: np.ndarray,
        *,
        vehicle: VehicleControlConfig | None = None,
        gp: GPConfig | None = None,
        aware: bool = False,
        control_period: float = DEFAULT_CONTROL_PERIOD,
    ):
        self.uvms = uvms
        self.n_arm = uvms.n_arm
        self.control_period = require_period(control_period)
        self.arm_controller = arm_controller  # the port the arm's controller fills
        self.layout = uvms.layout  # the floating state's parts by name
        self.target = np.asarray(target, dtype=float).copy()
        self.vehicle = make_vehicle_controller(uvms.vehicle, vehicle, self.control_period)
        self.aware = aware
        self.gp = SlidingWindowGP(3 * self.n_arm, 6, gp if gp is not None else GPConfig(window=60)) if aware else None
        self.estimator = self.gp  # interface.DisturbanceEstimator of the body wrench (None: unaware)
        self.name = f"{arm_controller.name}+{self.vehicle.config.kind.upper()}{'+GP' if aware else ''}"
        self._features = None
        self._pending_events: list[str] = []

    @property
    def controller(self) -> Controller:
        """The arm's controller: the one this one wraps (:class:`~hydroarm.control.interface.WrapsController`;
        ``arm_controller`` is the same object)."""
        return self.arm_controller

    def reset(self) -> None:
        self.arm_controller.reset()
        self.vehicle.reset()
        if self.gp is not None:
            self.gp.reset()
        self._features = None
        self._pending_events = []

    def features(self, x: np.ndarray, reference: Reference, t: float) -> np.ndarray:
        parts = self.layout
        return np.concatenate([x[parts.arm_q], x[parts.arm_v], reference.sample(t)[2]])

    def compute(self, t: float, y: np.ndarray, reference: Reference) -> ControlOutput:
        """The input ``[tau_arm, thrust]`` for the measured plant state ``y = [q, v, f]``;
        ``reference`` the arm's joint reference."""
        start = time.perf_counter()
        parts = self.layout
        arm_out = self.arm_controller.compute(t, parts.arm_state(y), reference)
        events = [*self._pending_events, *arm_out.events]
        self._pending_events = []
        d_hat = np.zeros(6)
        gp_time = 0.0
        if self.gp is not None and self.gp.n_samples > 0:
            gp_start = time.perf_counter()
            mean, _, predicted = self.gp.predict(self.features(y, reference, t), return_events=True)
            events.extend(predicted)
            if np.all(np.isfinite(mean)):
                d_hat = mean
            else:
                events.append("gp_nonfinite_prediction")
            gp_time = time.perf_counter() - gp_start
        thrust, wrench, saturated = self.vehicle.compute(y[parts.base_pose], y[parts.base_velocity], self.target, d_hat)
        self._features = self.features(y, reference, t) if self.gp is not None else None
        timings = {"gp": gp_time, "total": time.perf_counter() - start}
        record = {
            "thrust_command": thrust,
            "wrench": wrench,
            "vehicle_disturbance_estimate": d_hat,
            "saturated": np.asarray(saturated, dtype=bool),
        }
        return ControlOutput(
            tau=np.concatenate([arm_out.tau, thrust]),
            status=arm_out.status,
            timings=timings,
            disturbance_mean=arm_out.disturbance_mean,
            disturbance_var=arm_out.disturbance_var,
            events=tuple(events),
            record=record,
        )

    def residual(self, x: np.ndarray, u: np.ndarray, x_next: np.ndarray) -> np.ndarray:
        """What the vehicle-only model misses over the step (body wrench, N and N m)."""
        vehicle, twist = self.uvms.vehicle, self.layout.base_velocity
        nu, nu_next = x[twist], x_next[twist]
        rot = body_rotation(x)
        thrust = vehicle.clip_thrust(u[self.n_arm :])
        damping = (vehicle.linear_damping + vehicle.quadratic_damping * np.abs(nu)) * nu
        model = vehicle.allocation @ thrust + restoring_wrench(vehicle, rot) - damping
        return self.vehicle.inertia @ (nu_next - nu) / self.control_period - model

    def observe(self, t: float, y: np.ndarray, u: np.ndarray, y_next: np.ndarray) -> None:
        self.arm_controller.observe(t, self.layout.arm_state(y), u[: self.n_arm], self.layout.arm_state(y_next))
        if self.gp is None or self._features is None:
            return
        target = self.residual(y, u, y_next)
        if not np.all(np.isfinite(target)):
            self._pending_events.append("gp_sample_rejected")
            return
        self.gp.update(self._features, target)
        _, events = self.gp.update_hyperparameters(return_events=True)
        self._pending_events.extend(events)
