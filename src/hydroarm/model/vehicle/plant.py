"""The true floating plant: vehicle + arm + water + thrusters, integrated by a Lie-group RK4.

State ``x = [q (7 + n), v (6 + n), f (n_thr)]``: the configuration (base position, base
quaternion (x, y, z, w), arm angles), the velocity (body twist of the base, arm rates) and
the thrusters' actual forces (N). Input ``u = [tau_arm (n), f_cmd (n_thr)]`` (N m, N), held
over the control period: the commanded thrust is clipped to each thruster's limits and,
with a thrust time constant T > 0, reached with the first-order lag ``f' = (f_cmd - f) / T``,
solved in closed form at every RK4 stage time (so the lag adds no stiffness).

Integration: RKMK4 (Munthe-Kaas' Runge-Kutta on Lie groups, classic RK4 tableau). A stage's
configuration is ``q0 (+) xi`` (Pinocchio's ``integrate``: the base moves by the SE(3)
exponential of ``xi``'s 6 first entries, the arm angles add); the base's stage slope is the
body velocity corrected by the inverse differential of the exponential,
``xi' = V + 1/2 [xi, V] + 1/12 [xi, [xi, V]]`` (the terms RK4 needs for fourth order; the
arm's angles commute and need none). The RK4 arithmetic and the exponential are compiled;
three Pinocchio calls per stage (CRBA, NLE, Jacobians and their time variation) remain.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import pinocchio as pin
from numba.core import types
from numba.experimental import structref

from hydroarm.config import FrozenModel
from hydroarm.model.dynamics.integrator import inner_step_setting, inner_steps
from hydroarm.model.vehicle.description import quaternion_matrix
from hydroarm.model.vehicle.system import UVMS, UVMSDynamics, uvms_acceleration_kernel
from hydroarm.model.water.current import current_at
from hydroarm.model.water.morison import Water


class UVMSPlantConfig(FrozenModel):
    """``inner_step`` (s, in [1e-5, 0.1]): the longest RK4 step (the control period is split
    into equal steps no longer than this)."""

    inner_step: float = inner_step_setting(1e-3, "the floating plant")


@dataclass(frozen=True)
class UVMSStepInfo:
    """``thrust_wrench`` (6,): the thrusters' body wrench averaged over the step with the RK4
    weights (N, N m); ``disturbance`` (n_arm,): NaN, the arm's generalised disturbance is not
    separated on the floating system (the field of the plant protocol,
    :class:`hydroarm.sim.plant_protocol.Plant`)."""

    thrust_wrench: np.ndarray
    disturbance: np.ndarray


class UVMSPlant:
    """The floating plant (module docstring). Owns its :class:`UVMSDynamics` (and Pinocchio
    workspace): one plant per thread."""

    def __init__(self, uvms: UVMS, water: Water | None = None, config: UVMSPlantConfig | None = None):
        self.uvms = uvms
        self.config = config if config is not None else UVMSPlantConfig()
        self.dynamics = UVMSDynamics(uvms, water)
        self.water = self.dynamics.water
        self.nq, self.nv = uvms.nq, uvms.nv
        self.n_arm = uvms.n_arm
        self.n_thr = uvms.vehicle.n_thrusters
        self.n_state = self.nq + self.nv + self.n_thr
        self.layout = uvms.layout  # the state's parts by name
        self.n = self.n_arm  # the plant protocol's joints: the arm's
        self.n_inputs = self.n_arm + self.n_thr  # u = [tau_arm, thrust command]
        self.state_size = self.n_state
        self._unknown = np.full(self.n_arm, np.nan)
        self.rkmk4 = RKMK4(self.nq, self.nv, self.n_thr)

    def joint_state(self, x: np.ndarray) -> np.ndarray:
        """The arm's [q, v] (2 n_arm,) of a state [q, v, f]."""
        return self.layout.arm_state(x)

    def state_record(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """The vehicle's part of a state, for the trajectory: ``base_pose`` (7: position m,
        quaternion x y z w), ``base_velocity`` (6: body twist), ``thrust`` (n_thr: the
        thrusters' delivered forces, N)."""
        parts = self.layout
        return {
            "base_pose": x[parts.base_pose].copy(),
            "base_velocity": x[parts.base_velocity].copy(),
            "thrust": x[parts.thrust].copy(),
        }

    def measure(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The measured state: the true state (no sensor model on the floating system; ``rng``
        is not drawn from)."""
        return np.array(x, dtype=float)

    def new_sensor(self, period: float, rng: np.random.Generator, seed: int) -> None:
        """None: the floating system's sensor is :meth:`measure` (the true state)."""
        return None

    def new_actuator(self, period: float) -> None:
        """None: the arm's torques act as commanded; the thrusters' lag is in the plant's state."""
        return None

    def initial_state(self, q: np.ndarray | None = None, v: np.ndarray | None = None) -> np.ndarray:
        """``[q, v, f = 0]`` (default: the neutral configuration at rest)."""
        q = self.uvms.neutral() if q is None else np.asarray(q, dtype=float)
        v = np.zeros(self.nv) if v is None else np.asarray(v, dtype=float)
        return np.concatenate([q, v, np.zeros(self.n_thr)])

    def split(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(q, v, thrust)`` views of a state."""
        parts = self.layout
        return x[parts.q], x[parts.v], x[parts.thrust]

    def step(self, t: float, x: np.ndarray, u: np.ndarray, dt: float) -> tuple[np.ndarray, UVMSStepInfo]:
        """Integrate from (t, x) over dt (s) under the held input ``u = [tau_arm, f_cmd]``."""
        steps, h = inner_steps(dt, self.config.inner_step)
        vehicle = self.uvms.vehicle
        u = np.asarray(u, dtype=float)
        x = np.asarray(x, dtype=float)
        rkmk4 = self.rkmk4
        parts = self.layout
        qs, vs = rkmk4.start(x[parts.q], x[parts.v])
        rkmk4.tau[:] = 0.0
        rkmk4.tau[6:] = u[: self.n_arm]
        rkmk4.target[:] = np.clip(u[self.n_arm :], vehicle.thrust_min, vehicle.thrust_max)
        rkmk4.thrust0[:] = x[parts.thrust]
        dyn = self.dynamics
        model, data = self.uvms.model, dyn.data
        strips, water, work = dyn.strips, dyn.vehicle, rkmk4.work
        time = t
        for _ in range(steps):
            for stage, stage_time in enumerate(stage_times(time, h)):
                pin.crba(model, data, qs)
                nonlinear = pin.nonLinearEffects(model, data, qs, vs)
                pin.computeJointJacobiansTimeVariation(model, data, qs, vs)
                rkmk4_stage_kernel(stage, stage_time, t, h, data.M, nonlinear, data.J, data.dJ, water, strips, work)
            rkmk4.end_step()
            time += h
        thrust = thrust_at(rkmk4.target, rkmk4.thrust0, dt, float(vehicle.thrust_time_constant))
        return np.concatenate([rkmk4.q0, rkmk4.v0, thrust]), UVMSStepInfo(
            thrust_wrench=rkmk4.wrench / (6.0 * steps), disturbance=self._unknown.copy()
        )

    def acceleration(self, t: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """v' (nv,) at state x under input u, the thrust being the state's ``f``."""
        q, v, thrust = self.split(np.asarray(x, dtype=float))
        tau = np.zeros(self.nv)
        tau[6:] = np.asarray(u, dtype=float)[: self.n_arm]
        return self.dynamics.acceleration(t, q, v, tau, thrust)


@numba.njit(cache=True)
def thrust_at(target, thrust0, elapsed, lag):  # pragma: no cover - compiled
    """Thrust after ``elapsed`` s of the first-order lag toward ``target`` from ``thrust0``."""
    if lag <= 0.0:
        return target.copy()
    decay = np.exp(-elapsed / lag)
    return target + (thrust0 - target) * decay


@numba.njit(cache=True)
def se3_exp_quaternion(xi):  # pragma: no cover - compiled
    """SE(3) exponential of the twist ``xi`` = (v, omega): ``(translation (3,), quaternion (4,) x y z w)``."""
    wx, wy, wz = xi[3], xi[4], xi[5]
    theta2 = wx * wx + wy * wy + wz * wz
    theta = np.sqrt(theta2)
    if theta2 < 1e-8:
        a = 0.5 - theta2 / 24.0 + theta2 * theta2 / 720.0  # (1 - cos) / theta^2
        b = 1.0 / 6.0 - theta2 / 120.0 + theta2 * theta2 / 5040.0  # (theta - sin) / theta^3
        c = 0.5 - theta2 / 48.0 + theta2 * theta2 / 3840.0  # sin(theta/2) / theta
        w = 1.0 - theta2 / 8.0 + theta2 * theta2 / 384.0  # cos(theta/2)
    else:
        a = (1.0 - np.cos(theta)) / theta2
        b = (theta - np.sin(theta)) / (theta2 * theta)
        c = np.sin(0.5 * theta) / theta
        w = np.cos(0.5 * theta)
    v = xi[:3]
    om = xi[3:]
    wv = np.array([wy * v[2] - wz * v[1], wz * v[0] - wx * v[2], wx * v[1] - wy * v[0]])
    wwv = np.array([wy * wv[2] - wz * wv[1], wz * wv[0] - wx * wv[2], wx * wv[1] - wy * wv[0]])
    translation = v + a * wv + b * wwv
    quaternion = np.array([c * om[0], c * om[1], c * om[2], w])
    return translation, quaternion


@numba.njit(cache=True)
def integrate_configuration(q0, xi, out):  # pragma: no cover - compiled
    """``out = q0 (+) xi``: Pinocchio's ``integrate`` for a free-flyer root and 1-DOF joints."""
    translation, dq = se3_exp_quaternion(xi[:6])
    x0, y0, z0, w0 = q0[3], q0[4], q0[5], q0[6]
    rot = quaternion_matrix(x0, y0, z0, w0)
    for i in range(3):
        out[i] = q0[i] + rot[i, 0] * translation[0] + rot[i, 1] * translation[1] + rot[i, 2] * translation[2]
    x1, y1, z1, w1 = dq[0], dq[1], dq[2], dq[3]
    x = w0 * x1 + x0 * w1 + y0 * z1 - z0 * y1
    y = w0 * y1 + y0 * w1 + z0 * x1 - x0 * z1
    z = w0 * z1 + z0 * w1 + x0 * y1 - y0 * x1
    w = w0 * w1 - x0 * x1 - y0 * y1 - z0 * z1
    norm = np.sqrt(x * x + y * y + z * z + w * w)
    out[3], out[4], out[5], out[6] = x / norm, y / norm, z / norm, w / norm
    for i in range(7, q0.shape[0]):
        out[i] = q0[i] + xi[i - 1]


@numba.njit(cache=True)
def _ad(xi, eta):  # pragma: no cover - compiled
    """se(3) bracket [xi, eta] of twists (v, omega): (w1 x v2 + v1 x w2, w1 x w2)."""
    out = np.empty(6)
    v1, w1, v2, w2 = xi[:3], xi[3:6], eta[:3], eta[3:6]
    out[0] = w1[1] * v2[2] - w1[2] * v2[1] + v1[1] * w2[2] - v1[2] * w2[1]
    out[1] = w1[2] * v2[0] - w1[0] * v2[2] + v1[2] * w2[0] - v1[0] * w2[2]
    out[2] = w1[0] * v2[1] - w1[1] * v2[0] + v1[0] * w2[1] - v1[1] * w2[0]
    out[3] = w1[1] * w2[2] - w1[2] * w2[1]
    out[4] = w1[2] * w2[0] - w1[0] * w2[2]
    out[5] = w1[0] * w2[1] - w1[1] * w2[0]
    return out


def stage_times(time: float, h: float) -> tuple[float, float, float, float]:
    """The times (s) of the four stages of an RK4 step of h from ``time``."""
    half = time + 0.5 * h
    return time, half, half, time + h


@structref.register
class RKMK4WorkType(types.StructRef):
    """numba type of :class:`RKMK4`'s workspace."""


class RKMK4Work(structref.StructRefProxy):
    """The workspace of an RKMK4 step (:class:`RKMK4`)."""


structref.define_boxing(RKMK4WorkType, RKMK4Work)
_F1, _F2 = types.float64[::1], types.float64[:, ::1]
RKMK4_WORK_TYPE = RKMK4WorkType([
    ("q0", _F1), ("v0", _F1), ("qs", _F1), ("vs", _F1), ("slopes", _F2), ("accelerations", _F2),
    ("increment", _F1), ("wrench", _F1), ("tau", _F1), ("thrust0", _F1), ("target", _F1),
])  # fmt: skip


@numba.njit(cache=True)
def new_rkmk4_work(arrays):  # pragma: no cover - compiled
    """A :class:`RKMK4Work` of the 11 arrays (the fields of ``RKMK4_WORK_TYPE``, in order)."""
    s = structref.new(RKMK4_WORK_TYPE)
    (s.q0, s.v0, s.qs, s.vs, s.slopes, s.accelerations, s.increment, s.wrench, s.tau, s.thrust0,
     s.target) = arrays  # fmt: skip
    return s


class RKMK4:
    """One plant's RKMK4 workspace (owned, like its Pinocchio data): the step's start ``q0``
    (nq,), ``v0`` (nv,), the stage state ``qs``, ``vs``, the stage ``slopes`` and
    ``accelerations`` (4, nv), the configuration ``increment`` (nv,), the thrust ``wrench``
    (6,) summed with the RK4 weights, and the held inputs ``tau`` (nv,), ``thrust0`` and
    ``target`` (n_thr,); ``work`` the same arrays as one :class:`RKMK4Work` for the kernels.
    Shared by the floating plant, its prescribed-motion variant and (inside compiled code) the
    fast path: :func:`rkmk4_advance` is the step's arithmetic."""

    def __init__(self, nq: int, nv: int, n_thr: int = 0):
        names = ("q0", "v0", "qs", "vs", "slopes", "accelerations", "increment", "wrench", "tau", "thrust0", "target")
        shapes = (nq, nv, nq, nv, (4, nv), (4, nv), nv, 6, nv, n_thr, n_thr)
        arrays = tuple(np.zeros(shape) for shape in shapes)
        for name, array in zip(names, arrays, strict=True):
            setattr(self, name, array)
        self.work = new_rkmk4_work(arrays)

    def start(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Begin a step at (q, v) (the thrust wrench reset): returns the stage state ``(qs, vs)``."""
        self.q0[:] = q
        self.v0[:] = v
        self.qs[:] = q
        self.vs[:] = v
        self.wrench[:] = 0.0
        return self.qs, self.vs

    def end_step(self) -> None:
        """After the fourth stage: the next inner step starts where this one ended."""
        self.q0[:] = self.qs
        self.v0[:] = self.vs


@numba.njit(cache=True)
def rkmk4_advance(stage, h, work, acc):  # pragma: no cover - compiled
    """Store the stage's acceleration ``acc`` (nv,) and write the next stage's state (or, after
    stage 3, the step's result) into ``work.qs``, ``work.vs``: :func:`rkmk4_update` then
    :func:`integrate_configuration`."""
    rkmk4_update(stage, h, work.v0, work.vs, acc, work.slopes, work.accelerations, work.increment)
    integrate_configuration(work.q0, work.increment, work.qs)


@numba.njit(cache=True)
def rkmk4_stage_kernel(
    stage, stage_time, step_start, h, mass_upper, nonlinear, jac, djac, vehicle, strips, work
):  # pragma: no cover
    """One RKMK4 stage at the stage state (``work.qs``, ``work.vs``), Pinocchio's terms evaluated
    there.

    Stores the stage's acceleration and its configuration slope (the velocity, the base part
    corrected by dexp^-1 of the stage's increment ``xi = qs (-) q0``), then writes the next
    stage's state into (qs, vs); after stage 3 the step's result. ``work.wrench`` accumulates
    the thrust wrench with the RK4 weights. ``vehicle``: :class:`~hydroarm.model.vehicle.system.VehicleWater`
    (its thrust lag and current too); ``strips`` the arm's floating strips.
    """
    thrust = thrust_at(work.target, work.thrust0, stage_time - step_start, vehicle.lag)
    joint_acceleration = np.empty(0)
    water_velocity = np.empty(3)
    current_at(stage_time, np.zeros((3, 0)), vehicle.current_world, joint_acceleration, water_velocity)
    acc = uvms_acceleration_kernel(
        work.qs, work.vs, work.tau, thrust, water_velocity, mass_upper, nonlinear, jac, djac, vehicle, strips
    )
    weight = 1.0 if stage == 0 or stage == 3 else 2.0
    thrust_wrench = vehicle.allocation @ thrust
    for i in range(6):
        work.wrench[i] += weight * thrust_wrench[i]
    rkmk4_advance(stage, h, work, acc)


@numba.njit(cache=True)
def rkmk4_update(stage, h, v0, vs, acc, slopes, accelerations, increment):  # pragma: no cover - compiled
    """The RKMK4 bookkeeping of one stage, shared by :class:`UVMSPlant` and the compiled fast path.

    Stores the stage's acceleration ``acc`` (nv,) and configuration slope (the velocity, its base
    part corrected by dexp^-1 of the stage's increment ``xi``, a multiple of the previous slope),
    then writes the next stage's configuration increment into ``increment`` (nv,) and its
    velocity into ``vs``; after stage 3, the step's increment and final velocity.
    """
    nv = vs.shape[0]
    scale = 0.0 if stage == 0 else (h if stage == 3 else 0.5 * h)
    xi = np.zeros(6)
    if stage > 0:
        for i in range(6):
            xi[i] = scale * slopes[stage - 1, i]
    first = _ad(xi, vs[:6])
    second = _ad(xi, first)
    for i in range(6):
        slopes[stage, i] = vs[i] + 0.5 * first[i] + second[i] / 12.0
    for i in range(6, nv):
        slopes[stage, i] = vs[i]
    for i in range(nv):
        accelerations[stage, i] = acc[i]
    if stage < 3:
        nxt = h if stage == 2 else 0.5 * h
        for i in range(nv):
            increment[i] = nxt * slopes[stage, i]
            vs[i] = v0[i] + nxt * accelerations[stage, i]
    else:
        sixth = h / 6.0
        for i in range(nv):
            increment[i] = sixth * (slopes[0, i] + 2.0 * slopes[1, i] + 2.0 * slopes[2, i] + slopes[3, i])
            vs[i] = v0[i] + sixth * (
                accelerations[0, i] + 2.0 * accelerations[1, i] + 2.0 * accelerations[2, i] + accelerations[3, i]
            )
