"""Compiled strip integrals of the water on every wetted cylinder (Morison), and the true
arm dynamics they enter. The physics is in :mod:`hydroarm.model.water`'s docstring.
"""

from __future__ import annotations

import numba
import numpy as np

from hydroarm.model.arm import Arm, revolute_axes


class StripGeometry:
    """Constant arrays of the strip integrals of one (arm, water) pair, one row per cylinder.

    ``joint_ids`` (C,): the Pinocchio joint whose body carries each cylinder;
    ``start`` (C, 3) and unit ``axis`` (C, 3) in that body frame; ``length``
    (C,) m; ``drag_per_length`` = 1/2 rho C_d D (kg/m^2); ``mass_per_length``
    = rho C_m A (kg/m); ``buoyancy_force`` = rho g V (N); ``support`` (C, n) the
    mask of joints that move each cylinder; ``nodes``/``weights`` the
    Gauss-Legendre rule on [0, 1] (weights sum to 1). Chain data for the
    kernel's forward kinematics: ``parents``, ``placement_rotation`` /
    ``placement_translation`` (Pinocchio's jointPlacements), ``axes`` and
    ``idx_v`` per joint.
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
        self.drag_per_length = np.asarray(
            [0.5 * water.rho * (water.cd if c.cd is None else c.cd) * c.diameter for c in cylinders],
            dtype=float,
        )
        self.mass_per_length = np.asarray(
            [water.rho * (water.cm if c.cm is None else c.cm) * c.area for c in cylinders], dtype=float
        )
        self.buoyancy_force = np.asarray(
            [water.rho * water.gravity * c.displaced_volume for c in cylinders], dtype=float
        )
        self.support = arm.cylinder_support.copy().reshape(-1, n)
        model = arm.model
        self.parents = np.asarray(model.parents, dtype=np.int64)
        self.placement_rotation = np.stack([model.jointPlacements[i].rotation for i in range(model.njoints)])
        self.placement_translation = np.stack([model.jointPlacements[i].translation for i in range(model.njoints)])
        self.axes = revolute_axes(arm)
        self.idx_v = np.asarray([-1] + [model.joints[i].idx_v for i in range(1, model.njoints)], dtype=np.int64)

    def kernel_constants(self) -> tuple:
        """The constant arguments of the compiled kernels, in their order."""
        return (
            self.parents, self.placement_rotation, self.placement_translation, self.axes, self.idx_v,
            self.joint_ids, self.start, self.axis, self.length, self.support,
            self.drag_per_length, self.mass_per_length, self.buoyancy_force, self.nodes, self.weights,
        )  # fmt: skip


@numba.njit(cache=True)
def rotation_into(axis, angle, out):
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
def _rotation(axis, angle):
    """Rodrigues: rotation by ``angle`` about unit ``axis``, (3, 3)."""
    out = np.empty((3, 3))
    rotation_into(axis, angle, out)
    return out


@numba.njit(cache=True)
def _matmul3(a, b, out):
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]


@numba.njit(cache=True)
def _apply(rot, pos, local, out):
    """out = pos + rot @ local for 3-vectors (pos may be None-like zeros)."""
    for i in range(3):
        out[i] = pos[i] + rot[i, 0] * local[0] + rot[i, 1] * local[1] + rot[i, 2] * local[2]


@numba.njit(cache=True)
def forward_kinematics(q, parents, placement_rotation, placement_translation, axes, idx_v):
    """World placement of every joint frame: (R (nj, 3, 3), p (nj, 3)).

    Same as Pinocchio's ``data.oMi`` (a test checks it): computed here so the
    water kernel needs no per-joint Python access to Pinocchio's data.
    """
    nj = parents.shape[0]
    rot = np.zeros((nj, 3, 3))
    pos = np.zeros((nj, 3))
    local_rot = np.empty((3, 3))
    for i in range(3):
        rot[0, i, i] = 1.0
    for i in range(1, nj):
        par = parents[i]
        _matmul3(placement_rotation[i], _rotation(axes[i], q[idx_v[i]]), local_rot)
        _matmul3(rot[par], local_rot, rot[i])
        _apply(rot[par], pos[par], placement_translation[i], pos[i])
    return rot, pos


@numba.njit(cache=True)
def _drag_piece(s0, s1, a_n, b_n, j0, jr, coefficient, nodes, weights, force):
    """Add int_{s0}^{s1} (J0 + s Jr)^T f(s) ds to ``force``, f = -c |v_n| v_n, v_n = a_n + s b_n."""
    n = force.shape[0]
    width = s1 - s0
    for m in range(nodes.shape[0]):
        s = s0 + width * nodes[m]
        w = width * weights[m]
        v0 = a_n[0] + s * b_n[0]
        v1 = a_n[1] + s * b_n[1]
        v2 = a_n[2] + s * b_n[2]
        scale = -coefficient * w * np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        f0, f1, f2 = scale * v0, scale * v1, scale * v2
        for c in range(n):
            force[c] += (j0[0, c] + s * jr[0, c]) * f0 + (j0[1, c] + s * jr[1, c]) * f1 + (j0[2, c] + s * jr[2, c]) * f2


@numba.njit(cache=True)
def water_terms_kernel(
    q, v, water_velocity, jac, djac,
    parents, placement_rotation, placement_translation, axes, idx_v,
    joint_ids, start, axis, length, support, drag_per_length, mass_per_length, buoyancy_force,
    nodes, weights, use_drag, use_added_mass, use_buoyancy,
):  # fmt: skip
    """Strip integrals over all cylinders: returns ``(M_A (n, n), h_A (n,), f (n,))``.

    ``jac``/``djac``: Pinocchio's world joint Jacobian (6, n) and its time
    derivative at (q, v), rows (linear, angular) at the world origin. Along a
    cylinder ``p(s) = p0 + s e`` (s in [0, L]) every kinematic quantity is
    affine in s: ``J_p(s) = J0 + s Jr`` with ``J0 = S (J_lin + J_ang x p0)``,
    ``Jr = S (J_ang x e)``; so the point velocity, its normal part and the
    acceleration bias are affine in s too. The added-mass and buoyancy
    integrands are then polynomials of degree <= 2 (exact with >= 2 Gauss
    points); the drag integrand ``|v_n| v_n`` has a kink where ``|v_n(s)|`` is
    smallest, so the drag integral is split there and each piece integrated by
    Gauss-Legendre. Water generalised force = ``-M_A q'' - h_A + f``, f = drag + buoyancy.
    """
    n = v.shape[0]
    rot, pos = forward_kinematics(q, parents, placement_rotation, placement_translation, axes, idx_v)
    mass = np.zeros((n, n))
    bias_force = np.zeros(n)
    force = np.zeros(n)
    j0 = np.empty((3, n))
    jr = np.empty((3, n))
    nj0 = np.empty((3, n))
    njr = np.empty((3, n))
    p0 = np.empty(3)
    e = np.empty(3)
    zero = np.zeros(3)
    a_n = np.empty(3)
    b_n = np.empty(3)
    bias0 = np.empty(3)
    bias1 = np.empty(3)
    for k in range(joint_ids.shape[0]):
        j = joint_ids[k]
        L = length[k]
        _apply(rot[j], pos[j], start[k], p0)
        _apply(rot[j], zero, axis[k], e)
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
                j0[0, c] = jac[0, c] + jac[4, c] * p0[2] - jac[5, c] * p0[1]
                j0[1, c] = jac[1, c] + jac[5, c] * p0[0] - jac[3, c] * p0[2]
                j0[2, c] = jac[2, c] + jac[3, c] * p0[1] - jac[4, c] * p0[0]
                jr[0, c] = jac[4, c] * e[2] - jac[5, c] * e[1]
                jr[1, c] = jac[5, c] * e[0] - jac[3, c] * e[2]
                jr[2, c] = jac[3, c] * e[1] - jac[4, c] * e[0]
            else:
                for i in range(3):
                    j0[i, c] = 0.0
                    jr[i, c] = 0.0
        # velocity at s: vel0 + s * velr (velr = omega x e is normal to e)
        vel0 = np.zeros(3)
        velr = np.zeros(3)
        for i in range(3):
            for c in range(n):
                vel0[i] += j0[i, c] * v[c]
                velr[i] += jr[i, c] * v[c]
        if use_drag and drag_per_length[k] > 0.0:
            for i in range(3):
                a_n[i] = vel0[i] - water_velocity[i]
            along = a_n[0] * e[0] + a_n[1] * e[1] + a_n[2] * e[2]
            for i in range(3):
                a_n[i] -= along * e[i]
            along = velr[0] * e[0] + velr[1] * e[1] + velr[2] * e[2]
            for i in range(3):
                b_n[i] = velr[i] - along * e[i]
            bb = b_n[0] * b_n[0] + b_n[1] * b_n[1] + b_n[2] * b_n[2]
            split = -1.0
            if bb > 0.0:
                split = -(a_n[0] * b_n[0] + a_n[1] * b_n[1] + a_n[2] * b_n[2]) / bb
            if 0.0 < split < L:
                _drag_piece(0.0, split, a_n, b_n, j0, jr, drag_per_length[k], nodes, weights, force)
                _drag_piece(split, L, a_n, b_n, j0, jr, drag_per_length[k], nodes, weights, force)
            else:
                _drag_piece(0.0, L, a_n, b_n, j0, jr, drag_per_length[k], nodes, weights, force)
        if use_added_mass and mass_per_length[k] > 0.0:
            # bias(s) = dJ_lin v + dJ_ang v x p(s) + omega x v(s) = bias0 + s bias1
            bias0[0] = dl0 + da1 * p0[2] - da2 * p0[1] + om1 * vel0[2] - om2 * vel0[1]
            bias0[1] = dl1 + da2 * p0[0] - da0 * p0[2] + om2 * vel0[0] - om0 * vel0[2]
            bias0[2] = dl2 + da0 * p0[1] - da1 * p0[0] + om0 * vel0[1] - om1 * vel0[0]
            bias1[0] = da1 * e[2] - da2 * e[1] + om1 * velr[2] - om2 * velr[1]
            bias1[1] = da2 * e[0] - da0 * e[2] + om2 * velr[0] - om0 * velr[2]
            bias1[2] = da0 * e[1] - da1 * e[0] + om0 * velr[1] - om1 * velr[0]
            for c in range(n):
                along0 = e[0] * j0[0, c] + e[1] * j0[1, c] + e[2] * j0[2, c]
                alongr = e[0] * jr[0, c] + e[1] * jr[1, c] + e[2] * jr[2, c]
                for i in range(3):
                    nj0[i, c] = j0[i, c] - e[i] * along0
                    njr[i, c] = jr[i, c] - e[i] * alongr
            coefficient = mass_per_length[k] * L
            for m in range(nodes.shape[0]):
                s = L * nodes[m]
                w = coefficient * weights[m]
                for a in range(n):
                    na0 = nj0[0, a] + s * njr[0, a]
                    na1 = nj0[1, a] + s * njr[1, a]
                    na2 = nj0[2, a] + s * njr[2, a]
                    bias_force[a] += w * (
                        na0 * (bias0[0] + s * bias1[0])
                        + na1 * (bias0[1] + s * bias1[1])
                        + na2 * (bias0[2] + s * bias1[2])
                    )
                    for b in range(a, n):
                        mass[a, b] += w * (
                            na0 * (nj0[0, b] + s * njr[0, b])
                            + na1 * (nj0[1, b] + s * njr[1, b])
                            + na2 * (nj0[2, b] + s * njr[2, b])
                        )
        if use_buoyancy:
            half = 0.5 * L
            for c in range(n):
                force[c] += buoyancy_force[k] * (j0[2, c] + half * jr[2, c])
    for a in range(n):
        for b in range(a + 1, n):
            mass[b, a] = mass[a, b]
    return mass, bias_force, force


@numba.njit(cache=True)
def underwater_dynamics_kernel(
    q, v, tau, water_velocity, joint_acceleration, friction, mass_upper, nonlinear, jac, djac,
    parents, placement_rotation, placement_translation, axes, idx_v,
    joint_ids, start, axis, length, support, drag_per_length, mass_per_length, buoyancy_force,
    nodes, weights, use_drag, use_added_mass, use_buoyancy,
):  # fmt: skip
    """True acceleration and disturbance: returns ``(q'' (n,), disturbance (n,))``.

    Solves ``(M + M_A)(q'' - a_c) = tau - nle - h_A + f - b v`` with ``M`` from
    the upper triangle ``mass_upper`` (Pinocchio's CRBA), ``nle = C v + G``,
    ``a_c = joint_acceleration`` (the paper current), ``b = friction``.
    ``disturbance = M q'' + nle - tau``: the generalised force the dry model lacks.
    """
    n = v.shape[0]
    added, bias, force = water_terms_kernel(
        q, v, water_velocity, jac, djac,
        parents, placement_rotation, placement_translation, axes, idx_v,
        joint_ids, start, axis, length, support, drag_per_length, mass_per_length, buoyancy_force,
        nodes, weights, use_drag, use_added_mass, use_buoyancy,
    )  # fmt: skip
    mass = np.empty((n, n))
    for a in range(n):
        for b in range(a, n):
            mass[a, b] = mass_upper[a, b]
            mass[b, a] = mass_upper[a, b]
    rhs = tau - nonlinear + force - bias - friction * v
    acc = np.linalg.solve(mass + added, rhs) + joint_acceleration
    disturbance = mass @ acc + nonlinear - tau
    return acc, disturbance
