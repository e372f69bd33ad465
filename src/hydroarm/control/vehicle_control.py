"""Station keeping of the vehicle under the arm: thruster allocation, a cascaded PID, a linear MPC.

* :class:`ThrusterAllocation`: body wrench -> thruster forces. The pseudo-inverse of the 6 x n
  allocation matrix B when its answer is within the thrusters' limits; otherwise the box QP
  ``min |B f - w|^2 + eps |f|^2, f_min <= f <= f_max`` (DAQP, :mod:`hydroarm.control.qp`).
* :class:`VehiclePID`: ArduSub's structure: the pose error in the body frame (position
  ``R^T (p_ref - p)``, attitude the rotation vector of ``R^T R_ref``) -> a body velocity
  command (P, limited) -> a body wrench (PI on the velocity error, scaled by the vehicle's
  rigid + added mass), plus the vehicle's own restoring wrench (weight and buoyancy: the only
  model term it uses) and an optional learned feed-forward ``-d_hat``.
* :class:`VehicleMPC`: a linear MPC on the 6-DOF model linearised about hover (pose error and
  body velocity, inertia M_RB + M_A, linear damping; the restoring wrench is fed forward, not
  modelled), condensed, with
  box bounds on the wrench (each axis' reach through the allocation), the same integral
  action and feed-forward; DAQP.

Both see the vehicle's pose and twist only (blind to the arm); the coupling-aware variant
(:mod:`hydroarm.control.uvms_control`) feeds a GP's estimate of the arm's force forward.
"""

from __future__ import annotations

import numpy as np
import pydantic
import scipy.linalg

from hydroarm.config import FrozenModel
from hydroarm.control.interface import DEFAULT_CONTROL_PERIOD
from hydroarm.control.mpc.condense import condense
from hydroarm.control.qp import DaqpBoxSolver
from hydroarm.model.vehicle.description import Vehicle, body_rotation, rotation_log

Six = list[float]


class VehicleControlConfig(FrozenModel):
    """Gains of the station-keeping controllers (per DOF: x y z roll pitch yaw, body frame)."""

    kind: str = pydantic.Field("pid", pattern="^(pid|mpc)$", description="pid or mpc")
    position_gain: Six = pydantic.Field([1.0, 1.0, 1.0, 2.0, 2.0, 1.5], description="P: pose error -> velocity (1/s)")
    velocity_gain: Six = pydantic.Field([4.0, 4.0, 4.0, 6.0, 6.0, 5.0], description="P on velocity, x mass (1/s)")
    integral_gain: Six = pydantic.Field([3.0, 3.0, 3.0, 4.0, 4.0, 3.0], description="I on velocity, x mass (1/s^2)")
    max_speed: Six = pydantic.Field([0.5, 0.5, 0.5, 1.0, 1.0, 1.0], description="velocity command limit (m/s, rad/s)")
    horizon: int = pydantic.Field(15, ge=2, le=100, description="MPC steps (-)")
    mpc_step: float = pydantic.Field(0.05, gt=0.0, le=1.0, description="MPC prediction step (s)")
    mpc_pose_weight: Six = pydantic.Field([400.0, 400.0, 400.0, 100.0, 100.0, 100.0], description="Q on pose error")
    mpc_velocity_weight: Six = pydantic.Field([10.0, 10.0, 10.0, 1.0, 1.0, 1.0], description="Q on body velocity")
    mpc_input_weight: float = pydantic.Field(1e-3, gt=0.0, description="R on the wrench (1/N^2)")
    allocation_regularisation: float = pydantic.Field(1e-6, gt=0.0, description="eps of the allocation QP")


class ThrusterAllocation:
    """Body wrench (6,) -> thrust (n,) within ``[thrust_min, thrust_max]`` (module docstring)."""

    def __init__(self, vehicle: Vehicle, regularisation: float = 1e-6):
        self.matrix = vehicle.allocation
        self.lower, self.upper = vehicle.thrust_min, vehicle.thrust_max
        self.pinv = np.linalg.pinv(self.matrix)
        self.hessian = self.matrix.T @ self.matrix + regularisation * np.eye(self.matrix.shape[1])
        self.solver = DaqpBoxSolver()
        reach = np.minimum(self.upper, -self.lower)
        self.wrench_limit = np.abs(self.matrix) @ reach  # per axis, each alone

    def allocate(self, wrench: np.ndarray) -> tuple[np.ndarray, bool]:
        """``(thrust, saturated)``: saturated when the pseudo-inverse's answer was out of bounds."""
        thrust = self.pinv @ wrench
        if np.all(thrust >= self.lower) and np.all(thrust <= self.upper):
            return thrust, False
        result = self.solver.solve(self.hessian, -self.matrix.T @ wrench, self.lower, self.upper, np.clip(
            thrust, self.lower, self.upper))  # fmt: skip
        if result.x is None:
            return np.clip(thrust, self.lower, self.upper), True
        return np.clip(result.x, self.lower, self.upper), True


def pose_error(q_vehicle: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Body-frame error (6,) from the vehicle pose (7: p, quaternion x y z w) to ``target`` (7)."""
    rot = body_rotation(q_vehicle)
    rot_ref = body_rotation(target)
    return np.concatenate([rot.T @ (target[:3] - q_vehicle[:3]), rotation_log(rot.T @ rot_ref)])


def restoring_wrench(vehicle: Vehicle, rot: np.ndarray, rho: float = 1000.0, gravity: float = 9.81) -> np.ndarray:
    """The vehicle's own weight and buoyancy as a body wrench (6,) (the arm is not in it)."""
    up = rot[2]  # world z in the body frame
    weight = -vehicle.mass * gravity * up
    buoyancy = rho * gravity * vehicle.displaced_volume * up
    return np.concatenate([weight + buoyancy, np.cross(vehicle.cg, weight) + np.cross(vehicle.cb, buoyancy)])


class VehiclePID:
    """Cascaded pose -> velocity -> wrench PID (module docstring). ``compute(q7, nu, target, d_hat)``."""

    def __init__(
        self,
        vehicle: Vehicle,
        config: VehicleControlConfig | None = None,
        control_period: float = DEFAULT_CONTROL_PERIOD,
    ):
        self.vehicle = vehicle
        self.config = config if config is not None else VehicleControlConfig()
        self.period = control_period
        inertia = np.zeros((6, 6))
        inertia[:3, :3] = vehicle.mass * np.eye(3)
        inertia[3:, 3:] = vehicle.inertia
        self.inertia = inertia + vehicle.added_mass
        self.scale = np.diag(self.inertia)
        self.allocation = ThrusterAllocation(vehicle, self.config.allocation_regularisation)
        self.integral = np.zeros(6)

    def reset(self) -> None:
        self.integral[:] = 0.0

    def _integrate(self, error: np.ndarray, wrench_fb: np.ndarray, feed: np.ndarray) -> np.ndarray:
        """Anti-windup: integrate only while the total stays within the thrusters' reach."""
        c = self.config
        candidate = self.integral + self.period * error
        total = wrench_fb + self.scale * np.asarray(c.integral_gain) * candidate + feed
        if np.all(np.abs(total) <= self.allocation.wrench_limit):
            self.integral = candidate
        return self.scale * np.asarray(c.integral_gain) * self.integral

    def compute(self, q_vehicle: np.ndarray, nu: np.ndarray, target: np.ndarray, d_hat: np.ndarray | None = None):
        """``(thrust (n,), wrench (6,), saturated)``."""
        c = self.config
        rot = body_rotation(q_vehicle)
        error = pose_error(q_vehicle, target)
        command = np.clip(np.asarray(c.position_gain) * error, -np.asarray(c.max_speed), np.asarray(c.max_speed))
        velocity_error = command - nu
        feed = -restoring_wrench(self.vehicle, rot) - (0.0 if d_hat is None else d_hat)
        wrench_fb = self.scale * np.asarray(c.velocity_gain) * velocity_error
        wrench = wrench_fb + self._integrate(velocity_error, wrench_fb, feed) + feed
        thrust, saturated = self.allocation.allocate(wrench)
        return thrust, wrench, saturated


class VehicleMPC(VehiclePID):
    """Linear MPC about hover (module docstring), integral action and feed-forward as the PID's.

    The prediction model is the hover linearisation *without* the restoring stiffness: the
    commanded wrench already carries ``-restoring_wrench`` (the vehicle's own weight and
    buoyancy at the measured attitude), so the plant sees no restoring moment from the MPC's
    deviation variable; modelling it again would count it twice. Condensed once, here, by
    :func:`hydroarm.control.mpc.condense.condense` (the one condensing routine of every MPC).
    """

    def __init__(
        self,
        vehicle: Vehicle,
        config: VehicleControlConfig | None = None,
        control_period: float = DEFAULT_CONTROL_PERIOD,
    ):
        super().__init__(vehicle, config, control_period)
        c = self.config
        self.ad, self.bd = hover_model(vehicle, self.inertia, c.mpc_step)
        n = c.horizon
        weights = np.concatenate([c.mpc_pose_weight, c.mpc_velocity_weight])
        tiled_a, tiled_b = np.tile(self.ad, (n, 1, 1)), np.tile(self.bd, (n, 1, 1))
        inputs = c.mpc_input_weight * np.ones(6)
        condensed = [
            condense(tiled_a, tiled_b, np.zeros((n, 12)), weights, inputs, np.diag(weights), e0) for e0 in np.eye(12)
        ]
        self.hessian = condensed[0].H
        self.gradient_map = np.column_stack([problem.g for problem in condensed])  # (6 N, 12): g = F s
        self.solver = DaqpBoxSolver()
        self.warm = np.zeros(6 * n)

    def reset(self) -> None:
        super().reset()
        self.warm[:] = 0.0

    def compute(self, q_vehicle: np.ndarray, nu: np.ndarray, target: np.ndarray, d_hat: np.ndarray | None = None):
        c = self.config
        rot = body_rotation(q_vehicle)
        error = pose_error(q_vehicle, target)
        feed = -restoring_wrench(self.vehicle, rot) - (0.0 if d_hat is None else d_hat)
        integral = self._integrate(error, np.zeros(6), feed)
        offset = feed + integral  # the wrench the MPC's deviation variable rides on
        state = np.concatenate([-error, nu])
        n = c.horizon
        gradient = self.gradient_map @ state
        limit = np.tile(self.allocation.wrench_limit, n)
        lower, upper = -limit - np.tile(offset, n), limit - np.tile(offset, n)
        result = self.solver.solve(self.hessian, gradient, lower, upper, np.clip(self.warm, lower, upper))
        if result.x is None:
            delta = np.clip(-np.linalg.solve(self.hessian, gradient), lower, upper)
        else:
            delta = result.x
        self.warm = np.concatenate([delta[6:], delta[-6:]])
        wrench = delta[:6] + offset
        thrust, saturated = self.allocation.allocate(wrench)
        return thrust, wrench, saturated


def hover_model(vehicle: Vehicle, inertia: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """``(A_d (12, 12), B_d (12, 6))``: the vehicle about hover, zero-order hold over ``step`` s,
    state ``[pose deviation (6), body velocity (6)]``, input the body wrench beyond the
    restoring feed-forward; ``inertia`` (6, 6) = M_RB + M_A. Linear damping plus the quadratic
    damping linearised at |nu_r| = 0.1; no restoring stiffness (:class:`VehicleMPC`)."""
    minv = np.linalg.inv(inertia)
    damping = np.diag(vehicle.linear_damping + 0.1 * vehicle.quadratic_damping)
    a = np.zeros((12, 12))
    a[:6, 6:] = np.eye(6)
    a[6:, 6:] = -minv @ damping
    b = np.vstack([np.zeros((6, 6)), minv])
    block = scipy.linalg.expm(np.block([[a, b], [np.zeros((6, 18))]]) * step)
    return block[:12, :12], block[:12, 12:]


def make_vehicle_controller(
    vehicle: Vehicle, config: VehicleControlConfig | None = None, control_period=DEFAULT_CONTROL_PERIOD
):
    """:class:`VehiclePID` or :class:`VehicleMPC` by ``config.kind``."""
    config = config if config is not None else VehicleControlConfig()
    cls = VehicleMPC if config.kind == "mpc" else VehiclePID
    return cls(vehicle, config, control_period)
