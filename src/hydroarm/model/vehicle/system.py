"""The floating underwater vehicle-manipulator system (UVMS): one Pinocchio model, one set of water forces.

The model has a free-flyer root (the vehicle's body frame, origin at the body reference
point) carrying the vehicle's dry rigid body, and the arm's joints mounted at
``Vehicle.mount`` (``pin.appendModel``): q = [p (3, world), quaternion (x, y, z, w), q_arm],
v = [nu (6: body-frame linear and angular velocity, Fossen's [u v w p q r]), v_arm]. Bodies
the arm file fixes to its base (e.g. the Alpha 5's base module) become part of the root.

Equations of motion (docs/vehicle.md), solved for v' at every RK4 stage:

    (M(q) + M_A,arm(q) + M_A,veh) v' = tau - nle(q, v) - h_A,arm + f_arm + F_veh + B_thr f_thr

* ``M``, ``nle`` (Coriolis + weight of vehicle and arm): Pinocchio (CRBA, NLE);
* ``M_A,arm``, ``h_A,arm``, ``f_arm`` (drag on the velocity relative to the current, buoyancy):
  the arm's Morison strips, by the same compiled kernel as the fixed-base arm
  (:func:`hydroarm.model.water.strips.water_terms`). It works from the world joint Jacobian
  of the whole system (6 + n columns: the base's 6 DOF move every cylinder) and from the
  world placements of the arm's joints, which its revolute-only forward kinematics computes
  once the joints hung on the base are given the base's current world placement
  (:func:`floating_placements`). With the base fixed at the identity the operations on the
  arm's columns are those of the fixed-base arm, in the same order: the same numbers;
* ``M_A,veh`` (6 x 6, root block), ``F_veh``: the vehicle's added-mass Coriolis term,
  damping and buoyancy (:func:`hydroarm.model.vehicle.description.vehicle_generalised_force`);
* ``B_thr f_thr``: the thrusters' body wrench (allocation matrix times thrust).

The added mass of both arm and vehicle is in the matrix that is solved: no acceleration is
lagged a step.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numba
import numpy as np
import pinocchio as pin
from numba.core import types
from numba.experimental import structref

from hydroarm.config import ConfigError
from hydroarm.model.arm.description import Arm
from hydroarm.model.arm.loading import load_arm
from hydroarm.model.vehicle.description import Vehicle, load_vehicle, quaternion_matrix, vehicle_generalised_force
from hydroarm.model.water.current import CurrentField
from hydroarm.model.water.effects import DRAG_REYNOLDS
from hydroarm.model.water.morison import Water
from hydroarm.model.water.strips import StripGeometry, Strips, water_terms

ROOT_JOINT = 1
"""Pinocchio joint id of the free-flyer root (the vehicle)."""


@dataclass(frozen=True)
class StateLayout:
    """Where each part of the floating system's state sits, by name: ``x = [q (nq = 7 + n),
    v (nv = 6 + n), thrust (n_thr)]`` with ``q = [base position (3, world, m), quaternion
    (x, y, z, w), q_arm (n, rad)]`` and ``v = [nu (6: body-frame twist), v_arm (n, rad/s)]``
    (the prescribed-motion plant's state has no thrust: ``n_thrusters = 0``).

    Every field but ``n_arm`` and ``n_thrusters`` is a slice of x: ``q``, ``v``, ``thrust``,
    ``base_pose`` (7), ``arm_q`` (n), ``base_velocity`` (6), ``arm_v`` (n); ``nq``, ``nv`` and
    ``size`` are lengths. :meth:`arm_state` is the arm's joint state ``[q_arm, v_arm]`` (2n,).
    """

    n_arm: int
    n_thrusters: int = 0
    nq: int = dataclasses.field(init=False)
    nv: int = dataclasses.field(init=False)
    size: int = dataclasses.field(init=False)
    q: slice = dataclasses.field(init=False)
    v: slice = dataclasses.field(init=False)
    thrust: slice = dataclasses.field(init=False)
    base_pose: slice = dataclasses.field(init=False)
    arm_q: slice = dataclasses.field(init=False)
    base_velocity: slice = dataclasses.field(init=False)
    arm_v: slice = dataclasses.field(init=False)

    def __post_init__(self) -> None:
        n, nq, nv = self.n_arm, 7 + self.n_arm, 6 + self.n_arm
        parts = {
            "nq": nq,
            "nv": nv,
            "size": nq + nv + self.n_thrusters,
            "q": slice(0, nq),
            "v": slice(nq, nq + nv),
            "thrust": slice(nq + nv, nq + nv + self.n_thrusters),
            "base_pose": slice(0, 7),
            "arm_q": slice(7, nq),
            "base_velocity": slice(nq, nq + 6),
            "arm_v": slice(nq + 6, nq + 6 + n),
        }
        for name, value in parts.items():
            object.__setattr__(self, name, value)

    def arm_state(self, x: np.ndarray) -> np.ndarray:
        """The arm's joint state ``[q_arm, v_arm]`` (2n,) of a state (or measurement) x."""
        return np.concatenate([x[self.arm_q], x[self.arm_v]])


@dataclass
class UVMS:
    """A vehicle with an arm (or none): constants only (Pinocchio model + arm + vehicle).

    ``model``: free-flyer root + the arm's joints; ``arm_joint_ids[i]``: the system joint id
    of the arm's joint i + 1; ``n_arm`` arm DOF; ``mount`` the arm base in the body frame.
    """

    vehicle: Vehicle
    arm: Arm | None
    model: pin.Model
    mount: pin.SE3
    arm_joint_ids: np.ndarray

    @property
    def n_arm(self) -> int:
        return 0 if self.arm is None else self.arm.n_joints

    @property
    def nq(self) -> int:
        return int(self.model.nq)

    @property
    def nv(self) -> int:
        return int(self.model.nv)

    @property
    def layout(self) -> StateLayout:
        """The floating plant's state layout (:class:`StateLayout`), its thrusters included."""
        return StateLayout(self.n_arm, self.vehicle.n_thrusters)

    def create_data(self) -> pin.Data:
        return self.model.createData()

    def neutral(self, position=(0.0, 0.0, 0.0), q_arm: np.ndarray | None = None) -> np.ndarray:
        """A configuration (nq,): the vehicle level at ``position`` (m), the arm at ``q_arm`` (default 0)."""
        q = pin.neutral(self.model)
        q[:3] = position
        if q_arm is not None:
            q[7:] = q_arm
        return q


def build_uvms(
    vehicle: Vehicle | str | None = None,
    arm: Arm | str | None = "mount",
    *,
    mount: pin.SE3 | None = None,
    gravity: float | None = None,
) -> UVMS:
    """The floating system of ``vehicle`` (default the BlueROV2 Heavy) with ``arm`` mounted.

    ``arm``: an :class:`Arm`, a built-in name or file (``load_arm``), ``"mount"`` (the arm
    the vehicle file names, the Alpha 5 for the BlueROV2 Heavy) or None (the vehicle alone).
    ``mount``: override the vehicle file's mounting pose. ``gravity`` (m/s^2 along -z of the
    world): default the arm's (9.81 without an arm).
    """
    if vehicle is None or isinstance(vehicle, str):
        vehicle = load_vehicle(vehicle or "bluerov2-heavy")
    if isinstance(arm, str):
        arm = load_arm(vehicle.mount_arm if arm == "mount" else arm)
    if arm is not None and np.any(arm.model.armature != 0.0):
        raise ConfigError(
            f"arm {arm.name!r}: armature = {arm.model.armature.tolist()}: the floating system does not model "
            "reflected rotor inertia yet; mount an arm with armature = 0"
        )
    mount = vehicle.mount if mount is None else mount
    root = pin.Model()
    root.name = vehicle.name
    joint = root.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "vehicle")
    root.appendBodyToJoint(joint, vehicle.rigid_inertia(), pin.SE3.Identity())
    root.addFrame(pin.Frame("vehicle", joint, pin.SE3.Identity(), pin.FrameType.BODY))
    if arm is None:
        model, ids = root, np.zeros(0, dtype=np.int64)
    else:
        frame = root.getFrameId("vehicle")
        model = pin.appendModel(root, arm.model, frame, mount)
        ids = np.asarray([model.getJointId(arm.model.names[i]) for i in range(1, arm.model.njoints)], dtype=np.int64)
        if not np.array_equal(ids, np.arange(2, arm.model.njoints + 1)):
            raise RuntimeError(f"unexpected joint order after appendModel: {ids.tolist()}")
    g = gravity if gravity is not None else (arm.gravity_acceleration if arm is not None else 9.81)
    model.gravity = pin.Motion(np.array([0.0, 0.0, -g]), np.zeros(3))
    return UVMS(vehicle=vehicle, arm=arm, model=model, mount=mount, arm_joint_ids=ids)


def mounted_arm(uvms: UVMS) -> Arm:
    """The arm's fixed-base model with gravity in its base frame as mounted on a level vehicle
    (what a fixed-base arm controller on the vehicle knows: the vehicle's motion is a
    disturbance to it)."""
    arm = uvms.arm
    if arm is None:
        raise ValueError(f"the vehicle {uvms.vehicle.name!r} carries no arm")
    model = arm.model.copy()
    gravity = uvms.mount.rotation.T @ uvms.model.gravity.linear
    model.gravity = pin.Motion(gravity, np.zeros(3))
    return dataclasses.replace(arm, model=model)


def floating_strips(uvms: UVMS, water: Water) -> StripGeometry:
    """The arm's strip geometry on a floating base: the fixed-base :class:`StripGeometry` with
    (i) one pseudo joint appended to its chain (parent: the universe, axis z, angle 0) that
    carries the cylinders the arm file fixes to its base, and (ii) ``floating`` set: the
    placements of the joints hung on the universe (``root_rows``) are replaced at every call by
    their world placement, the root's placement times ``body_rotation``/``body_translation``
    (their placement in the vehicle frame, :func:`floating_placements`). ``support`` gains the
    base's 6 columns (all ones: the base moves every cylinder). An arm without wetted cylinders
    (or none) gives :meth:`StripGeometry.empty`."""
    arm = uvms.arm
    if arm is None or not arm.cylinders:
        return StripGeometry.empty(uvms.nv, water)
    geometry = StripGeometry(arm, water)
    nj = geometry.parents.shape[0]
    mount = uvms.mount
    parents = np.append(geometry.parents, 0).astype(np.int64)
    rotations = np.vstack([geometry.placement_rotation, np.eye(3)[None]])
    translations = np.vstack([geometry.placement_translation, np.zeros((1, 3))])
    root_rows = np.asarray([i for i in range(1, nj + 1) if parents[i] == 0], dtype=np.int64)
    body_rotation, body_translation = rotations.copy(), translations.copy()
    for i in root_rows:
        placement = mount * pin.SE3(rotations[i], translations[i])
        body_rotation[i] = placement.rotation
        body_translation[i] = placement.translation
    n_cyl = geometry.joint_ids.shape[0]
    return geometry.replace(
        parents=parents, axes=np.vstack([geometry.axes, [0.0, 0.0, 1.0]]),
        idx_v=np.append(geometry.idx_v, arm.n_joints).astype(np.int64),
        placement_rotation=rotations, placement_translation=translations,
        floating=True, root_rows=root_rows, body_rotation=body_rotation, body_translation=body_translation,
        joint_ids=np.where(geometry.joint_ids == 0, nj, geometry.joint_ids).astype(np.int64),
        support=np.hstack([np.ones((n_cyl, 6)), geometry.support]).reshape(n_cyl, 6 + arm.n_joints),
        current_joint=np.zeros((3, 0)), current_world=CurrentField(water.current, 0).world,
    )  # fmt: skip


@numba.njit(cache=True)
def floating_placements(strips, q):  # pragma: no cover - compiled
    """Write the world placement of every chain row hung on the universe into the strips' chain:
    root placement (q[:3], quaternion q[3:7]) times its placement in the body frame."""
    rot = quaternion_matrix(q[3], q[4], q[5], q[6])
    body_rotation, body_translation = strips.body_rotation, strips.body_translation
    placement_rotation, placement_translation = strips.placement_rotation, strips.placement_translation
    for k in range(strips.root_rows.shape[0]):
        i = strips.root_rows[k]
        for a in range(3):
            placement_translation[i, a] = q[a] + (
                rot[a, 0] * body_translation[i, 0] + rot[a, 1] * body_translation[i, 1]
                + rot[a, 2] * body_translation[i, 2]
            )  # fmt: skip
            for b in range(3):
                placement_rotation[i, a, b] = (
                    rot[a, 0] * body_rotation[i, 0, b] + rot[a, 1] * body_rotation[i, 1, b]
                    + rot[a, 2] * body_rotation[i, 2, b]
                )  # fmt: skip
    return rot


@numba.njit(cache=True)
def floating_water_terms(strips, q, v, water_velocity, jac, djac):  # pragma: no cover - compiled
    """The arm's strip integrals on the floating system: ``(M_A, h_A, f, f_tau)`` as
    :func:`~hydroarm.model.water.strips.water_terms` ((nv, nv), (nv,) x 3).

    ``q`` (7 + n), ``v`` (6 + n), ``jac``/``djac`` Pinocchio's world Jacobian of the whole
    system and its time derivative (6, nv). The chain's forward kinematics runs on the arm
    angles plus the pseudo joint's zero angle.
    """
    n_arm = q.shape[0] - 7
    angles = np.zeros(n_arm + 1)
    for i in range(n_arm):
        angles[i] = q[7 + i]
    floating_placements(strips, q)
    return water_terms(strips, angles, v, water_velocity, jac, djac)


@structref.register
class VehicleWaterType(types.StructRef):
    """numba type of :class:`VehicleWater`."""


class VehicleWater(structref.StructRefProxy):
    """The vehicle's constants as the floating kernels read them: ``allocation`` (6, n_thr),
    ``added_mass`` (6, 6), ``linear_damping``/``quadratic_damping`` (6,), ``buoyancy`` (N),
    ``cb`` (3,) m, the water's switches on the vehicle (``added_mass_on``, ``drag_on``,
    ``buoyancy_on``), the current (``current_world``, :class:`~hydroarm.model.water.current.CurrentField`'s)
    and the thrusters' ``lag`` (s)."""


structref.define_boxing(VehicleWaterType, VehicleWater)
VEHICLE_WATER_TYPE = VehicleWaterType([
    ("allocation", types.float64[:, ::1]), ("added_mass", types.float64[:, ::1]),
    ("linear_damping", types.float64[::1]), ("quadratic_damping", types.float64[::1]),
    ("buoyancy", types.float64), ("cb", types.float64[::1]),
    ("added_mass_on", types.boolean), ("drag_on", types.boolean), ("buoyancy_on", types.boolean),
    ("current_world", types.float64[::1]), ("lag", types.float64),
])  # fmt: skip


@numba.njit(cache=True)
def _new_vehicle_water(arrays, scalars, switches, current_world):  # pragma: no cover - compiled
    s = structref.new(VEHICLE_WATER_TYPE)
    s.allocation, s.added_mass, s.linear_damping, s.quadratic_damping, s.cb = arrays
    s.buoyancy, s.lag = scalars
    s.added_mass_on, s.drag_on, s.buoyancy_on = switches
    s.current_world = current_world
    return s


def vehicle_water(vehicle: Vehicle, water: Water) -> VehicleWater:
    """The :class:`VehicleWater` of ``vehicle`` in ``water`` (the current taken as is)."""
    arrays = tuple(
        np.ascontiguousarray(a, dtype=float)
        for a in (vehicle.allocation, vehicle.added_mass, vehicle.linear_damping, vehicle.quadratic_damping,
                  vehicle.cb)
    )  # fmt: skip
    buoyancy = water.rho * water.gravity * vehicle.displaced_volume
    return _new_vehicle_water(
        arrays, (float(buoyancy), float(vehicle.thrust_time_constant)),
        (bool(water.added_mass), bool(water.drag), bool(water.buoyancy)), CurrentField(water.current, 0).world,
    )  # fmt: skip


@numba.njit(cache=True)
def uvms_system_kernel(
    q, v, tau, thrust, water_velocity, mass_upper, nonlinear, jac, djac, vehicle, strips
):  # pragma: no cover
    """The floating system's equations of motion ``(mass (nv, nv), rhs (nv,))``: ``mass v' = rhs``
    with the water's added mass in ``mass`` and every other force in ``rhs`` (arguments as
    :func:`uvms_acceleration_kernel`)."""
    nv = v.shape[0]
    mass = np.empty((nv, nv))
    for a in range(nv):
        for b in range(a, nv):
            mass[a, b] = mass_upper[a, b]
            mass[b, a] = mass_upper[a, b]
    rhs = tau - nonlinear
    if strips.joint_ids.shape[0] > 0:
        added, bias, force, tau_force = floating_water_terms(strips, q, v, water_velocity, jac, djac)
        mass += added
        rhs += force - bias
        if strips.drag_model == DRAG_REYNOLDS:
            rhs += tau_force
    rot = quaternion_matrix(q[3], q[4], q[5], q[6])
    body = vehicle_generalised_force(
        v[:6], rot, water_velocity, vehicle.added_mass, vehicle.linear_damping, vehicle.quadratic_damping,
        vehicle.buoyancy, vehicle.cb, vehicle.added_mass_on, vehicle.drag_on, vehicle.buoyancy_on,
    )  # fmt: skip
    wrench = vehicle.allocation @ thrust
    for i in range(6):
        rhs[i] += body[i] + wrench[i]
        if vehicle.added_mass_on:
            for j in range(6):
                mass[i, j] += vehicle.added_mass[i, j]
    return mass, rhs


@numba.njit(cache=True)
def uvms_acceleration_kernel(
    q, v, tau, thrust, water_velocity, mass_upper, nonlinear, jac, djac, vehicle, strips
):  # pragma: no cover
    """v' (nv,) of the floating system (see the module docstring).

    ``tau`` (nv,): generalised force besides the water and thrusters (zero on the base, the
    arm's joint torques); ``thrust`` (n_thr,) thruster forces (N) after saturation;
    ``mass_upper``, ``nonlinear``: Pinocchio's CRBA (upper triangle) and NLE at (q, v);
    ``vehicle``: :class:`VehicleWater`; ``strips``: the arm's floating :class:`Strips`.
    """
    mass, rhs = uvms_system_kernel(q, v, tau, thrust, water_velocity, mass_upper, nonlinear, jac, djac, vehicle, strips)
    return np.linalg.solve(mass, rhs)


class UVMSDynamics:
    """The floating system's dynamics at one instant, with its own Pinocchio workspace.

    ``water``: the water (rho, coefficients, switches, current; the ``paper`` current is a
    fixed-base joint disturbance and is rejected here); the vehicle's damping and added mass
    follow ``water.drag`` / ``water.added_mass``, its buoyancy ``water.buoyancy``.
    ``geometry``/``strips``: the arm's floating strips (:func:`floating_strips`), ``vehicle``
    the :class:`VehicleWater`.
    """

    def __init__(self, uvms: UVMS, water: Water | None = None):
        water = water if water is not None else Water()
        if water.current.model == "paper":
            water = water.model_copy(update={"current": water.current.model_copy(update={"model": "none"})})
        self.uvms = uvms
        self.water = water
        self.data = uvms.create_data()
        self.current = CurrentField(water.current, 0)
        self.geometry = floating_strips(uvms, water)
        self.strips: Strips = self.geometry.compiled
        self.vehicle = vehicle_water(uvms.vehicle, water)

    def pinocchio_terms(self, q: np.ndarray, v: np.ndarray):
        """``(M upper, nle, J, dJ)`` from Pinocchio at (q, v) (three calls)."""
        model, data = self.uvms.model, self.data
        pin.crba(model, data, q)
        nonlinear = pin.nonLinearEffects(model, data, q, v)
        pin.computeJointJacobiansTimeVariation(model, data, q, v)
        return data.M, nonlinear, data.J, data.dJ

    def acceleration(self, t: float, q: np.ndarray, v: np.ndarray, tau: np.ndarray, thrust: np.ndarray) -> np.ndarray:
        """v' (nv,) at time t under generalised force ``tau`` (nv,) and thruster forces ``thrust``."""
        mass, nonlinear, jac, djac = self.pinocchio_terms(q, v)
        return uvms_acceleration_kernel(
            q, v, np.asarray(tau, dtype=float), np.asarray(thrust, dtype=float), self.current.at(t)[1],
            mass, nonlinear, jac, djac, self.vehicle, self.strips,
        )  # fmt: skip

    def system(self, t: float, q: np.ndarray, v: np.ndarray, tau: np.ndarray, thrust: np.ndarray):
        """``(mass (nv, nv), rhs (nv,))`` of ``mass v' = rhs`` at time t (the water's added mass in
        ``mass``; gravity, buoyancy, drag, Coriolis, ``tau`` and the thrust in ``rhs``)."""
        mass, nonlinear, jac, djac = self.pinocchio_terms(q, v)
        return uvms_system_kernel(
            q, v, np.asarray(tau, dtype=float), np.asarray(thrust, dtype=float), self.current.at(t)[1],
            mass, nonlinear, jac, djac, self.vehicle, self.strips,
        )  # fmt: skip

    def arm_water_terms(self, q: np.ndarray, v: np.ndarray, t: float = 0.0, *, drag=None, added_mass=None,
                        buoyancy=None, axial=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
        """The arm's strip integrals ``(M_A (nv, nv), h_A (nv,), f (nv,))`` on the floating system;
        each effect defaults to the water's switch (the axial drag follows ``drag`` unless given)."""
        w = self.water
        drag = w.drag if drag is None else drag
        axial = (w.axial_drag and drag) if axial is None else axial
        strips = self.geometry.switched(
            drag, w.added_mass if added_mass is None else added_mass, w.buoyancy if buoyancy is None else buoyancy,
            axial,
        )  # fmt: skip
        _, _, jac, djac = self.pinocchio_terms(q, v)
        mass, bias, force, tau_force = floating_water_terms(strips, q, v, self.current.at(t)[1], jac, djac)
        if drag and w.drag_model == "reynolds":
            force = force + tau_force
        return mass, bias, force
