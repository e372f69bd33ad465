"""The floating plant, fast: one compiled call per control step (rigid body + water + RKMK4).

The same equations as :mod:`hydroarm.model.vehicle.system` (docs/vehicle.md), evaluated body by body in
the bodies' own frames instead of through Pinocchio's world Jacobians:

* rigid body: Featherstone's RNEA (bias forces: Coriolis, gravity, external wrenches) and CRBA
  (mass matrix) on the free-flyer + revolute tree of the Pinocchio model, compiled; a 10 x 10
  Cholesky solve;
* the arm's water: the strip water of every plant (:func:`hydroarm.model.water.effects.cylinder_water`),
  each cylinder in the frame of its body (:func:`~hydroarm.model.vehicle.fast_kernels.body_frame`),
  with ``drag_points`` Gauss points per cylinder (per drag piece) instead of the water's
  ``quadrature_points``. The added-mass density ``rho C_m A (I - e e^T)`` of a cylinder is
  constant in its body's frame, so its line integral is a constant 6 x 6 body inertia
  (``J_b^T I_A J_b`` = the strips' ``M_A``), added to the body's inertia in the CRBA; the kernel
  adds the velocity term (exact with >= 2 points, a polynomial of degree 2). Buoyancy at the
  midpoint (exact); the drag split at the kink of ``|v_n|`` (the only approximation against the
  exact path; 8 points reproduce it to round-off, tests/test_uvms_fast.py);
* the vehicle's water (:func:`~hydroarm.model.vehicle.description.vehicle_generalised_force`), thrusters
  and their lag: as :class:`~hydroarm.model.vehicle.plant.UVMSPlant`.

``arm_drag``/``arm_added_mass``/``arm_buoyancy``/``arm_current`` switch each effect on the
arm only (the vehicle keeps the ``Water`` switches): the UVMS study's one-effect-off runs.
Measured speed and accuracy: docs/vehicle.md, "Speed".
"""

from __future__ import annotations

import numba
import numpy as np
import pydantic
from numba.core import types
from numba.experimental import structref

from hydroarm.config import FrozenModel
from hydroarm.model.dynamics.integrator import inner_step_setting, inner_steps
from hydroarm.model.vehicle.fast_kernels import RIGID_TREE_TYPE, WORK_TYPE, evaluate, new_rigid_tree, workspace
from hydroarm.model.vehicle.plant import UVMSPlant, UVMSStepInfo, integrate_configuration, rkmk4_update, thrust_at
from hydroarm.model.vehicle.system import UVMS, VEHICLE_WATER_TYPE, vehicle_water
from hydroarm.model.water.current import current_at
from hydroarm.model.water.morison import Water
from hydroarm.model.water.strips import STRIPS_TYPE, StripGeometry


class FastUVMSConfig(FrozenModel):
    """Settings of :class:`FastUVMSPlant`."""

    inner_step: float = inner_step_setting(5e-3, "the floating plant")
    drag_points: int = pydantic.Field(3, ge=1, le=16, description="Gauss points per drag piece on each cylinder (-)")
    arm_drag: bool = pydantic.Field(
        True, description="switch: drag on the arm alone (on/off); on only where water.drag is too"
    )
    arm_added_mass: bool = pydantic.Field(
        True, description="switch: added mass of the arm alone (on/off); on only where water.added_mass is too"
    )
    arm_buoyancy: bool = pydantic.Field(
        True, description="switch: buoyancy of the arm alone (on/off); on only where water.buoyancy is too"
    )
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


@structref.register
class FastUVMSType(types.StructRef):
    """numba type of :class:`FastUVMS`."""


class FastUVMS(structref.StructRefProxy):
    """What :func:`fast_step_kernel` reads, as one compiled handle (one argument to unbox per
    control step, not three): ``tree``, ``vehicle``, ``strips`` (:class:`FastUVMSDynamics`'s) and
    ``work``, their :func:`~hydroarm.model.vehicle.fast_kernels.workspace`, built once (the plant
    owns it, as it owns its Pinocchio data: one plant per thread), the held generalised force
    ``tau`` (nv,; its base part zero) and the thrusters' limits ``thrust_min``/``thrust_max``
    (n_thr,) N."""


structref.define_boxing(FastUVMSType, FastUVMS)
FAST_UVMS_TYPE = FastUVMSType([
    ("tree", RIGID_TREE_TYPE), ("vehicle", VEHICLE_WATER_TYPE), ("strips", STRIPS_TYPE), ("work", WORK_TYPE),
    ("tau", types.float64[::1]), ("thrust_min", types.float64[::1]), ("thrust_max", types.float64[::1]),
])  # fmt: skip


@numba.njit(cache=True)
def new_fast_uvms(nv, tree, vehicle, strips, thrust_min, thrust_max):  # pragma: no cover - compiled
    """A :class:`FastUVMS` of the three structures, the thrust limits and a new workspace for nv
    velocities."""
    s = structref.new(FAST_UVMS_TYPE)
    s.tree, s.vehicle, s.strips = tree, vehicle, strips
    s.work = workspace(nv, tree, vehicle, strips)
    s.tau = np.zeros(nv)
    s.thrust_min, s.thrust_max = thrust_min, thrust_max
    return s


@numba.njit(cache=True, inline="always")
def clip(value, low, high):  # pragma: no cover - compiled
    """``np.clip`` of one float, its arithmetic (numpy's ``_NPY_MIN(_NPY_MAX(value, low), high)``:
    NaN passes through, ties keep the bound)."""
    value = value if (value != value or value > low) else low
    return value if (value != value or value < high) else high


class FastUVMSDynamics:
    """Constant structures of the compiled path for one (system, water, settings) triple: the
    rigid tree (``tree``, its inertias ``rigid`` and with the added inertias ``total``, (nj, 6,
    6)), the vehicle (``vehicle``, :class:`~hydroarm.model.vehicle.system.VehicleWater`) and the arm's
    strips in its bodies' frames (``geometry``/``strips``: ``joint_ids`` the body carrying each
    cylinder, ``start``/``axis`` in its frame; the arm switches of ``config`` applied)."""

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
        arm_water = water.model_copy(update={
            "quadrature_points": config.drag_points,
            "drag": water.drag and config.arm_drag,
            "axial_drag": water.axial_drag and config.arm_drag,
            "added_mass": water.added_mass and config.arm_added_mass,
            "buoyancy": water.buoyancy and config.arm_buoyancy,
        })  # fmt: skip
        arm = uvms.arm
        if arm is not None and arm.cylinders:
            geometry = StripGeometry(arm, arm_water)
            mount = uvms.mount
            bodies, starts, axes = [], [], []
            for k in range(geometry.joint_ids.shape[0]):
                j = int(geometry.joint_ids[k])
                start, axis = geometry.start[k], geometry.axis[k]
                body = 1 if j == 0 else j + 1
                if j == 0:
                    start = mount.rotation @ start + mount.translation
                    axis = mount.rotation @ axis
                bodies.append(body)
                starts.append(start)
                axes.append(axis)
                if arm_water.added_mass:
                    total[body] += cylinder_added_inertia(start, axis, geometry.length[k], geometry.mass_per_length[k])
            geometry = geometry.replace(
                joint_ids=np.asarray(bodies, dtype=np.int64), start=np.asarray(starts, dtype=float).reshape(-1, 3),
                axis=np.asarray(axes, dtype=float).reshape(-1, 3), support=np.ones((len(bodies), 6)),
            )  # fmt: skip
        else:
            geometry = StripGeometry.empty(6, arm_water)
        if water.added_mass:
            total[1] += vehicle.added_mass
        self.total = total
        self.geometry = geometry
        self.strips = geometry.compiled
        self.vehicle = vehicle_water(vehicle, water)
        arrays = (self.parents, self.place_rotation, self.place_translation, self.axes, self.rigid, self.total)
        self.tree = new_rigid_tree(
            tuple(np.ascontiguousarray(a) for a in arrays), float(-model.gravity.linear[2]), bool(config.arm_current)
        )

    def acceleration(self, t: float, q: np.ndarray, v: np.ndarray, tau: np.ndarray, thrust: np.ndarray) -> np.ndarray:
        """v' (nv,) at time t under generalised force ``tau`` (nv; its base part a body wrench)."""
        from hydroarm.model.water.current import CurrentField

        water_velocity = CurrentField(self.water.current, 0).at(t)[1]
        nv = self.uvms.nv
        out = np.empty(nv)
        work = workspace(nv, self.tree, self.vehicle, self.strips)
        evaluate(np.asarray(q, float), np.asarray(v, float), np.asarray(tau, float), np.asarray(thrust, float),
                 water_velocity, self.tree, self.vehicle, self.strips, work, out)  # fmt: skip
        return out


@numba.njit(cache=True)
def fast_step_kernel(t, x, u, steps, h, fast):  # pragma: no cover - compiled
    """The whole control step under the held input ``u = [tau_arm, f_cmd]`` (the command clipped
    to the thrusters' limits): ``steps`` RKMK4 steps of h (the floating plant's arithmetic,
    :func:`~hydroarm.model.vehicle.plant.rkmk4_update` and
    :func:`~hydroarm.model.vehicle.plant.integrate_configuration`); returns (x_next, the thrust
    wrench averaged with the RK4 weights). ``fast``: the plant's :class:`FastUVMS`."""
    tree, vehicle, strips, work, u_tau = fast.tree, fast.vehicle, fast.strips, fast.work, fast.tau
    nv = u_tau.shape[0]
    nq = nv + 1
    n_arm = nv - 6
    allocation, lag, current_world = vehicle.allocation, vehicle.lag, vehicle.current_world
    n_thr = allocation.shape[1]
    if u.shape[0] != n_arm + n_thr:
        raise ValueError("u: expected [tau_arm (n_arm,), thrust command (n_thr,)]")
    for i in range(n_arm):
        u_tau[6 + i] = u[i]
    low, high = fast.thrust_min, fast.thrust_max
    target = np.empty(n_thr)
    for b in range(n_thr):
        target[b] = clip(u[n_arm + b], low[b], high[b])
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
            evaluate(qs, vs, u_tau, thrust, water_velocity, tree, vehicle, strips, work, acc)
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
    return out, wrench / (6.0 * steps)


class FastUVMSPlant(UVMSPlant):
    """:class:`UVMSPlant` with the compiled step of this module (one call per control step).
    ``config``: :class:`FastUVMSConfig` (inner step, drag points, the arm's effect switches)."""

    def __init__(self, uvms: UVMS, water: Water | None = None, config: FastUVMSConfig | None = None):
        config = config if config is not None else FastUVMSConfig()
        super().__init__(uvms, water)
        self.config = config
        self.fast = FastUVMSDynamics(uvms, self.water, config)
        fast = self.fast
        vehicle = uvms.vehicle
        limits = (np.array(vehicle.thrust_min, dtype=float), np.array(vehicle.thrust_max, dtype=float))
        self._compiled = new_fast_uvms(self.nv, fast.tree, fast.vehicle, fast.strips, *limits)
        self._split = (None, None, 0, 0.0)  # (dt, config, steps, h) of the last step

    def step(self, t: float, x: np.ndarray, u: np.ndarray, dt: float) -> tuple[np.ndarray, UVMSStepInfo]:
        """Integrate from (t, x) over dt (s) under the held input ``u = [tau_arm, f_cmd]``."""
        last_dt, config, steps, h = self._split
        if dt != last_dt or config is not self.config:
            steps, h = inner_steps(dt, self.config.inner_step)
            self._split = (dt, self.config, steps, h)
        x_next, wrench = fast_step_kernel(
            float(t), np.asarray(x, dtype=float), np.ascontiguousarray(u, dtype=float), steps, h, self._compiled
        )
        return x_next, UVMSStepInfo(thrust_wrench=wrench, disturbance=self._unknown.copy())

    def acceleration(self, t: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        q, v, thrust = self.split(np.asarray(x, dtype=float))
        tau = np.zeros(self.nv)
        tau[6:] = np.asarray(u, dtype=float)[: self.n_arm]
        return self.fast.acceleration(t, q, v, tau, thrust)


__all__ = ["FastUVMSConfig", "FastUVMSDynamics", "FastUVMSPlant", "cylinder_added_inertia"]
