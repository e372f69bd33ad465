"""Compiled passes over a revolute tree, in the bodies' own frames, shared by the fixed-base arm's
fast path (:mod:`hydroarm.model.arm.fast_kernels`) and the floating system's
(:mod:`hydroarm.model.vehicle.fast_kernels`): Featherstone's RNEA (joint placement, twist and
velocity-product propagation, the body forces ``I a + v x* I v``, forces carried to the parent)
and the CRBA's column walk. Each is written once here so that the two
kernels are the same arithmetic, operation for operation.

The tree is Pinocchio's (``parents``, ``jointPlacements`` as ``place_rotation`` (nj, 3, 3) /
``place_translation`` (nj, 3), revolute ``axes`` (nj, 3)); spatial vectors are (linear,
angular), Pinocchio's order; ``rot`` (nj, 3, 3) / ``pos`` (nj, 3) are each body's placement in
its parent, ``rot_world`` its orientation in the world.
"""

from __future__ import annotations

import numba

from hydroarm.model.water.strips import rotation_into


@numba.njit(cache=True, inline="always")
def motion_to_child(rot, pos, m, out):  # pragma: no cover - compiled
    """out = X m: motion (v, w) in the parent frame -> the child frame (child placement rot, pos)."""
    w0, w1, w2 = m[3], m[4], m[5]
    l0 = m[0] + w1 * pos[2] - w2 * pos[1]
    l1 = m[1] + w2 * pos[0] - w0 * pos[2]
    l2 = m[2] + w0 * pos[1] - w1 * pos[0]
    for i in range(3):
        out[i] = rot[0, i] * l0 + rot[1, i] * l1 + rot[2, i] * l2
        out[3 + i] = rot[0, i] * w0 + rot[1, i] * w1 + rot[2, i] * w2


@numba.njit(cache=True, inline="always")
def force_to_parent(rot, pos, f, out):  # pragma: no cover - compiled
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


@numba.njit(cache=True, inline="always")
def place_joint(i, par, angle, place_rotation, place_translation, axes, rot, pos, rot_world, rj):  # pragma: no cover
    """Body i's placement in its parent ``par`` at joint angle ``angle`` (rad): ``rot[i]`` =
    placement rotation x the joint's rotation (``rj`` (3, 3) scratch), ``pos[i]``, and its world
    orientation ``rot_world[i] = rot_world[par] rot[i]``."""
    rotation_into(axes[i], angle, rj)
    for a in range(3):
        pos[i, a] = place_translation[i, a]
        for b in range(3):
            rot[i, a, b] = (place_rotation[i, a, 0] * rj[0, b] + place_rotation[i, a, 1] * rj[1, b]
                            + place_rotation[i, a, 2] * rj[2, b])  # fmt: skip
    for a in range(3):
        for b in range(3):
            rot_world[i, a, b] = (rot_world[par, a, 0] * rot[i, 0, b] + rot_world[par, a, 1] * rot[i, 1, b]
                                  + rot_world[par, a, 2] * rot[i, 2, b])  # fmt: skip


@numba.njit(cache=True, inline="always")
def joint_motion(i, par, qd, axes, rot, pos, vel, acc):  # pragma: no cover - compiled
    """Body i's twist ``vel[i]`` = X vel[par] + S qd and velocity-product acceleration ``acc[i]``
    = X acc[par] + vel[i] x (S qd) (S = (0, axis); ``qd`` rad/s), body i placed by the last
    :func:`place_joint`."""
    motion_to_child(rot[i], pos[i], vel[par], vel[i])
    motion_to_child(rot[i], pos[i], acc[par], acc[i])
    s0, s1, s2 = axes[i, 0] * qd, axes[i, 1] * qd, axes[i, 2] * qd
    vel[i, 3] += s0
    vel[i, 4] += s1
    vel[i, 5] += s2
    acc[i, 0] += vel[i, 1] * s2 - vel[i, 2] * s1
    acc[i, 1] += vel[i, 2] * s0 - vel[i, 0] * s2
    acc[i, 2] += vel[i, 0] * s1 - vel[i, 1] * s0
    acc[i, 3] += vel[i, 4] * s2 - vel[i, 5] * s1
    acc[i, 4] += vel[i, 5] * s0 - vel[i, 3] * s2
    acc[i, 5] += vel[i, 3] * s1 - vel[i, 4] * s0


@numba.njit(cache=True, inline="always")
def body_force(inertia, acc, vel, scratch, out):  # pragma: no cover - compiled
    """out (6,) = I a + v x* (I v): a body's force from its spatial ``inertia`` (6, 6), its
    acceleration ``acc`` (6,; gravity's included by the caller) and twist ``vel`` (6,);
    ``scratch`` (6,) receives I v."""
    for a in range(6):
        s = 0.0
        t2 = 0.0
        for b in range(6):
            s += inertia[a, b] * acc[b]
            t2 += inertia[a, b] * vel[b]
        out[a] = s
        scratch[a] = t2
    w0, w1, w2 = vel[3], vel[4], vel[5]
    out[0] += w1 * scratch[2] - w2 * scratch[1]
    out[1] += w2 * scratch[0] - w0 * scratch[2]
    out[2] += w0 * scratch[1] - w1 * scratch[0]
    out[3] += w1 * scratch[5] - w2 * scratch[4] + vel[1] * scratch[2] - vel[2] * scratch[1]
    out[4] += w2 * scratch[3] - w0 * scratch[5] + vel[2] * scratch[0] - vel[0] * scratch[2]
    out[5] += w0 * scratch[4] - w1 * scratch[3] + vel[0] * scratch[1] - vel[1] * scratch[0]


@numba.njit(cache=True, inline="always")
def crba_column(i, parents, axes, rot, pos, composite, root, offset, mass, tmp, tmp2):  # pragma: no cover
    """The CRBA's column of joint i (coordinate ``i + offset``) from its composite inertia
    ``composite`` (6, 6, body i's frame): ``mass[k, k] = S^T I^c S`` and, walking up to the
    joints whose parent is ``root``, ``mass[j + offset, k]`` (and its mirror). Returns the last
    joint reached j; ``tmp`` (6,) then holds ``I^c S`` in j's frame (``tmp2`` (6,) scratch)."""
    k = i + offset
    a0, a1, a2 = axes[i, 0], axes[i, 1], axes[i, 2]
    for a in range(6):
        tmp[a] = composite[a, 3] * a0 + composite[a, 4] * a1 + composite[a, 5] * a2
    mass[k, k] = a0 * tmp[3] + a1 * tmp[4] + a2 * tmp[5]
    j = i
    while parents[j] > root:
        for a in range(6):
            tmp2[a] = 0.0
        force_to_parent(rot[j], pos[j], tmp, tmp2)
        for a in range(6):
            tmp[a] = tmp2[a]
        j = parents[j]
        value = axes[j, 0] * tmp[3] + axes[j, 1] * tmp[4] + axes[j, 2] * tmp[5]
        mass[j + offset, k] = value
        mass[k, j + offset] = value
    return j
