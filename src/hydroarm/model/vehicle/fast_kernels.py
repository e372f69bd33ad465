"""Compiled kernels of :mod:`hydroarm.model.vehicle.fast`: one evaluation of the floating system's
v' (RNEA with the water's body wrenches, CRBA with the added inertias, Cholesky), in the bodies'
own frames. Spatial vectors are (linear, angular), Pinocchio's order.

The arm's water is the strip water of every plant (:func:`hydroarm.model.water.effects.cylinder_water`
on the body-frame :class:`~hydroarm.model.water.strips.Strips` of
:class:`~hydroarm.model.vehicle.fast.FastUVMSDynamics`),
evaluated in the frame of the body that carries each cylinder (:func:`body_frame`): the body
wrench about the body origin. Its added-mass inertia is constant there and sits in the CRBA's
``total`` inertias; the kernel adds only the velocity term."""

from __future__ import annotations

import numba
import numpy as np
from numba.core import types
from numba.experimental import structref

from hydroarm.model.dynamics.fixed_order import cholesky_solve_into
from hydroarm.model.dynamics.tree_kernels import (
    body_force,
    crba_column,
    force_to_parent,
    joint_motion,
    place_joint,
)
from hydroarm.model.vehicle.description import quaternion_matrix, vehicle_generalised_force
from hydroarm.model.water.effects import (
    COLUMNS,
    CYL,
    DA,
    DL,
    FLOW,
    OM,
    P0,
    UP,
    VEL0,
    VELR,
    E,
    cylinder_water,
    new_frame,
)


@structref.register
class RigidTreeType(types.StructRef):
    """numba type of :class:`RigidTree`."""


class RigidTree(structref.StructRefProxy):
    """The free-flyer + revolute tree of the fast path: ``parents`` (nj,), ``place_rotation``
    (nj, 3, 3) / ``place_translation`` (nj, 3) (Pinocchio's jointPlacements), ``axes`` (nj, 3),
    the bodies' spatial inertias ``rigid`` (nj, 6, 6) and with the water's added inertias
    ``total``, ``gravity`` (m/s^2 along -z) and ``arm_current`` (whether the arm's drag sees the
    current)."""


structref.define_boxing(RigidTreeType, RigidTree)
RIGID_TREE_TYPE = RigidTreeType([
    ("parents", types.int64[::1]), ("place_rotation", types.float64[:, :, ::1]),
    ("place_translation", types.float64[:, ::1]), ("axes", types.float64[:, ::1]),
    ("rigid", types.float64[:, :, ::1]), ("total", types.float64[:, :, ::1]), ("gravity", types.float64),
    ("arm_current", types.boolean),
])  # fmt: skip


@numba.njit(cache=True)
def new_rigid_tree(arrays, gravity, arm_current):  # pragma: no cover - compiled
    """A :class:`RigidTree` of (parents, place_rotation, place_translation, axes, rigid, total)."""
    s = structref.new(RIGID_TREE_TYPE)
    s.parents, s.place_rotation, s.place_translation, s.axes, s.rigid, s.total = arrays
    s.gravity, s.arm_current = gravity, arm_current
    return s


_F1, _F2, _F3, _I1 = types.float64[::1], types.float64[:, ::1], types.float64[:, :, ::1], types.int64[::1]
WORK_TYPE = types.Tuple([
    types.Tuple([_F3, _F2, _F3, _F2, _F2, _F2, _F3, _F2, _F1, _F1, _F1, _F2, _F2, _F2, _F1, _F2]),
    types.Tuple([_I1, _F3, _F2, _F2, _F3, _F3]), types.Tuple([_F2, _F2, _F1, _F1, _F1]),
    types.Tuple([_I1, _F2, _F2, _F2]),
])  # fmt: skip
"""numba type of what :func:`workspace` returns."""


@numba.njit(cache=True)
def workspace(nv, tree, vehicle, strips):  # pragma: no cover - compiled
    """What :func:`evaluate` works with (numba type :data:`WORK_TYPE`): scratch arrays, the strip
    water's body frame (:func:`~hydroarm.model.water.effects.new_frame`), a (6,) and a joint
    rotation (3, 3), then the arrays of ``tree``, ``vehicle`` and ``strips`` it reads (taken out
    of the structures here, once, rather than at every evaluation). Every evaluation writes the scratch before it reads
    it, so one workspace serves any number of evaluations (the fast plant builds it once)."""
    nj = tree.parents.shape[0]
    frame = new_frame(6, True, strips.nodes, strips.weights, strips.curve_log_re, strips.curve_cd)
    scratch = (
        np.zeros((nj, 3, 3)), np.zeros((nj, 3)), np.zeros((nj, 3, 3)), np.zeros((nj, 6)), np.zeros((nj, 6)),
        np.zeros((nj, 6)), np.zeros((nj, 6, 6)), np.zeros((nv, nv)), np.zeros(nv), np.zeros(6), np.zeros(6),
        np.zeros((6, 6)), np.zeros((6, 6)), frame, np.zeros(6), np.zeros((3, 3)),
    )  # fmt: skip
    tree_arrays = (tree.parents, tree.place_rotation, tree.place_translation, tree.axes, tree.rigid, tree.total)
    vehicle_arrays = (vehicle.allocation, vehicle.added_mass, vehicle.linear_damping, vehicle.quadratic_damping,
                      vehicle.cb)  # fmt: skip
    strip_arrays = (strips.joint_ids, strips.start, strips.axis, strips.table)
    return scratch, tree_arrays, vehicle_arrays, strip_arrays


@numba.njit(cache=True)
def _motion_matrix(rot, pos, x):  # pragma: no cover - compiled
    """x = the 6 x 6 X (parent motion -> child motion)."""
    for i in range(3):
        for j in range(3):
            x[3 + i, j] = 0.0
    for i in range(3):
        for j in range(3):
            x[i, j] = rot[j, i]
            x[3 + i, 3 + j] = rot[j, i]
        # -R^T [p]x
        x[i, 3] = -(rot[1, i] * pos[2] - rot[2, i] * pos[1])
        x[i, 4] = -(rot[2, i] * pos[0] - rot[0, i] * pos[2])
        x[i, 5] = -(rot[0, i] * pos[1] - rot[1, i] * pos[0])


@numba.njit(cache=True, inline="always")
def body_frame(start, axis, table, k, vel, acc, rot_world, water_velocity, arm_current, frame):  # pragma: no cover
    """Fill ``frame`` with cylinder k's kinematics in the frame of its body and its coefficients
    (``start``, ``axis``, ``table``: the body-frame strips' arrays): ``vel`` (6,) the body twist,
    ``acc`` (6,) its velocity-product acceleration, ``rot_world`` (3, 3) its orientation, the
    water moving at ``water_velocity`` (3,, world; seen only if ``arm_current``)."""
    for c in range(COLUMNS):
        frame[CYL, c] = table[k, c]
    for i in range(3):
        frame[P0, i] = start[k, i]
        frame[E, i] = axis[k, i]
        frame[OM, i] = vel[3 + i]
        frame[DL, i] = acc[i]
        frame[DA, i] = acc[3 + i]
        frame[UP, i] = rot_world[2, i]
    p0, p1, p2 = frame[P0, 0], frame[P0, 1], frame[P0, 2]
    e0, e1, e2 = frame[E, 0], frame[E, 1], frame[E, 2]
    w0, w1, w2 = vel[3], vel[4], vel[5]
    frame[VEL0, 0] = vel[0] + (w1 * p2 - w2 * p1)
    frame[VEL0, 1] = vel[1] + (w2 * p0 - w0 * p2)
    frame[VEL0, 2] = vel[2] + (w0 * p1 - w1 * p0)
    frame[VELR, 0] = w1 * e2 - w2 * e1
    frame[VELR, 1] = w2 * e0 - w0 * e2
    frame[VELR, 2] = w0 * e1 - w1 * e0
    for i in range(3):
        cur = 0.0
        if arm_current:
            cur = rot_world[0, i] * water_velocity[0] + rot_world[1, i] * water_velocity[1]
            cur += rot_world[2, i] * water_velocity[2]
        frame[FLOW, i] = cur


@numba.njit(cache=True, inline="always")
def evaluate(q, v, tau, thrust, water_velocity, tree, vehicle, strips, work, out):  # pragma: no cover - compiled
    """v' (nv,) into ``out``: RNEA bias with the water's body wrenches, CRBA with the added
    inertias, Cholesky solve. ``tau`` (nv,): generalised force (base: body wrench); ``tree`` the
    :class:`RigidTree`, ``vehicle`` the :class:`~hydroarm.model.vehicle.system.VehicleWater`, ``strips`` the
    arm's body-frame strips (their scalars and switches; their arrays, as the tree's and the
    vehicle's, come in ``work``: :func:`workspace`)."""
    scratch, tree_arrays, vehicle_arrays, strip_arrays = work
    rot, pos, rot_world, vel, acc, force, composite, mass, rhs, tmp, tmp2, tmp6, xm, frame, unused, rj = scratch
    parents, rigid = tree_arrays[0], tree_arrays[4]
    allocation, added_mass, linear_damping, quadratic_damping, cb = vehicle_arrays
    bodies, start, axis, table = strip_arrays
    _forward_pass(q, v, parents, tree_arrays[1], tree_arrays[2], tree_arrays[3], rot, pos, rot_world, vel, acc, rj)
    _rigid_forces(parents.shape[0], rigid, tree.gravity, rot_world, vel, acc, tmp, tmp2, force)
    # the arm's water on its bodies
    no_inertia = tmp6[:0, :0]  # the added inertia is in ``total``
    arm_current = tree.arm_current
    wet = strips.drag or strips.axial or strips.added_mass or strips.buoyancy
    for k in range(bodies.shape[0] if wet else 0):
        i = bodies[k]
        for a in range(6):
            tmp[a] = 0.0
        body_frame(start, axis, table, k, vel[i], acc[i], rot_world[i], water_velocity, arm_current, frame)
        cylinder_water(strips, frame, no_inertia, unused, tmp, tmp)
        for a in range(6):
            force[i, a] -= tmp[a]
    # the vehicle's water and thrust on the base
    body = vehicle_generalised_force(
        v[:6], rot_world[1], water_velocity, added_mass, linear_damping, quadratic_damping,
        vehicle.buoyancy, cb, vehicle.added_mass_on, vehicle.drag_on, vehicle.buoyancy_on,
    )  # fmt: skip
    for a in range(6):
        s = body[a]
        for b in range(thrust.shape[0]):
            s += allocation[a, b] * thrust[b]
        force[1, a] -= s
    _backward_pass(
        tau, parents, tree_arrays[3], tree_arrays[5], rot, pos, force, composite, mass, rhs, tmp, tmp2, tmp6, xm
    )
    cholesky_solve_into(mass, rhs, out)


@numba.njit(cache=True, inline="always")
def _forward_pass(
    q, v, parents, place_rotation, place_translation, axes, rot, pos, rot_world, vel, acc, rj
):  # pragma: no cover
    """The bodies' placements (``rot``, ``pos`` in the parent; ``rot_world``), twists ``vel`` and
    velocity-product accelerations ``acc`` (body frames), into those arrays of the
    :func:`workspace`. Root: world placement from q; body twist = v[:6]; no velocity-product
    acceleration. The arrays come one by one, not as the workspace's tuples: unpacking a tuple
    again here cost about 1 us of the 43 us control step (measured, bench_side_by_side.py)."""
    nj = parents.shape[0]
    rot_world[1] = quaternion_matrix(q[3], q[4], q[5], q[6])
    for i in range(6):
        vel[1, i] = v[i]
        acc[1, i] = 0.0
    for i in range(2, nj):
        par = parents[i]
        place_joint(i, par, q[5 + i], place_rotation, place_translation, axes, rot, pos, rot_world, rj)
        joint_motion(i, par, v[4 + i], axes, rot, pos, vel, acc)


@numba.njit(cache=True, inline="always")
def _rigid_forces(nj, rigid, gravity, rot_world, vel, acc, tmp, tmp2, force):  # pragma: no cover - compiled
    """The bodies' forces before the water: I (a + a_gravity) + v x* I v, into ``force``."""
    for i in range(1, nj):
        for a in range(6):
            tmp[a] = acc[i, a]
        for a in range(3):
            tmp[a] += rot_world[i, 2, a] * gravity
        body_force(rigid[i], tmp, vel[i], tmp2, force[i])


@numba.njit(cache=True, inline="always")
def _backward_pass(
    tau, parents, axes, total, rot, pos, force, composite, mass, rhs, tmp, tmp2, tmp6, xm
):  # pragma: no cover
    """RNEA's backward pass (``rhs`` = tau - bias) and the CRBA (``mass``, from the composite
    inertias started at ``total``): the linear system of v', into those arrays of the
    :func:`workspace` (one by one, as :func:`_forward_pass`'s)."""
    nj = parents.shape[0]
    nv = rhs.shape[0]
    for a in range(nv):
        for b in range(nv):
            mass[a, b] = 0.0
    for i in range(1, nj):
        for a in range(6):
            for b in range(6):
                composite[i, a, b] = total[i, a, b]
    for i in range(nj - 1, 1, -1):
        par = parents[i]
        k = 4 + i
        rhs[k] = tau[k] - (axes[i, 0] * force[i, 3] + axes[i, 1] * force[i, 4] + axes[i, 2] * force[i, 5])
        force_to_parent(rot[i], pos[i], force[i], force[par])
        # F = Ic S, carried to the root
        j = crba_column(i, parents, axes, rot, pos, composite[i], 1, 4, mass, tmp, tmp2)
        for a in range(6):
            tmp2[a] = 0.0
        force_to_parent(rot[j], pos[j], tmp, tmp2)
        for a in range(6):
            mass[a, k] = tmp2[a]
            mass[k, a] = tmp2[a]
        _motion_matrix(rot[i], pos[i], xm)
        _add_transformed_inertia(xm, composite[i], composite[par], tmp6)
    for a in range(6):
        rhs[a] = tau[a] - force[1, a]
        for b in range(6):
            mass[a, b] = composite[1, a, b]


@numba.njit(cache=True)
def _add_transformed_inertia(x, inertia, out, scratch):  # pragma: no cover - compiled
    """out += x^T inertia x (6 x 6)."""
    for a in range(6):
        for b in range(6):
            s = 0.0
            for c in range(6):
                s += inertia[a, c] * x[c, b]
            scratch[a, b] = s
    for a in range(6):
        for b in range(6):
            s = 0.0
            for c in range(6):
                s += x[c, a] * scratch[c, b]
            out[a, b] += s
