"""The whole vehicle-manipulator system's controller: an arm controller + a station keeper.

* The arm: any controller of the registry (default ``SMC``) built on the arm alone, fixed-base,
  seeing joint states only (:func:`mounted_arm`: the arm's dry model with gravity turned into
  its base frame as mounted on a level vehicle; the vehicle's motion is a disturbance to it).
* The vehicle: :class:`~hydroarm.control.vehicle_control.VehiclePID` or ``VehicleMPC``, blind
  to the arm, or coupling-aware: a :class:`~hydroarm.control.gp.SlidingWindowGP` learns what
  the vehicle-only model misses (the arm's reaction, weight and buoyancy, its water, and the
  current's drag) and the station keeper feeds its mean forward.

The GP's sample at step k: input ``[q_arm, v_arm, a_ref_arm]`` (what drives the arm's force on
the vehicle), target the body wrench residual ``M_v (nu_{k+1} - nu_k) / T - (B f + g_v(R) -
D(nu_k) nu_k)`` with M_v = M_RB + M_A and the vehicle's own restoring wrench g_v and damping
(the current unknown: relative velocity = nu).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from hydroarm.control.gp import GPConfig, SlidingWindowGP
from hydroarm.control.registry import build_controller
from hydroarm.control.vehicle_control import VehicleControlConfig, make_vehicle_controller, restoring_wrench
from hydroarm.model.arm import Arm
from hydroarm.model.uvms import UVMS


def mounted_arm(uvms: UVMS) -> Arm:
    """The arm's fixed-base model with gravity in its base frame as mounted on a level vehicle."""
    arm = uvms.arm
    model = arm.model.copy()
    gravity = uvms.mount.rotation.T @ uvms.model.gravity.linear
    model.gravity = pin.Motion(gravity, np.zeros(3))
    return dataclasses.replace(arm, model=model)


@dataclass
class UVMSOutput:
    """``u = [tau_arm, thrust]``; ``wrench`` the commanded body wrench; ``saturated`` thrust-limited;
    ``d_hat`` (6,) the fed-forward estimate (zeros when blind); ``timings`` (s)."""

    u: np.ndarray
    wrench: np.ndarray
    saturated: bool
    d_hat: np.ndarray
    timings: dict


class UVMSController:
    """Arm controller + station keeper (+ GP). ``compute(t, x, reference, target)``, ``observe``."""

    def __init__(
        self,
        uvms: UVMS,
        *,
        arm_controller: str = "SMC",
        vehicle: VehicleControlConfig | None = None,
        gp: GPConfig | None = None,
        aware: bool = False,
        control_period: float = 0.01,
        arm_sections: dict | None = None,
    ):
        self.uvms = uvms
        self.n_arm = uvms.n_arm
        self.period = control_period
        # the vehicle-manipulator plant gives its true state: an estimator set to "plant" passes it through
        self.arm = build_controller(
            arm_controller, mounted_arm(uvms), arm_sections or {}, control_period, sensor_variance=0.0
        )
        self.vehicle = make_vehicle_controller(uvms.vehicle, vehicle, control_period)
        self.aware = aware
        self.gp = SlidingWindowGP(3 * self.n_arm, 6, gp if gp is not None else GPConfig(window=60)) if aware else None
        self.name = f"{arm_controller}+{self.vehicle.config.kind.upper()}{'+GP' if aware else ''}"
        self._features = None

    def reset(self) -> None:
        self.arm.reset()
        self.vehicle.reset()
        if self.gp is not None:
            self.gp.reset()

    def features(self, x: np.ndarray, reference, t: float) -> np.ndarray:
        n, nq = self.n_arm, self.uvms.nq
        return np.concatenate([x[7:nq], x[nq + 6 : nq + 6 + n], reference.sample(t)[2]])

    def compute(self, t: float, x: np.ndarray, reference, target: np.ndarray) -> UVMSOutput:
        """Control for the measured plant state ``x = [q, v, f]``; ``reference`` the arm's joint
        reference; ``target`` the vehicle's pose (7: p, quaternion x y z w)."""
        start = time.perf_counter()
        n, nq = self.n_arm, self.uvms.nq
        y_arm = np.concatenate([x[7:nq], x[nq + 6 : nq + 6 + n]])
        tau = self.arm.compute(t, y_arm, reference).tau
        d_hat = np.zeros(6)
        gp_time = 0.0
        if self.gp is not None and self.gp.n_samples > 0:
            gp_start = time.perf_counter()
            mean, _ = self.gp.predict(self.features(x, reference, t))
            if np.all(np.isfinite(mean)):
                d_hat = mean
            gp_time = time.perf_counter() - gp_start
        thrust, wrench, saturated = self.vehicle.compute(x[:7], x[nq : nq + 6], target, d_hat)
        self._features = self.features(x, reference, t) if self.gp is not None else None
        timings = {"gp": gp_time, "total": time.perf_counter() - start}
        return UVMSOutput(np.concatenate([tau, thrust]), wrench, saturated, d_hat, timings)

    def residual(self, x: np.ndarray, u: np.ndarray, x_next: np.ndarray) -> np.ndarray:
        """What the vehicle-only model misses over the step (body wrench, N and N m)."""
        vehicle, nq = self.uvms.vehicle, self.uvms.nq
        nu, nu_next = x[nq : nq + 6], x_next[nq : nq + 6]
        rot = pin.Quaternion(x[6], *x[3:6]).toRotationMatrix()
        thrust = vehicle.clip_thrust(u[self.n_arm :])
        damping = (vehicle.linear_damping + vehicle.quadratic_damping * np.abs(nu)) * nu
        model = vehicle.allocation @ thrust + restoring_wrench(vehicle, rot) - damping
        return self.vehicle.inertia @ (nu_next - nu) / self.period - model

    def observe(self, t: float, x: np.ndarray, u: np.ndarray, x_next: np.ndarray) -> None:
        if self.gp is None or self._features is None:
            return
        target = self.residual(x, u, x_next)
        if np.all(np.isfinite(target)):
            self.gp.add(self._features, target)
            self.gp.update_hyperparameters()
