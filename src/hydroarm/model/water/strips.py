"""The strip water as one compiled structure: the geometry of every wetted cylinder, the water's
coefficients, switches and current (:class:`Strips`), and the loop over the cylinders that every
plant calls (:func:`water_terms`). The physics is in :mod:`hydroarm.model.water.morison`'s docstring; the
effects themselves (drag, axial drag, added mass, buoyancy) are one compiled function each in
:mod:`hydroarm.model.water.effects`.

:class:`StripGeometry` holds the arrays on the Python side and :meth:`StripGeometry.compile` packs
them into a :class:`Strips`, a numba StructRef: one argument of the kernels instead of the 15
arrays and three switches they used to take one by one (from Python it costs about 0.7 us per
call against 4.8 us for a named tuple of 35 arrays, and it caches with a hand-written
constructor). The per-cylinder coefficients travel as one table, and each cylinder's kinematics
in one 2-D frame array (:mod:`hydroarm.model.water.effects`), so the compiled loops read no
reference-counted field per Gauss node. Built once per
(arm, water) pair by its owner (the plant, the water model, the regressor, the vehicle's paths);
the fixed-base arm, the floating arm (:mod:`hydroarm.model.vehicle.system`), the fast vehicle path
(:mod:`hydroarm.model.vehicle.fast_kernels`), the regressor (:mod:`hydroarm.model.water.regressor`)
and the Reynolds drag (:mod:`hydroarm.model.water.reynolds`) all read it.
"""

from __future__ import annotations

import copy

import numba
import numpy as np
from numba.core import types
from numba.experimental import structref

from hydroarm.model.arm.description import Arm, revolute_axes
from hydroarm.model.dynamics.fixed_order import cholesky_solve_into, matvec
from hydroarm.model.water.current import CurrentField, current_at
from hydroarm.model.water.effects import (
    COLUMNS,
    CYL,
    DA,
    DL,
    DRAG_CONSTANT,
    DRAG_REYNOLDS,
    FLOW,
    J0,
    JR,
    JW,
    KIRCHHOFF,
    MORISON,
    OM,
    P0,
    VEL0,
    VELR,
    E,
    cylinder_water,
    new_frame,
)
from hydroarm.model.water.reynolds import CD_SMOOTH, LOG_RE, aspect_factor

__all__ = ["Strips", "StripGeometry", "forward_kinematics", "rotation_into", "underwater_dynamics", "water_terms"]

_F1, _F2, _F3, _I1 = types.float64[::1], types.float64[:, ::1], types.float64[:, :, ::1], types.int64[::1]

CHAIN_FIELDS = ("parents", "placement_rotation", "placement_translation", "axes", "idx_v")
FLOATING_FIELDS = ("floating", "root_rows", "body_rotation", "body_translation")
CYLINDER_FIELDS = ("joint_ids", "start", "axis", "support")
COEFFICIENT_FIELDS = ("table", "viscosity", "curve_log_re", "curve_cd")
TABLE_FIELDS = ("length", "drag_per_length", "mass_per_length", "buoyancy_force", "axial_drag", "reynolds_drag",
                "diameter")  # fmt: skip
"""The columns of ``Strips.table``, in order (:data:`hydroarm.model.water.effects.LENGTH` ...)."""
QUADRATURE_FIELDS = ("nodes", "weights")
SWITCH_FIELDS = ("drag", "added_mass", "buoyancy", "axial", "drag_model", "added_mass_model")
CURRENT_FIELDS = ("current_joint", "current_world")
GROUPS = (CHAIN_FIELDS, FLOATING_FIELDS, CYLINDER_FIELDS, COEFFICIENT_FIELDS, QUADRATURE_FIELDS, SWITCH_FIELDS,
          CURRENT_FIELDS)  # fmt: skip


@structref.register
class StripsType(types.StructRef):
    """numba type of :class:`Strips`."""


class Strips(structref.StructRefProxy):
    """The compiled strip water (module docstring): an opaque handle from Python, fields read by
    the kernels. Make it with :meth:`StripGeometry.compile`; its arrays are the geometry's (not
    copied: an owner that writes into them, as the regressor does with its coefficients, changes
    what the kernels see)."""


structref.define_boxing(StripsType, Strips)

STRIPS_TYPE = StripsType([
    # chain (revolute tree; Pinocchio's jointPlacements)
    ("parents", _I1), ("placement_rotation", _F3), ("placement_translation", _F2), ("axes", _F2), ("idx_v", _I1),
    # floating base: the chain rows hung on the universe and their placement in the vehicle frame
    ("floating", types.boolean), ("root_rows", _I1), ("body_rotation", _F3), ("body_translation", _F2),
    # cylinders (C rows) and their coefficients (C, 7): TABLE_FIELDS
    ("joint_ids", _I1), ("start", _F2), ("axis", _F2), ("support", _F2),
    ("table", _F2), ("viscosity", types.float64), ("curve_log_re", _F1), ("curve_cd", _F1),
    # quadrature on [0, 1]
    ("nodes", _F1), ("weights", _F1),
    # switches
    ("drag", types.boolean), ("added_mass", types.boolean), ("buoyancy", types.boolean), ("axial", types.boolean),
    ("drag_model", types.int64), ("added_mass_model", types.int64),
    # the current (CurrentField's arrays)
    ("current_joint", _F2), ("current_world", _F1),
])  # fmt: skip


@numba.njit(cache=True)
def _new_strips(chain, floating, cylinders, coefficients, quadrature, switches, current):  # pragma: no cover
    s = structref.new(STRIPS_TYPE)
    s.parents, s.placement_rotation, s.placement_translation, s.axes, s.idx_v = chain
    s.floating, s.root_rows, s.body_rotation, s.body_translation = floating
    s.joint_ids, s.start, s.axis, s.support = cylinders
    s.table, s.viscosity, s.curve_log_re, s.curve_cd = coefficients
    s.nodes, s.weights = quadrature
    s.drag, s.added_mass, s.buoyancy, s.axial, s.drag_model, s.added_mass_model = switches
    s.current_joint, s.current_world = current
    return s


@numba.njit(cache=True)
def replicate_strips(s):  # pragma: no cover - compiled
    """A private copy of the compiled strips ``s``: the same fields, every array copied. Threads
    that read one shared :class:`Strips` contend on its arrays' reference counts (every read of
    an array field is an atomic increment of a count they all write); each reading its own copy,
    they do not. Equal values, so the kernels' numbers are the same to the bit."""
    return _new_strips(
        (s.parents.copy(), s.placement_rotation.copy(), s.placement_translation.copy(), s.axes.copy(), s.idx_v.copy()),
        (s.floating, s.root_rows.copy(), s.body_rotation.copy(), s.body_translation.copy()),
        (s.joint_ids.copy(), s.start.copy(), s.axis.copy(), s.support.copy()),
        (s.table.copy(), s.viscosity, s.curve_log_re.copy(), s.curve_cd.copy()),
        (s.nodes.copy(), s.weights.copy()),
        (s.drag, s.added_mass, s.buoyancy, s.axial, s.drag_model, s.added_mass_model),
        (s.current_joint.copy(), s.current_world.copy()),
    )


class StripGeometry:
    """The arrays of the strip integrals of one (arm, water) pair, one row per cylinder, and the
    water's switches; :meth:`compile` packs them into a :class:`Strips`.

    ``joint_ids`` (C,): the Pinocchio joint whose body carries each cylinder; ``start`` (C, 3)
    and unit ``axis`` (C, 3) in that body frame; ``length`` (C,) m; ``drag_per_length`` =
    1/2 rho C_d D (kg/m^2); ``mass_per_length`` = rho C_m A (kg/m); ``buoyancy_force`` = rho g V
    (N); ``axial_drag`` = 1/2 rho C_a A (kg/m, the end area A); ``reynolds_drag`` = 1/2 rho D
    kappa(L/D) (kg/m^2, :mod:`hydroarm.model.water.reynolds`) with ``diameter`` (C,) m, the water's
    ``viscosity`` (m^2/s) and the C_d(Re) curve; ``support`` (C, n) the mask of joints that move
    each cylinder; ``nodes``/``weights`` the Gauss-Legendre rule on [0, 1] (weights sum to 1).
    Chain data for the kernel's forward kinematics: ``parents``, ``placement_rotation`` /
    ``placement_translation`` (Pinocchio's jointPlacements), ``axes`` and ``idx_v`` per joint;
    ``floating`` False and empty ``root_rows`` on a fixed base
    (:func:`~hydroarm.model.vehicle.system.floating_strips` sets them). The per-cylinder coefficients go
    into ``Strips.table`` (:data:`TABLE_FIELDS`). Switches: ``drag``, ``added_mass``,
    ``buoyancy``, ``axial`` (bool), ``drag_model`` (0 constant C_d, 1 Reynolds),
    ``added_mass_model`` (0 Morison, 1 Kirchhoff).
    ``current_joint``, ``current_world``: :class:`~hydroarm.model.water.current.CurrentField`'s arrays.
    """

    def __init__(self, arm: Arm, water):
        nodes, weights = np.polynomial.legendre.leggauss(water.quadrature_points)
        self.nodes = 0.5 * (nodes + 1.0)
        self.weights = 0.5 * weights
        cylinders = arm.cylinders
        n = arm.n_joints
        self.joint_ids = np.asarray([c.joint_id for c in cylinders], dtype=np.int64)
        self.start = np.asarray([c.start for c in cylinders], dtype=float).reshape(-1, 3)
        self.axis = np.asarray([c.axis for c in cylinders], dtype=float).reshape(-1, 3)
        self.length = np.asarray([c.length for c in cylinders], dtype=float)
        coefficients = [c.coefficients(water) for c in cylinders]  # (C_d, C_m): the one precedence rule
        self.drag_per_length = np.asarray(
            [0.5 * water.rho * cd * c.diameter for c, (cd, _) in zip(cylinders, coefficients, strict=True)],
            dtype=float,
        )
        self.mass_per_length = np.asarray(
            [water.rho * cm * c.area for c, (_, cm) in zip(cylinders, coefficients, strict=True)], dtype=float
        )
        self.buoyancy_force = np.asarray(
            [water.rho * water.gravity * c.displaced_volume for c in cylinders], dtype=float
        )
        self.axial_drag = np.asarray([0.5 * water.rho * c.cd_axial * c.area for c in cylinders], dtype=float)
        self.diameter = np.asarray([c.diameter for c in cylinders], dtype=float)
        self.reynolds_drag = 0.5 * water.rho * self.diameter * aspect_factor(self.length / self.diameter)
        self.viscosity = float(water.kinematic_viscosity)
        self.curve_log_re, self.curve_cd = LOG_RE.copy(), CD_SMOOTH.copy()
        self.support = arm.cylinder_support.copy().reshape(-1, n)
        model = arm.model
        self.parents = np.asarray(model.parents, dtype=np.int64)
        self.placement_rotation = np.stack([model.jointPlacements[i].rotation for i in range(model.njoints)])
        self.placement_translation = np.stack([model.jointPlacements[i].translation for i in range(model.njoints)])
        self.axes = revolute_axes(arm)
        self.idx_v = np.asarray([-1] + [model.joints[i].idx_v for i in range(1, model.njoints)], dtype=np.int64)
        self.floating = False
        self.root_rows = np.zeros(0, dtype=np.int64)
        self.body_rotation = np.zeros((0, 3, 3))
        self.body_translation = np.zeros((0, 3))
        self.drag, self.added_mass, self.buoyancy = bool(water.drag), bool(water.added_mass), bool(water.buoyancy)
        self.axial = bool(water.axial_drag)
        self.drag_model = DRAG_REYNOLDS if water.drag_model == "reynolds" else DRAG_CONSTANT
        self.added_mass_model = KIRCHHOFF if water.added_mass_model == "kirchhoff" else MORISON
        current = CurrentField(water.current, n)
        self.current_joint, self.current_world = current.joint, current.world

    @classmethod
    def empty(cls, n: int, water) -> StripGeometry:
        """No cylinder at all (a vehicle without an arm, or an arm without wetted cylinders), for
        n generalised velocities: the kernels' loops do nothing."""
        out = cls.__new__(cls)
        nodes, weights = np.polynomial.legendre.leggauss(water.quadrature_points)
        out.nodes, out.weights = 0.5 * (nodes + 1.0), 0.5 * weights
        out.joint_ids = np.zeros(0, dtype=np.int64)
        out.start, out.axis = np.zeros((0, 3)), np.zeros((0, 3))
        for name in ("length", "drag_per_length", "mass_per_length", "buoyancy_force", "axial_drag", "diameter",
                     "reynolds_drag"):  # fmt: skip
            setattr(out, name, np.zeros(0))
        out.viscosity = float(water.kinematic_viscosity)
        out.curve_log_re, out.curve_cd = LOG_RE.copy(), CD_SMOOTH.copy()
        out.support = np.zeros((0, n))
        out.parents = np.zeros(1, dtype=np.int64)
        out.placement_rotation, out.placement_translation = np.eye(3)[None].copy(), np.zeros((1, 3))
        out.axes, out.idx_v = np.zeros((1, 3)), np.zeros(1, dtype=np.int64)
        out.floating, out.root_rows = False, np.zeros(0, dtype=np.int64)
        out.body_rotation, out.body_translation = np.zeros((0, 3, 3)), np.zeros((0, 3))
        out.drag, out.added_mass, out.buoyancy = bool(water.drag), bool(water.added_mass), bool(water.buoyancy)
        out.axial = bool(water.axial_drag)
        out.drag_model = DRAG_REYNOLDS if water.drag_model == "reynolds" else DRAG_CONSTANT
        out.added_mass_model = KIRCHHOFF if water.added_mass_model == "kirchhoff" else MORISON
        current = CurrentField(water.current, 0)
        out.current_joint, out.current_world = current.joint, current.world
        return out

    def switched(self, drag: bool, added_mass: bool, buoyancy: bool, axial: bool) -> Strips:
        """These strips compiled with the effects switched as given (built once per choice)."""
        key = (bool(drag), bool(added_mass), bool(buoyancy), bool(axial))
        cache = self.__dict__.setdefault("_switched", {})
        if key not in cache:
            own = (self.drag, self.added_mass, self.buoyancy, self.axial) == key
            fields = {"drag": key[0], "added_mass": key[1], "buoyancy": key[2], "axial": key[3]}
            cache[key] = self.compile() if own else self.replace(**fields).compile()
        return cache[key]

    @property
    def compiled(self) -> Strips:
        """:meth:`compile` with these switches, built once."""
        return self.switched(self.drag, self.added_mass, self.buoyancy, self.axial)

    def replace(self, **fields) -> StripGeometry:
        """A shallow copy with some fields replaced (the arrays not named are shared)."""
        out = copy.copy(self)
        out.__dict__.pop("_switched", None)
        out.__dict__.pop("table", None)
        for name, value in fields.items():
            if not hasattr(self, name):
                raise AttributeError(f"StripGeometry has no field {name!r}")
            setattr(out, name, value)
        return out

    def compile(self) -> Strips:
        """These arrays and switches as one :class:`Strips` (shares the arrays but the per-cylinder
        coefficients, which it packs into ``table`` (C, 7): the columns of :data:`TABLE_FIELDS`;
        an owner that changes coefficients between calls writes into that table)."""
        self.table = np.column_stack([np.asarray(getattr(self, name), dtype=float) for name in TABLE_FIELDS])
        self.table = np.ascontiguousarray(self.table.reshape(-1, COLUMNS))

        def pack(names):
            out = []
            for name in names:
                value = getattr(self, name)
                if isinstance(value, np.ndarray):
                    value = np.ascontiguousarray(value, dtype=np.int64 if value.dtype.kind in "iu" else float)
                out.append(value)
            return tuple(out)

        values = [pack(group) for group in GROUPS]
        values[1] = (bool(self.floating), *values[1][1:])
        values[3] = (values[3][0], float(self.viscosity), *values[3][2:])
        values[5] = (bool(self.drag), bool(self.added_mass), bool(self.buoyancy), bool(self.axial),
                     int(self.drag_model), int(self.added_mass_model))  # fmt: skip
        return _new_strips(*values)


@numba.njit(cache=True)
def rotation_into(axis, angle, out):  # pragma: no cover - compiled
    """Rodrigues: ``out`` (3, 3) = the rotation by ``angle`` about unit ``axis``."""
    c, s = np.cos(angle), np.sin(angle)
    x, y, z = axis[0], axis[1], axis[2]
    t = 1.0 - c
    out[0, 0] = c + x * x * t
    out[0, 1] = x * y * t - z * s
    out[0, 2] = x * z * t + y * s
    out[1, 0] = y * x * t + z * s
    out[1, 1] = c + y * y * t
    out[1, 2] = y * z * t - x * s
    out[2, 0] = z * x * t - y * s
    out[2, 1] = z * y * t + x * s
    out[2, 2] = c + z * z * t


@numba.njit(cache=True)
def _matmul3(a, b, out):  # pragma: no cover - compiled
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]


@numba.njit(cache=True)
def _apply(rot, pos, local, out):  # pragma: no cover - compiled
    """out = pos + rot @ local for 3-vectors."""
    for i in range(3):
        out[i] = pos[i] + rot[i, 0] * local[0] + rot[i, 1] * local[1] + rot[i, 2] * local[2]


@numba.njit(cache=True)
def forward_kinematics(strips, q):  # pragma: no cover - compiled
    """World placement of every joint frame of the strips' chain at angles q: (R (nj, 3, 3), p (nj, 3)).

    Same as Pinocchio's ``data.oMi`` (a test checks it): computed here so the water kernel
    needs no per-joint Python access to Pinocchio's data.
    """
    parents, axes, idx_v = strips.parents, strips.axes, strips.idx_v
    nj = parents.shape[0]
    rot = np.zeros((nj, 3, 3))
    pos = np.zeros((nj, 3))
    local_rot = np.empty((3, 3))
    joint_rot = np.empty((3, 3))
    for i in range(3):
        rot[0, i, i] = 1.0
    for i in range(1, nj):
        par = parents[i]
        rotation_into(axes[i], q[idx_v[i]], joint_rot)
        _matmul3(strips.placement_rotation[i], joint_rot, local_rot)
        _matmul3(rot[par], local_rot, rot[i])
        _apply(rot[par], pos[par], strips.placement_translation[i], pos[i])
    return rot, pos


@numba.njit(cache=True, inline="always")
def jacobian_frame(strips, k, rot, pos, jac, djac, v, frame):  # pragma: no cover - compiled
    """Fill ``frame`` (:mod:`hydroarm.model.water.effects`' rows) with cylinder k's kinematics in
    the world frame from the joint Jacobian, and its coefficients.

    ``jac``/``djac``: Pinocchio's world joint Jacobian (6, n) and its time derivative at (q, v),
    rows (linear, angular) at the world origin. Along the cylinder ``p(s) = p0 + s e``,
    ``J_p(s) = J0 + s Jr`` with ``J0 = S (J_lin + J_ang x p0)``, ``Jr = S (J_ang x e)`` (S the
    support mask); the point velocity ``vel0 + s velr``; ``om``, ``dl``, ``da`` the link's
    angular velocity and the velocity-product parts ``dJ v`` (linear at the origin, angular);
    ``jw`` the masked angular Jacobian (filled for the Kirchhoff added mass only).
    """
    n = v.shape[0]
    j = strips.joint_ids[k]
    start, axis, support, table = strips.start, strips.axis, strips.support, strips.table
    for c in range(COLUMNS):
        frame[CYL, c] = table[k, c]
    for i in range(3):
        frame[P0, i] = pos[j, i] + rot[j, i, 0] * start[k, 0] + rot[j, i, 1] * start[k, 1] + rot[j, i, 2] * start[k, 2]
        frame[E, i] = 0.0 + rot[j, i, 0] * axis[k, 0] + rot[j, i, 1] * axis[k, 1] + rot[j, i, 2] * axis[k, 2]
    p0, p1, p2 = frame[P0, 0], frame[P0, 1], frame[P0, 2]
    e0, e1, e2 = frame[E, 0], frame[E, 1], frame[E, 2]
    om0 = om1 = om2 = 0.0
    dl0 = dl1 = dl2 = 0.0
    da0 = da1 = da2 = 0.0
    for c in range(n):
        if support[k, c] != 0.0:
            vc = v[c]
            om0 += jac[3, c] * vc
            om1 += jac[4, c] * vc
            om2 += jac[5, c] * vc
            dl0 += djac[0, c] * vc
            dl1 += djac[1, c] * vc
            dl2 += djac[2, c] * vc
            da0 += djac[3, c] * vc
            da1 += djac[4, c] * vc
            da2 += djac[5, c] * vc
            frame[J0, c] = jac[0, c] + jac[4, c] * p2 - jac[5, c] * p1
            frame[J0 + 1, c] = jac[1, c] + jac[5, c] * p0 - jac[3, c] * p2
            frame[J0 + 2, c] = jac[2, c] + jac[3, c] * p1 - jac[4, c] * p0
            frame[JR, c] = jac[4, c] * e2 - jac[5, c] * e1
            frame[JR + 1, c] = jac[5, c] * e0 - jac[3, c] * e2
            frame[JR + 2, c] = jac[3, c] * e1 - jac[4, c] * e0
        else:
            for i in range(3):
                frame[J0 + i, c] = 0.0
                frame[JR + i, c] = 0.0
    frame[OM, 0], frame[OM, 1], frame[OM, 2] = om0, om1, om2
    frame[DL, 0], frame[DL, 1], frame[DL, 2] = dl0, dl1, dl2
    frame[DA, 0], frame[DA, 1], frame[DA, 2] = da0, da1, da2
    for i in range(3):
        vel0 = 0.0
        velr = 0.0
        for c in range(n):
            vel0 += frame[J0 + i, c] * v[c]
            velr += frame[JR + i, c] * v[c]
        frame[VEL0, i] = vel0
        frame[VELR, i] = velr
    if strips.added_mass_model == KIRCHHOFF:
        for c in range(n):
            on = support[k, c] != 0.0
            for i in range(3):
                frame[JW + i, c] = jac[3 + i, c] if on else 0.0


@numba.njit(cache=True)
def world_frame(strips, n, water_velocity):  # pragma: no cover - compiled
    """A world frame (:func:`~hydroarm.model.water.effects.new_frame`) for n generalised
    velocities, the strips' quadrature and curve, the water moving at ``water_velocity`` (3,) m/s."""
    frame = new_frame(n, False, strips.nodes, strips.weights, strips.curve_log_re, strips.curve_cd)
    for i in range(3):
        frame[FLOW, i] = water_velocity[i]
    return frame


@numba.njit(cache=True)
def water_terms(strips, q, v, water_velocity, jac, djac):  # pragma: no cover - compiled
    """Strip integrals over all cylinders: ``(M_A (n, n), h_A (n,), f (n,), f_tau (n,))``.

    The water's generalised force is ``-M_A q'' - h_A + f + f_tau``: ``f`` collects buoyancy,
    the constant-C_d drag and the axial drag, ``f_tau`` the Reynolds drag (zeros otherwise),
    which the plant adds to the joint torque before the rest (as it did when that drag was a
    kernel of its own: the same numbers). ``q`` (nj - 1,) the chain's angles, ``v`` (n,) the
    generalised velocity, ``jac``/``djac`` (6, n) as :func:`jacobian_frame`'s. Each cylinder's
    effects: :func:`~hydroarm.model.water.effects.cylinder_water`.
    """
    n = v.shape[0]
    rot, pos = forward_kinematics(strips, q)
    mass = np.zeros((n, n))
    bias = np.zeros(n)
    force = np.zeros(n)
    tau_force = np.zeros(n)
    drag_force = force if strips.drag_model == DRAG_CONSTANT else tau_force
    frame = world_frame(strips, n, water_velocity)
    for k in range(strips.joint_ids.shape[0]):
        jacobian_frame(strips, k, rot, pos, jac, djac, v, frame)
        cylinder_water(strips, frame, mass, bias, force, drag_force)
    for a in range(n):
        for b in range(a + 1, n):
            mass[b, a] = mass[a, b]
    return mass, bias, force, tau_force


@numba.njit(cache=True)
def solve_underwater(v, applied, joint_acceleration, viscous, rigid, added, bias, force):  # pragma: no cover
    """``(q'' (n,), disturbance (n,))`` of ``(M + M_A)(q'' - a_c) = tau - nle - h_A + f - b v``.

    ``rigid`` = (M upper triangle (Pinocchio's CRBA), nle = C v + G, J, dJ); ``applied`` the
    joint torque tau; ``joint_acceleration`` a_c (the paper current); ``viscous`` b.
    ``disturbance = M q'' + nle - tau``: the generalised force the dry model lacks. The solve
    (Cholesky, M + M_A symmetric positive definite) and the product are fixed-order loops, not
    LAPACK / BLAS: the same bits under any BLAS kernel, which a learner in the loop would amplify
    (the flagship's run otherwise moved by 5.6 % between OpenBLAS's Haswell and Sandybridge
    kernels); a failed factorisation leaves NaN, which the plant reports as diverged.
    """
    n = v.shape[0]
    mass_upper, nonlinear = rigid[0], rigid[1]
    mass = np.empty((n, n))
    for a in range(n):
        for b in range(a, n):
            mass[a, b] = mass_upper[a, b]
            mass[b, a] = mass_upper[a, b]
    rhs = applied - nonlinear + force - bias - viscous * v
    acc = np.empty(n)
    cholesky_solve_into(mass + added, rhs, acc)
    acc += joint_acceleration
    disturbance = matvec(mass, acc) + nonlinear - applied
    return acc, disturbance


@numba.njit(cache=True)
def underwater_dynamics(strips, q, v, tau, t, viscous, rigid):  # pragma: no cover - compiled
    """True acceleration and disturbance of the fixed-base arm: ``(q'' (n,), disturbance (n,))``.

    The current at time t (s), :func:`water_terms`, then :func:`solve_underwater` (the Reynolds
    drag joins tau first and the disturbance after). ``viscous`` (N m s/rad) the joint viscous
    friction; ``rigid`` = (M upper, nle, J, dJ) from Pinocchio at (q, v).
    """
    n = v.shape[0]
    joint_acceleration = np.empty(n)
    water_velocity = np.empty(3)
    current_at(t, strips.current_joint, strips.current_world, joint_acceleration, water_velocity)
    added, bias, force, tau_force = water_terms(strips, q, v, water_velocity, rigid[2], rigid[3])
    applied = tau + tau_force if strips.drag_model == DRAG_REYNOLDS else tau
    acc, disturbance = solve_underwater(v, applied, joint_acceleration, viscous, rigid, added, bias, force)
    if strips.drag_model == DRAG_REYNOLDS:
        disturbance = disturbance + tau_force
    return acc, disturbance
