"""The floating plant, fast: one compiled call per control step (rigid body + water + RKMK4).

The same equations as :mod:`hydroarm.model.uvms` (docs/vehicle.md), evaluated body by body in
the bodies' own frames instead of through Pinocchio's world Jacobians:

* rigid body: Featherstone's RNEA (bias forces: Coriolis, gravity, external wrenches) and CRBA
  (mass matrix) on the free-flyer + revolute tree of the Pinocchio model, compiled; a 10 x 10
  Cholesky solve;
* the arm's added mass: the Morison added-mass density ``rho C_m A (I - e e^T)`` of a cylinder
  is constant in its body's frame, so its line integral is a constant 6 x 6 body inertia
  (``J_b^T I_A J_b`` = the strips' ``M_A``), added to the body's inertia in the CRBA; the
  velocity term (``h_A``: the normal part of each point's classical acceleration at q'' = 0) is
  affine along the cylinder and integrated in closed form;
* buoyancy at the midpoint (exact); drag ``-1/2 rho C_d D |v_n| v_n`` split at its kink and
  integrated by Gauss-Legendre with ``drag_points`` per piece (the only approximation against
  the exact path; 8 points reproduce it to round-off, tests/test_uvms_fast.py);
* the vehicle's water (:func:`~hydroarm.model.vehicle.vehicle_generalised_force`), thrusters
  and their lag: as :class:`~hydroarm.model.uvms_plant.UVMSPlant`.

``arm_drag``/``arm_added_mass``/``arm_buoyancy``/``arm_current`` switch each effect on the
arm only (the vehicle keeps the ``Water`` switches): the UVMS study's one-effect-off runs.
Measured speed and accuracy: docs/vehicle.md, "Speed".
"""

from __future__ import annotations

import numba
import numpy as np
import pydantic

from hydroarm.config import ConfigError, FrozenModel
from hydroarm.model.current import current_at
from hydroarm.model.plant import inner_steps
from hydroarm.model.strips import StripGeometry
from hydroarm.model.uvms import UVMS
from hydroarm.model.uvms_fast_kernels import evaluate, workspace
from hydroarm.model.uvms_plant import UVMSPlant, UVMSStepInfo, integrate_configuration, rkmk4_update, thrust_at
from hydroarm.model.water import Water


class FastUVMSConfig(FrozenModel):
    """Settings of :class:`FastUVMSPlant`."""

    inner_step: float = pydantic.Field(5e-3, ge=1e-5, le=0.1, description="RK4 step (s)")
    drag_points: int = pydantic.Field(3, ge=1, le=16, description="Gauss points per drag piece on each cylinder (-)")
    arm_drag: bool = pydantic.Field(True, description="switch: drag on the arm (on/off)")
    arm_added_mass: bool = pydantic.Field(True, description="switch: added mass of the arm (on/off)")
    arm_buoyancy: bool = pydantic.Field(True, description="switch: buoyancy of the arm (on/off)")
    arm_current: bool = pydantic.Field(True, description="switch: the current seen by the arm's drag (on/off)")


def _skew(p: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]])


def cylinder_added_inertia(start: np.ndarray, axis: np.ndarray, length: float, mass_per_length: float) -> np.ndarray:
    """6 x 6 body inertia (linear first, about the body origin) of the Morison added-mass
    density ``mass_per_length (I - e e^T)`` along ``start + s axis``, s in [0, length]
    (2-point Gauss: exact, the integrand is quadratic in s)."""
    proj = mass_per_length * (np.eye(3) - np.outer(axis, axis))
    out = np.zeros((6, 6))
    for node in (0.5 - 0.5 / np.sqrt(3.0), 0.5 + 0.5 / np.sqrt(3.0)):
        r = _skew(start + node * length * axis)
        block = np.block([[proj, -proj @ r], [r @ proj, -r @ proj @ r]])
        out += 0.5 * length * block
    return out


class FastUVMSDynamics:
    """Constant arrays of the compiled path for one (system, water, settings) triple."""

    def __init__(self, uvms: UVMS, water: Water | None = None, config: FastUVMSConfig | None = None):
        water = water if water is not None else Water()
        if water.current.model == "paper":
            water = water.model_copy(update={"current": water.current.model_copy(update={"model": "none"})})
        config = config if config is not None else FastUVMSConfig()
        self.uvms, self.water, self.config = uvms, water, config
        model = uvms.model
        nj = model.njoints
        vehicle = uvms.vehicle
        self.parents = np.asarray(model.parents, dtype=np.int64)
        self.place_rotation = np.stack([model.jointPlacements[i].rotation for i in range(nj)])
        self.place_translation = np.stack([model.jointPlacements[i].translation for i in range(nj)])
        self.axes = np.zeros((nj, 3))
        for i in range(2, nj):
            name = model.joints[i].shortname()
            if name in ("JointModelRX", "JointModelRY", "JointModelRZ"):
                self.axes[i, "XYZ".index(name[-1])] = 1.0
            elif name == "JointModelRevoluteUnaligned":
                self.axes[i] = np.asarray(model.joints[i].extract().axis)
            else:
                raise ValueError(f"joint {model.names[i]}: type {name} is not supported (revolute only)")
        self.rigid = np.stack([model.inertias[i].matrix() for i in range(nj)])
        total = self.rigid.copy()
        rows = []
        arm = uvms.arm
        if arm is not None and arm.cylinders:
            if water.drag_model != "constant":
                raise ConfigError(
                    "water.drag_model = 'reynolds': only the fixed-base plant (UnderwaterPlant) has it; "
                    "use water.drag_model = 'constant' here"
                )
            geometry = StripGeometry(arm, water)
            mount = uvms.mount
            for k in range(geometry.joint_ids.shape[0]):
                j = int(geometry.joint_ids[k])
                start, axis = geometry.start[k], geometry.axis[k]
                body = 1 if j == 0 else j + 1
                if j == 0:
                    start = mount.rotation @ start + mount.translation
                    axis = mount.rotation @ axis
                rows.append((body, start, axis, geometry.length[k], geometry.drag_per_length[k],
                             geometry.mass_per_length[k], geometry.buoyancy_force[k]))  # fmt: skip
                if water.added_mass and config.arm_added_mass:
                    total[body] += cylinder_added_inertia(start, axis, geometry.length[k], geometry.mass_per_length[k])
        if water.added_mass:
            total[1] += vehicle.added_mass
        self.total = total
        self.cyl_body = np.asarray([r[0] for r in rows], dtype=np.int64)
        self.cyl_start = np.asarray([r[1] for r in rows], dtype=float).reshape(-1, 3)
        self.cyl_axis = np.asarray([r[2] for r in rows], dtype=float).reshape(-1, 3)
        self.cyl_values = np.asarray([r[3:] for r in rows], dtype=float).reshape(-1, 4)  # L, drag, mass, buoyancy
        nodes, weights = np.polynomial.legendre.leggauss(config.drag_points)
        self.nodes, self.weights = 0.5 * (nodes + 1.0), 0.5 * weights
        buoyancy = water.rho * water.gravity * vehicle.displaced_volume
        self.constants = (
            self.parents, self.place_rotation, self.place_translation, self.axes, self.rigid, self.total,
            self.cyl_body, self.cyl_start, self.cyl_axis, self.cyl_values, self.nodes, self.weights,
            vehicle.allocation, vehicle.added_mass, vehicle.linear_damping, vehicle.quadratic_damping,
            float(buoyancy), vehicle.cb, float(-model.gravity.linear[2]),
        )  # fmt: skip
        self.flags = np.array(
            [water.added_mass, water.drag, water.buoyancy, water.drag and config.arm_drag,
             water.added_mass and config.arm_added_mass, water.buoyancy and config.arm_buoyancy,
             config.arm_current], dtype=np.bool_,
        )  # fmt: skip

    def acceleration(self, t: float, q: np.ndarray, v: np.ndarray, tau: np.ndarray, thrust: np.ndarray) -> np.ndarray:
        """v' (nv,) at time t under generalised force ``tau`` (nv; its base part a body wrench)."""
        from hydroarm.model.current import CurrentField

        water_velocity = CurrentField(self.water.current, 0).at(t)[1]
        nv = self.uvms.nv
        out = np.empty(nv)
        evaluate(np.asarray(q, float), np.asarray(v, float), np.asarray(tau, float), np.asarray(thrust, float),
                 water_velocity, *self.constants, self.flags, workspace(self.parents.shape[0], nv), out)  # fmt: skip
        return out


@numba.njit(cache=True)
def fast_step_kernel(
    t, x, u_tau, target, steps, h, lag, n_thr, current_world,
    parents, place_rotation, place_translation, axes, rigid, total,
    cyl_body, cyl_start, cyl_axis, cyl_values, nodes, weights,
    allocation, added_mass, linear_damping, quadratic_damping, buoyancy, cb, gravity, flags,
):  # fmt: skip  # pragma: no cover - compiled
    """The whole control step: ``steps`` RKMK4 steps of h; returns (x_next, thrust wrench sum)."""
    nv = u_tau.shape[0]
    nq = nv + 1
    nj = parents.shape[0]
    work = workspace(nj, nv)
    q0 = x[:nq].copy()
    v0 = x[nq : nq + nv].copy()
    thrust0 = x[nq + nv :].copy()
    qs, vs = q0.copy(), v0.copy()
    slopes = np.empty((4, nv))
    accelerations = np.empty((4, nv))
    increment = np.empty(nv)
    acc = np.empty(nv)
    wrench = np.zeros(6)
    water_velocity = np.empty(3)
    none = np.empty(0)
    joints = np.zeros((3, 0))
    time = t
    for _ in range(steps):
        for stage in range(4):
            stage_time = time + (0.0 if stage == 0 else (h if stage == 3 else 0.5 * h))
            thrust = thrust_at(target, thrust0, stage_time - t, lag)
            current_at(stage_time, joints, current_world, none, water_velocity)
            evaluate(
                qs,
                vs,
                u_tau,
                thrust,
                water_velocity,
                parents,
                place_rotation,
                place_translation,
                axes,
                rigid,
                total,
                cyl_body,
                cyl_start,
                cyl_axis,
                cyl_values,
                nodes,
                weights,
                allocation,
                added_mass,
                linear_damping,
                quadratic_damping,
                buoyancy,
                cb,
                gravity,
                flags,
                work,
                acc,
            )
            weight = 1.0 if stage == 0 or stage == 3 else 2.0
            for i in range(6):
                s = 0.0
                for b in range(n_thr):
                    s += allocation[i, b] * thrust[b]
                wrench[i] += weight * s
            rkmk4_update(stage, h, v0, vs, acc, slopes, accelerations, increment)
            integrate_configuration(q0, increment, qs)
        q0[:] = qs
        v0[:] = vs
        time += h
    out = np.empty(x.shape[0])
    out[:nq] = q0
    out[nq : nq + nv] = v0
    out[nq + nv :] = thrust_at(target, thrust0, time - t, lag)
    return out, wrench


class FastUVMSPlant(UVMSPlant):
    """:class:`UVMSPlant` with the compiled step of this module (one call per control step).
    ``config``: :class:`FastUVMSConfig` (inner step, drag points, the arm's effect switches)."""

    def __init__(self, uvms: UVMS, water: Water | None = None, config: FastUVMSConfig | None = None):
        config = config if config is not None else FastUVMSConfig()
        super().__init__(uvms, water)
        self.config = config
        self.fast = FastUVMSDynamics(uvms, self.water, config)
        self._world = self.dynamics.current.world
        self._tau = np.zeros(self.nv)

    def step(self, t: float, x: np.ndarray, u: np.ndarray, dt: float) -> tuple[np.ndarray, UVMSStepInfo]:
        """Integrate from (t, x) over dt (s) under the held input ``u = [tau_arm, f_cmd]``."""
        steps, h = inner_steps(dt, self.config.inner_step)
        vehicle = self.uvms.vehicle
        u = np.asarray(u, dtype=float)
        self._tau[6:] = u[: self.n_arm]
        target = np.clip(u[self.n_arm :], vehicle.thrust_min, vehicle.thrust_max)
        x_next, wrench = fast_step_kernel(
            float(t), np.asarray(x, dtype=float), self._tau, target, steps, h, float(vehicle.thrust_time_constant),
            self.n_thr, self._world, *self.fast.constants, self.fast.flags,
        )  # fmt: skip
        return x_next, UVMSStepInfo(thrust_wrench=wrench / (6.0 * steps), disturbance=self._unknown.copy())

    def acceleration(self, t: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        q, v, thrust = self.split(np.asarray(x, dtype=float))
        tau = np.zeros(self.nv)
        tau[6:] = np.asarray(u, dtype=float)[: self.n_arm]
        return self.fast.acceleration(t, q, v, tau, thrust)


__all__ = ["FastUVMSConfig", "FastUVMSDynamics", "FastUVMSPlant", "cylinder_added_inertia"]
