"""Compiled kernels of :mod:`hydroarm.model.uvms_fast`: one evaluation of the floating system's
v' (RNEA with the water's body wrenches, CRBA with the added inertias, Cholesky), in the bodies'
own frames. Spatial vectors are (linear, angular), Pinocchio's order."""

from __future__ import annotations

import numba
import numpy as np

from hydroarm.model.strips import rotation_into
from hydroarm.model.vehicle import quaternion_matrix, vehicle_generalised_force


@numba.njit(cache=True)
def workspace(nj, nv):  # pragma: no cover - compiled
    """Scratch arrays of :func:`evaluate` (allocated once per control step)."""
    return (
        np.zeros((nj, 3, 3)), np.zeros((nj, 3)), np.zeros((nj, 3, 3)), np.zeros((nj, 6)), np.zeros((nj, 6)),
        np.zeros((nj, 6)), np.zeros((nj, 6, 6)), np.zeros((nv, nv)), np.zeros(nv), np.zeros(6), np.zeros(6),
        np.zeros((6, 6)),
        np.zeros((6, 6)),
    )  # fmt: skip


@numba.njit(cache=True, inline="always")
def _motion_to_child(rot, pos, m, out):  # pragma: no cover - compiled
    """out = X m: motion (v, w) in the parent frame -> the child frame (child placement rot, pos)."""
    w0, w1, w2 = m[3], m[4], m[5]
    l0 = m[0] + w1 * pos[2] - w2 * pos[1]
    l1 = m[1] + w2 * pos[0] - w0 * pos[2]
    l2 = m[2] + w0 * pos[1] - w1 * pos[0]
    for i in range(3):
        out[i] = rot[0, i] * l0 + rot[1, i] * l1 + rot[2, i] * l2
        out[3 + i] = rot[0, i] * w0 + rot[1, i] * w1 + rot[2, i] * w2


@numba.njit(cache=True, inline="always")
def _force_to_parent(rot, pos, f, out):  # pragma: no cover - compiled
    """out += X^T f: force (f, n) in the child frame -> the parent frame."""
    r0 = rot[0, 0] * f[0] + rot[0, 1] * f[1] + rot[0, 2] * f[2]
    r1 = rot[1, 0] * f[0] + rot[1, 1] * f[1] + rot[1, 2] * f[2]
    r2 = rot[2, 0] * f[0] + rot[2, 1] * f[1] + rot[2, 2] * f[2]
    out[0] += r0
    out[1] += r1
    out[2] += r2
    out[3] += rot[0, 0] * f[3] + rot[0, 1] * f[4] + rot[0, 2] * f[5] + pos[1] * r2 - pos[2] * r1
    out[4] += rot[1, 0] * f[3] + rot[1, 1] * f[4] + rot[1, 2] * f[5] + pos[2] * r0 - pos[0] * r2
    out[5] += rot[2, 0] * f[3] + rot[2, 1] * f[4] + rot[2, 2] * f[5] + pos[0] * r1 - pos[1] * r0


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
def _cross_into(a0, a1, a2, b0, b1, b2):  # pragma: no cover - compiled
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@numba.njit(cache=True)
def _water_on_cylinder(k, vel, acc, rot_world, water_velocity, cyl_start, cyl_axis, cyl_values, nodes, weights,
                       flags, out):  # fmt: skip  # pragma: no cover - compiled
    """Add the water's wrench on cylinder k (body frame, about the body origin) to ``out`` (6,)."""
    r0, r1, r2 = cyl_start[k, 0], cyl_start[k, 1], cyl_start[k, 2]
    e0, e1, e2 = cyl_axis[k, 0], cyl_axis[k, 1], cyl_axis[k, 2]
    length, drag, mass, buoyancy = cyl_values[k, 0], cyl_values[k, 1], cyl_values[k, 2], cyl_values[k, 3]
    w0, w1, w2 = vel[3], vel[4], vel[5]
    c0, c1, c2 = _cross_into(w0, w1, w2, r0, r1, r2)
    p0, p1, p2 = vel[0] + c0, vel[1] + c1, vel[2] + c2  # velocity at the start point
    q0, q1, q2 = _cross_into(w0, w1, w2, e0, e1, e2)  # its rate along s (normal to e)
    if flags[3] and drag > 0.0:
        a0, a1, a2 = p0, p1, p2
        if flags[6]:
            for i in range(3):
                cur = rot_world[0, i] * water_velocity[0] + rot_world[1, i] * water_velocity[1]
                cur += rot_world[2, i] * water_velocity[2]
                if i == 0:
                    a0 -= cur
                elif i == 1:
                    a1 -= cur
                else:
                    a2 -= cur
        along = a0 * e0 + a1 * e1 + a2 * e2
        a0, a1, a2 = a0 - along * e0, a1 - along * e1, a2 - along * e2
        along = q0 * e0 + q1 * e1 + q2 * e2
        b0, b1, b2 = q0 - along * e0, q1 - along * e1, q2 - along * e2
        bb = b0 * b0 + b1 * b1 + b2 * b2
        split = -(a0 * b0 + a1 * b1 + a2 * b2) / bb if bb > 0.0 else -1.0
        n_pieces = 2 if 0.0 < split < length else 1
        for piece in range(n_pieces):
            s0 = 0.0 if piece == 0 else split
            s1 = length if n_pieces == 1 or piece == 1 else split
            width = s1 - s0
            for m in range(nodes.shape[0]):
                s = s0 + width * nodes[m]
                v0, v1, v2 = a0 + s * b0, a1 + s * b1, a2 + s * b2
                scale = -drag * width * weights[m] * np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
                f0, f1, f2 = scale * v0, scale * v1, scale * v2
                m0, m1, m2 = _cross_into(r0 + s * e0, r1 + s * e1, r2 + s * e2, f0, f1, f2)
                out[0] += f0
                out[1] += f1
                out[2] += f2
                out[3] += m0
                out[4] += m1
                out[5] += m2
    if flags[4] and mass > 0.0:
        al0, al1, al2 = acc[3], acc[4], acc[5]
        x0, x1, x2 = _cross_into(al0, al1, al2, r0, r1, r2)
        y0, y1, y2 = _cross_into(w0, w1, w2, p0, p1, p2)
        d0, d1, d2 = acc[0] + x0 + y0, acc[1] + x1 + y1, acc[2] + x2 + y2  # classical acceleration at s = 0
        x0, x1, x2 = _cross_into(al0, al1, al2, e0, e1, e2)
        y0, y1, y2 = _cross_into(w0, w1, w2, q0, q1, q2)
        k0, k1, k2 = x0 + y0, x1 + y1, x2 + y2  # its rate along s
        l1, l2, l3 = length, 0.5 * length * length, length * length * length / 3.0
        g0, g1, g2 = l1 * d0 + l2 * k0, l1 * d1 + l2 * k1, l1 * d2 + l2 * k2
        h0, h1, h2 = l2 * d0 + l3 * k0, l2 * d1 + l3 * k1, l2 * d2 + l3 * k2
        along = g0 * e0 + g1 * e1 + g2 * e2
        g0, g1, g2 = -mass * (g0 - along * e0), -mass * (g1 - along * e1), -mass * (g2 - along * e2)
        along = h0 * e0 + h1 * e1 + h2 * e2
        h0, h1, h2 = -mass * (h0 - along * e0), -mass * (h1 - along * e1), -mass * (h2 - along * e2)
        m0, m1, m2 = _cross_into(r0, r1, r2, g0, g1, g2)
        n0, n1, n2 = _cross_into(e0, e1, e2, h0, h1, h2)
        out[0] += g0
        out[1] += g1
        out[2] += g2
        out[3] += m0 + n0
        out[4] += m1 + n1
        out[5] += m2 + n2
    if flags[5] and buoyancy != 0.0:
        f0, f1, f2 = buoyancy * rot_world[2, 0], buoyancy * rot_world[2, 1], buoyancy * rot_world[2, 2]
        half = 0.5 * length
        m0, m1, m2 = _cross_into(r0 + half * e0, r1 + half * e1, r2 + half * e2, f0, f1, f2)
        out[0] += f0
        out[1] += f1
        out[2] += f2
        out[3] += m0
        out[4] += m1
        out[5] += m2


@numba.njit(cache=True)
def evaluate(
    q, v, tau, thrust, water_velocity,
    parents, place_rotation, place_translation, axes, rigid, total,
    cyl_body, cyl_start, cyl_axis, cyl_values, nodes, weights,
    allocation, added_mass, linear_damping, quadratic_damping, buoyancy, cb, gravity, flags,
    work, out,
):  # fmt: skip  # pragma: no cover - compiled
    """v' (nv,) into ``out``: RNEA bias with the water's body wrenches, CRBA with the added
    inertias, Cholesky solve. ``tau`` (nv,): generalised force (base: body wrench)."""
    rot, pos, rot_world, vel, acc, force, composite, mass, rhs, tmp, tmp2, tmp6, xm = work
    rj = tmp6[:3, :3].copy()
    nj = parents.shape[0]
    nv = v.shape[0]
    # root: world placement from q; body twist = v[:6]; no velocity-product acceleration
    rot_world[1] = quaternion_matrix(q[3], q[4], q[5], q[6])
    for i in range(6):
        vel[1, i] = v[i]
        acc[1, i] = 0.0
    for i in range(2, nj):
        par = parents[i]
        rotation_into(axes[i], q[5 + i], rj)
        for a in range(3):
            pos[i, a] = place_translation[i, a]
            for b in range(3):
                rot[i, a, b] = (place_rotation[i, a, 0] * rj[0, b] + place_rotation[i, a, 1] * rj[1, b]
                                + place_rotation[i, a, 2] * rj[2, b])  # fmt: skip
        for a in range(3):
            for b in range(3):
                rot_world[i, a, b] = (rot_world[par, a, 0] * rot[i, 0, b] + rot_world[par, a, 1] * rot[i, 1, b]
                                      + rot_world[par, a, 2] * rot[i, 2, b])  # fmt: skip
        _motion_to_child(rot[i], pos[i], vel[par], vel[i])
        _motion_to_child(rot[i], pos[i], acc[par], acc[i])
        qd = v[4 + i]
        for a in range(3):
            vel[i, 3 + a] += axes[i, a] * qd
        # acc += v x (S qd), S qd = (0, axis qd)
        s0, s1, s2 = axes[i, 0] * qd, axes[i, 1] * qd, axes[i, 2] * qd
        acc[i, 0] += vel[i, 1] * s2 - vel[i, 2] * s1
        acc[i, 1] += vel[i, 2] * s0 - vel[i, 0] * s2
        acc[i, 2] += vel[i, 0] * s1 - vel[i, 1] * s0
        acc[i, 3] += vel[i, 4] * s2 - vel[i, 5] * s1
        acc[i, 4] += vel[i, 5] * s0 - vel[i, 3] * s2
        acc[i, 5] += vel[i, 3] * s1 - vel[i, 4] * s0
    # body forces: I (a + a_gravity) + v x* I v - f_ext
    for i in range(1, nj):
        for a in range(6):
            tmp[a] = acc[i, a]
        for a in range(3):
            tmp[a] += rot_world[i, 2, a] * gravity
        for a in range(6):
            s = 0.0
            t2 = 0.0
            for b in range(6):
                s += rigid[i, a, b] * tmp[b]
                t2 += rigid[i, a, b] * vel[i, b]
            force[i, a] = s
            tmp2[a] = t2
        w0, w1, w2 = vel[i, 3], vel[i, 4], vel[i, 5]
        force[i, 0] += w1 * tmp2[2] - w2 * tmp2[1]
        force[i, 1] += w2 * tmp2[0] - w0 * tmp2[2]
        force[i, 2] += w0 * tmp2[1] - w1 * tmp2[0]
        force[i, 3] += w1 * tmp2[5] - w2 * tmp2[4] + vel[i, 1] * tmp2[2] - vel[i, 2] * tmp2[1]
        force[i, 4] += w2 * tmp2[3] - w0 * tmp2[5] + vel[i, 2] * tmp2[0] - vel[i, 0] * tmp2[2]
        force[i, 5] += w0 * tmp2[4] - w1 * tmp2[3] + vel[i, 0] * tmp2[1] - vel[i, 1] * tmp2[0]
    for k in range(cyl_body.shape[0]):
        i = cyl_body[k]
        for a in range(6):
            tmp[a] = 0.0
        _water_on_cylinder(k, vel[i], acc[i], rot_world[i], water_velocity, cyl_start, cyl_axis, cyl_values,
                           nodes, weights, flags, tmp)  # fmt: skip
        for a in range(6):
            force[i, a] -= tmp[a]
    body = vehicle_generalised_force(v[:6], rot_world[1], water_velocity, added_mass, linear_damping,
                                     quadratic_damping, buoyancy, cb, flags[0], flags[1], flags[2])  # fmt: skip
    for a in range(6):
        s = body[a]
        for b in range(thrust.shape[0]):
            s += allocation[a, b] * thrust[b]
        force[1, a] -= s
    # backward pass: RNEA torques and CRBA
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
        _force_to_parent(rot[i], pos[i], force[i], force[par])
        # F = Ic S, carried to the root
        for a in range(6):
            tmp[a] = composite[i, a, 3] * axes[i, 0] + composite[i, a, 4] * axes[i, 1] + composite[i, a, 5] * axes[i, 2]
        mass[k, k] = axes[i, 0] * tmp[3] + axes[i, 1] * tmp[4] + axes[i, 2] * tmp[5]
        j = i
        while parents[j] > 1:
            for a in range(6):
                tmp2[a] = 0.0
            _force_to_parent(rot[j], pos[j], tmp, tmp2)
            for a in range(6):
                tmp[a] = tmp2[a]
            j = parents[j]
            mass[4 + j, k] = axes[j, 0] * tmp[3] + axes[j, 1] * tmp[4] + axes[j, 2] * tmp[5]
            mass[k, 4 + j] = mass[4 + j, k]
        for a in range(6):
            tmp2[a] = 0.0
        _force_to_parent(rot[j], pos[j], tmp, tmp2)
        for a in range(6):
            mass[a, k] = tmp2[a]
            mass[k, a] = tmp2[a]
        _motion_matrix(rot[i], pos[i], xm)
        _add_transformed_inertia(xm, composite[i], composite[par], tmp6)
    for a in range(6):
        rhs[a] = tau[a] - force[1, a]
        for b in range(6):
            mass[a, b] = composite[1, a, b]
    _cholesky_solve(mass, rhs, out)


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


@numba.njit(cache=True)
def _cholesky_solve(a, b, out):  # pragma: no cover - compiled
    """out = a^-1 b for symmetric positive definite ``a`` (overwritten by its factor)."""
    n = b.shape[0]
    for j in range(n):
        s = a[j, j]
        for k in range(j):
            s -= a[j, k] * a[j, k]
        d = np.sqrt(s)
        a[j, j] = d
        for i in range(j + 1, n):
            s = a[i, j]
            for k in range(j):
                s -= a[i, k] * a[j, k]
            a[i, j] = s / d
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= a[i, k] * out[k]
        out[i] = s / a[i, i]
    for i in range(n - 1, -1, -1):
        s = out[i]
        for k in range(i + 1, n):
            s -= a[k, i] * out[k]
        out[i] = s / a[i, i]
