"""The vehicle under a prescribed arm motion: the joints follow given q(t), q'(t), q''(t) and only
the vehicle is integrated (the replay of a logged arm motion on a floating vehicle).

Hybrid dynamics, exactly: the floating system's equations ``M(q) v' = rhs(q, v) + tau`` (the
water's added mass in M; gravity, buoyancy, drag, Coriolis in rhs: :meth:`UVMSDynamics.system`)
split into the vehicle's 6 rows and the arm's n rows. With the arm's acceleration ``a`` given,

    M_bb nu' = rhs_b + w_ext,b - M_ba a           (the vehicle, solved: 6 x 6)
    tau_arm  = M_ab nu' + M_aa a - rhs_a - w_ext,a  (the joint torques that motion takes)

``w_ext`` the generalised force of external wrenches: the input ``u`` (6,), a body wrench on
the vehicle at its body origin (N, N m, body frame), plus fixed :class:`PointWrench` es (a
tether: a world-frame force and moment at a point of any body). No torque has to be guessed
and no tracking loop probes the plant: this is cheaper than driving the free-floating plant
with a computed-torque controller, and the same dynamics (a test drives
:class:`~hydroarm.model.vehicle.plant.UVMSPlant` with ``tau_arm`` and gets the same v').

State ``x = [q (7 + n), v (6 + n)]`` as the floating plant's without the thrust (a passive
vehicle's thrusters, if any, deliver nothing). Integration: the floating plant's RKMK4 (its
workspace :class:`~hydroarm.model.vehicle.plant.RKMK4` and arithmetic
:func:`~hydroarm.model.vehicle.plant.rkmk4_advance`) on the vehicle; at every stage the arm's angles
and rates are set to the prescription at the stage's time. The water is the floating plant's
(:class:`~hydroarm.model.vehicle.system.UVMSDynamics`: the same strip kernel as every plant).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import pinocchio as pin

from hydroarm.model.dynamics.integrator import inner_steps
from hydroarm.model.vehicle.plant import RKMK4, UVMSPlantConfig, rkmk4_advance, stage_times
from hydroarm.model.vehicle.system import UVMS, StateLayout, UVMSDynamics
from hydroarm.model.water.morison import Water


class JointMotion(Protocol):
    """A prescribed joint motion: ``sample(t) -> (q, v, a)`` (rad, rad/s, rad/s^2; each (n,))."""

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


@dataclass(frozen=True)
class PointWrench:
    """A fixed external wrench: ``force`` (N) and ``moment`` (N m), world frame, at ``point``
    (m, in the Pinocchio frame ``frame``: ``"vehicle"`` or an arm link)."""

    frame: str
    point: tuple[float, float, float] = (0.0, 0.0, 0.0)
    force: tuple[float, float, float] = (0.0, 0.0, 0.0)
    moment: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class PrescribedStepInfo:
    """``arm_torque`` (n,): the joint torques the motion took, averaged over the step with the
    RK4 weights (N m); ``disturbance`` (n,): NaN (the protocol's field)."""

    arm_torque: np.ndarray
    disturbance: np.ndarray = field(default_factory=lambda: np.zeros(0))


class PrescribedUVMSPlant:
    """The vehicle integrated under a prescribed arm motion (module docstring); the plant
    protocol (:class:`hydroarm.sim.plant_protocol.Plant`) with ``u`` the vehicle body wrench (6,)."""

    def __init__(
        self,
        uvms: UVMS,
        motion: JointMotion,
        water: Water | None = None,
        config: UVMSPlantConfig | None = None,
        wrenches: tuple[PointWrench, ...] = (),
    ):
        self.uvms = uvms
        self.motion = motion
        self.config = config if config is not None else UVMSPlantConfig()
        self.dynamics = UVMSDynamics(uvms, water)
        self.water = self.dynamics.water
        self.nq, self.nv, self.n_arm = uvms.nq, uvms.nv, uvms.n_arm
        self.n = self.n_arm
        self.n_inputs = 6
        self.state_size = self.nq + self.nv
        self.layout = StateLayout(uvms.n_arm)  # the state's parts by name (no thrust)
        self._thrust = np.zeros(uvms.vehicle.n_thrusters)
        model = uvms.model
        for wrench in wrenches:
            if not model.existFrame(wrench.frame):
                names = [f.name for f in model.frames if f.name != "universe"]
                raise ValueError(f"wrench frame {wrench.frame!r}: no such body frame (one of {', '.join(names)})")
        self.wrenches = tuple(wrenches)
        self._data = model.createData()
        self.rkmk4 = RKMK4(self.nq, self.nv)

    # --- the protocol -------------------------------------------------------------------
    def joint_state(self, x: np.ndarray) -> np.ndarray:
        return self.layout.arm_state(x)

    def state_record(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """``base_pose`` (7: position m, quaternion x y z w), ``base_velocity`` (6: body twist)."""
        parts = self.layout
        return {"base_pose": x[parts.base_pose].copy(), "base_velocity": x[parts.base_velocity].copy()}

    def measure(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The true state (``rng`` is not drawn from)."""
        return np.array(x, dtype=float)

    def new_sensor(self, period: float, rng: np.random.Generator, seed: int) -> None:
        return None

    def new_actuator(self, period: float) -> None:
        return None

    def initial_state(self, t: float, pose: np.ndarray | None = None, twist: np.ndarray | None = None) -> np.ndarray:
        """``[q, v]`` at time t: the vehicle at ``pose`` (7: position m, quaternion x y z w;
        default level at the origin) with body ``twist`` (6, default 0), the arm as prescribed."""
        q = self.uvms.neutral()
        if pose is not None:
            q[self.layout.base_pose] = pose
        v = np.zeros(self.nv)
        if twist is not None:
            v[:6] = twist
        qa, va, _ = self.motion.sample(t)
        q[7:], v[6:] = qa, va
        return np.concatenate([q, v])

    # --- the dynamics -------------------------------------------------------------------
    def external_force(self, q: np.ndarray, body_wrench: np.ndarray | None = None) -> np.ndarray:
        """Generalised force (nv,) of the input body wrench (6, body frame) and the fixed wrenches."""
        out = np.zeros(self.nv)
        if body_wrench is not None:
            out[:6] = body_wrench
        if self.wrenches:
            model, data = self.uvms.model, self._data
            pin.computeJointJacobians(model, data, q)
            pin.updateFramePlacements(model, data)
            for wrench in self.wrenches:
                fid = model.getFrameId(wrench.frame)
                point = data.oMf[fid].act(np.asarray(wrench.point, dtype=float))
                jac = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
                lever = point - data.oMf[fid].translation
                linear = jac[:3] - pin.skew(lever) @ jac[3:]
                out += linear.T @ np.asarray(wrench.force, dtype=float)
                out += jac[3:].T @ np.asarray(wrench.moment, dtype=float)
        return out

    def free_force(self, t: float, x: np.ndarray) -> np.ndarray:
        """The generalised force (nv,) on the system at state x (nq + nv,) with no thrust and no
        external wrench: gravity, buoyancy, the water and the bias terms, ``M nu' = free_force``
        for the unactuated system (the right-hand side of :meth:`UVMSDynamics.system`)."""
        _, rhs = self.dynamics.system(t, x[self.layout.q], x[self.layout.v], np.zeros(self.nv), self._thrust)
        return rhs

    def accelerations(
        self, t: float, q: np.ndarray, v: np.ndarray, a: np.ndarray, body_wrench: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(nu' (6,), tau_arm (n,))`` at (q, v) with the arm's acceleration ``a`` (module docstring)."""
        mass, rhs = self.dynamics.system(t, q, v, np.zeros(self.nv), self._thrust)
        if self.wrenches or body_wrench is not None:
            rhs = rhs + self.external_force(q, body_wrench)
        nu_dot = np.linalg.solve(mass[:6, :6], rhs[:6] - mass[:6, 6:] @ a)
        tau = mass[6:, :6] @ nu_dot + mass[6:, 6:] @ a - rhs[6:]
        return nu_dot, tau

    def step(self, t: float, x: np.ndarray, u: np.ndarray | None, dt: float) -> tuple[np.ndarray, PrescribedStepInfo]:
        """Integrate the vehicle from (t, x) over dt (s) under the held body wrench ``u`` (6,) or None."""
        steps, h = inner_steps(dt, self.config.inner_step)
        body_wrench = None if u is None else np.asarray(u, dtype=float)
        x = np.asarray(x, dtype=float)
        rkmk4 = self.rkmk4
        qs, vs = rkmk4.start(x[self.layout.q], x[self.layout.v])
        acc = np.empty(self.nv)
        torque = np.zeros(self.n_arm)
        time = t
        for _ in range(steps):
            for stage, stage_time in enumerate(stage_times(time, h)):
                qa, va, aa = self.motion.sample(stage_time)
                qs[7:], vs[6:] = qa, va
                nu_dot, tau = self.accelerations(stage_time, qs, vs, aa, body_wrench)
                acc[:6], acc[6:] = nu_dot, aa
                torque += (1.0 if stage in (0, 3) else 2.0) * tau
                rkmk4_advance(stage, h, rkmk4.work, acc)
            qa, va, _ = self.motion.sample(time + h)
            qs[7:], vs[6:] = qa, va
            rkmk4.end_step()
            time += h
        info = PrescribedStepInfo(arm_torque=torque / (6.0 * steps), disturbance=np.full(self.n_arm, np.nan))
        return np.concatenate([rkmk4.q0, rkmk4.v0]), info
