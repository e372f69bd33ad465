"""Compiled kernels of :mod:`hydroarm.model.arm.fast`: the fixed-base arm's dynamics at one
instant and its whole RK4 control period, body by body in the bodies' own frames.

Rigid body: Featherstone's RNEA (``nle = C v + G``) and CRBA (``M``) on the revolute tree taken
from Pinocchio's model once; the same spatial algebra as the vehicle's fast path
(:mod:`hydroarm.model.dynamics.tree_kernels`, the passes both kernels call), with a fixed root. The
water: every wetted cylinder through :func:`hydroarm.model.water.effects.cylinder_water` in the
frame of the body that carries it (:func:`~hydroarm.model.vehicle.fast_kernels.body_frame`), its
wrench carried to the joints by the RNEA's backward pass; the added-mass inertia, constant in
that frame, joins the rigid one in the CRBA (``M + M_A``); the disturbance's ``M q''`` is an
RNEA pass. Then the reference plant's equation
(:func:`hydroarm.model.water.strips.solve_underwater`) ``(M + M_A)(q'' - a_c) = tau - nle - h_A + f - b v``
with a Cholesky solve, the joint friction and the Reynolds drag joining tau as
:func:`hydroarm.model.arm.plant.rk4_stage_kernel` does, and its RK4 bookkeeping
(:func:`hydroarm.model.dynamics.integrator.rk4_disturbance_stage`).

Everything allocates its scratch per call (a few small arrays per control period), and each
thread of :func:`batch_step_kernel` (``numba.prange``) steps its copies with its own replica of
the constants (:func:`replicate`), so that copies stepped in parallel share nothing, not even a
reference count. Spatial vectors are (linear, angular), Pinocchio's order.

The two entries a caller may call alone, :func:`rigid_terms` and :func:`evaluate`, are compiled
functions of their own, cached once (what they call is inlined into them by numba,
``inline="always"``, as the hot per-body and per-node helpers must be). Inlined too, as they were,
each direct call compiled its own copy of the whole evaluation. Measured on the paper arm with
empty caches (2-core Xeon, 2026-12-05, other runs on its second core): :func:`step_kernel`
compiles in 59 s instead of 93 s, after which the direct calls load from the cache instead of
compiling for 42 s and 71 s; the states of a control period are the same to the bit. A call
per RK4 stage is about 40 calls a control period; the period's time did not move beyond this
machine's noise (fastest of 5 alternating runs, CPU time: paper arm 0.26 ms before, 0.29 ms
after; Alpha 5 0.35 and 0.30 ms). Un-inlining the tree passes as well was tried and not kept:
they are called per body, and the paper arm's period then took about 30 % longer.
"""

from __future__ import annotations

import numba
import numpy as np
from numba.core import types
from numba.experimental import structref

from hydroarm.model.dynamics.fixed_order import cholesky_solve_into
from hydroarm.model.dynamics.integrator import rk4_disturbance_stage
from hydroarm.model.dynamics.tree_kernels import (
    body_force,
    crba_column,
    force_to_parent,
    joint_motion,
    motion_to_child,
    place_joint,
)
from hydroarm.model.real_loop.friction import friction_torque
from hydroarm.model.vehicle.fast_kernels import body_frame
from hydroarm.model.water.current import current_at
from hydroarm.model.water.effects import DRAG_REYNOLDS, cylinder_water, new_frame
from hydroarm.model.water.strips import STRIPS_TYPE, replicate_strips


@structref.register
class FastArmType(types.StructRef):
    """numba type of :class:`FastArm`."""


class FastArm(structref.StructRefProxy):
    """What :func:`step_kernel` reads, one compiled handle: the tree (``parents`` (nj,),
    ``place_rotation`` (nj, 3, 3) / ``place_translation`` (nj, 3): Pinocchio's jointPlacements,
    ``axes`` (nj, 3), the bodies' spatial inertias ``rigid`` and with the water's added inertias
    ``total`` (nj, 6, 6), in the bodies' frames, ``gravity`` (3,) m/s^2), the body-frame ``strips``
    (:class:`~hydroarm.model.water.strips.Strips`; its current too), the viscous ``uniform`` friction
    (N m s/rad) and the joint friction model (``friction_on`` and the five (n,) arrays of
    :func:`~hydroarm.model.real_loop.friction.friction_torque`)."""


structref.define_boxing(FastArmType, FastArm)
_F1, _F2, _F3, _I1 = types.float64[::1], types.float64[:, ::1], types.float64[:, :, ::1], types.int64[::1]
FAST_ARM_TYPE = FastArmType([
    ("parents", _I1), ("place_rotation", _F3), ("place_translation", _F2), ("axes", _F2), ("rigid", _F3),
    ("total", _F3), ("gravity", _F1), ("strips", STRIPS_TYPE), ("uniform", types.float64),
    ("friction_on", types.boolean), ("coulomb", _F1), ("breakaway", _F1), ("viscous", _F1),
    ("stribeck_velocity", _F1), ("width", _F1),
])  # fmt: skip


@numba.njit(cache=True)
def new_fast_arm(tree, gravity, strips, uniform, friction_on, friction):  # pragma: no cover - compiled
    """A :class:`FastArm` of (parents, place_rotation, place_translation, axes, rigid, total), the
    gravity, the strips and the friction (``friction``: the five arrays)."""
    s = structref.new(FAST_ARM_TYPE)
    s.parents, s.place_rotation, s.place_translation, s.axes, s.rigid, s.total = tree
    s.gravity, s.strips, s.uniform, s.friction_on = gravity, strips, uniform, friction_on
    s.coulomb, s.breakaway, s.viscous, s.stribeck_velocity, s.width = friction
    return s


@numba.njit(cache=True)
def scratch(arm):  # pragma: no cover - compiled
    """The work arrays of :func:`evaluate` for ``arm``: (rot, pos, rot_world (nj, 3, 3|3)), vel,
    acc, force, water, drag (nj, 6), the composite inertias and a spare (nj, 6, 6),
    a 6 x 6, three (6,) and a (6, 6), the body frame, a joint rotation (3, 3), a spare
    (nj, 3) and a spare (nj, 6); then :func:`evaluate`'s (n,) current
    acceleration, nle, water force, applied torque and right-hand side, its (n, n) matrix and the
    water's velocity (3,); last, the arrays of ``arm`` (its tree, strips and friction), taken out of
    the structure once here rather than at every use (each read of a structure's array field
    costs a reference count)."""
    nj = arm.parents.shape[0]
    n = nj - 1
    strips = arm.strips
    frame = new_frame(6, True, strips.nodes, strips.weights, strips.curve_log_re, strips.curve_cd)
    # a dozen allocations instead of thirty: the arrays of one shape are rows of one block (integer
    # indexing keeps them C-contiguous, the same types as separate arrays)
    rotations, points, motions = np.zeros((2, nj, 3, 3)), np.zeros((2, nj, 3)), np.zeros((6, nj, 6))
    inertias, small, vectors, joint = np.zeros((2, nj, 6, 6)), np.zeros((2, 6, 6)), np.zeros((3, 6)), np.zeros((5, n))
    rot_world = rotations[1]
    for a in range(3):
        rot_world[0, a, a] = 1.0
    return (
        rotations[0], points[0], rot_world, motions[0], motions[1], motions[2], motions[3], motions[4],
        inertias[0], inertias[1], small[0], vectors[0], vectors[1], vectors[2], small[1], frame, np.zeros((3, 3)),
        points[1], motions[5], joint[0], joint[1], joint[2], joint[3], joint[4], np.zeros((n, n)), np.zeros(3),
        (arm.parents, arm.place_rotation, arm.place_translation, arm.axes, arm.rigid, arm.total, arm.gravity),
        (strips.joint_ids, strips.start, strips.axis, strips.table, strips.current_joint, strips.current_world),
        (arm.coulomb, arm.breakaway, arm.viscous, arm.stribeck_velocity, arm.width),
    )  # fmt: skip


@numba.njit(cache=True, inline="always")
def _forward(q, v, arm, work):  # pragma: no cover - compiled
    """Forward pass: joint placements, world rotations, body twists and velocity-product
    accelerations (revolute joint i moves coordinate i - 1)."""
    rot, pos, rot_world, vel, acc = work[0], work[1], work[2], work[3], work[4]
    rj = work[16]
    parents, place_rotation, place_translation, axes = work[26][0], work[26][1], work[26][2], work[26][3]
    for i in range(1, parents.shape[0]):
        par = parents[i]
        place_joint(i, par, q[i - 1], place_rotation, place_translation, axes, rot, pos, rot_world, rj)
        joint_motion(i, par, v[i - 1], axes, rot, pos, vel, acc)


@numba.njit(cache=True, inline="always")
def _body_forces(arm, work):  # pragma: no cover - compiled
    """The rigid RNEA's body forces ``I (a + a_g) + v x* I v`` (a_g = -R^T g)."""
    rot_world, vel, acc, force = work[2], work[3], work[4], work[5]
    tmp, tmp2 = work[11], work[12]
    rigid, gravity = work[26][4], work[26][6]
    g0, g1, g2 = gravity[0], gravity[1], gravity[2]
    for i in range(1, rigid.shape[0]):
        for a in range(6):
            tmp[a] = acc[i, a]
        for a in range(3):
            tmp[a] -= rot_world[i, 0, a] * g0 + rot_world[i, 1, a] * g1 + rot_world[i, 2, a] * g2
        body_force(rigid[i], tmp, vel[i], tmp2, force[i])


@numba.njit(cache=True, inline="always")
def _water_wrenches(arm, water_velocity, work):  # pragma: no cover - compiled
    """The water's body wrenches: buoyancy, axial drag, the added mass's velocity term and the
    constant-C_d drag into ``water``, the Reynolds drag into ``drag``."""
    rot_world, vel, acc, water, drag = work[2], work[3], work[4], work[6], work[7]
    frame, unused = work[15], work[13]
    strips = arm.strips
    for i in range(water.shape[0]):
        for a in range(6):
            water[i, a] = 0.0
            drag[i, a] = 0.0
    if not (strips.drag or strips.axial or strips.added_mass or strips.buoyancy):
        return
    bodies, start, axis, table = work[27][0], work[27][1], work[27][2], work[27][3]
    reynolds = strips.drag_model == DRAG_REYNOLDS
    no_inertia = work[14][:0, :0]  # the added inertia is in ``arm.total``
    for k in range(bodies.shape[0]):
        i = bodies[k]
        body_frame(start, axis, table, k, vel[i], acc[i], rot_world[i], water_velocity, True, frame)
        cylinder_water(strips, frame, no_inertia, unused, water[i], drag[i] if reynolds else water[i])


@numba.njit(cache=True, inline="always")
def _backward(arm, work, nle, water_force, drag_force):  # pragma: no cover - compiled
    """RNEA's backward pass: ``nle`` and the water's generalised forces."""
    rot, pos, force, water, drag = work[0], work[1], work[5], work[6], work[7]
    parents, axes = work[26][0], work[26][3]
    for i in range(parents.shape[0] - 1, 0, -1):
        par = parents[i]
        k = i - 1
        a0, a1, a2 = axes[i, 0], axes[i, 1], axes[i, 2]
        nle[k] = a0 * force[i, 3] + a1 * force[i, 4] + a2 * force[i, 5]
        water_force[k] = a0 * water[i, 3] + a1 * water[i, 4] + a2 * water[i, 5]
        drag_force[k] = a0 * drag[i, 3] + a1 * drag[i, 4] + a2 * drag[i, 5]
        if par > 0:
            force_to_parent(rot[i], pos[i], force[i], force[par])
            force_to_parent(rot[i], pos[i], water[i], water[par])
            force_to_parent(rot[i], pos[i], drag[i], drag[par])


@numba.njit(cache=True, inline="always")
def _add_to_world(inertia, rot, p, out, scratch):  # pragma: no cover - compiled
    """out (6, 6) += X^T inertia X: a body's inertia (about its origin, its axes; the body placed
    at rotation ``rot`` and origin ``p`` in the outer frame) about the outer frame's origin, in
    its axes. X maps the outer frame's motion to the body's: ``(R^T (v - p x w), R^T w)``; the
    block structure of X spares half of the two 6 x 6 products, the symmetry of the result
    (``inertia`` symmetric) a third of the second."""
    for a in range(6):  # scratch = inertia X
        for b in range(3):
            scratch[a, b] = inertia[a, 0] * rot[b, 0] + inertia[a, 1] * rot[b, 1] + inertia[a, 2] * rot[b, 2]
        for b in range(3):
            scratch[a, 3 + b] = inertia[a, 3] * rot[b, 0] + inertia[a, 4] * rot[b, 1] + inertia[a, 5] * rot[b, 2]
        # minus (the linear columns) [p]x
        l0, l1, l2 = scratch[a, 0], scratch[a, 1], scratch[a, 2]
        scratch[a, 3] += -(l1 * p[2] - l2 * p[1])
        scratch[a, 4] += -(l2 * p[0] - l0 * p[2])
        scratch[a, 5] += -(l0 * p[1] - l1 * p[0])
    # out += X^T scratch, symmetric: the upper triangle computed, mirrored into the lower (the
    # top-left block's columns need only their top rows, the bottom-left block is the top-right's
    # transpose): 21 of the 36 three-term sums
    for b in range(3):
        for a in range(b + 1):
            s = rot[a, 0] * scratch[0, b] + rot[a, 1] * scratch[1, b] + rot[a, 2] * scratch[2, b]
            out[a, b] += s
            if a != b:
                out[b, a] += s
    for b in range(3, 6):
        s0 = rot[0, 0] * scratch[0, b] + rot[0, 1] * scratch[1, b] + rot[0, 2] * scratch[2, b]
        s1 = rot[1, 0] * scratch[0, b] + rot[1, 1] * scratch[1, b] + rot[1, 2] * scratch[2, b]
        s2 = rot[2, 0] * scratch[0, b] + rot[2, 1] * scratch[1, b] + rot[2, 2] * scratch[2, b]
        out[0, b] += s0
        out[1, b] += s1
        out[2, b] += s2
        out[b, 0] += s0
        out[b, 1] += s1
        out[b, 2] += s2
        t = rot[0, 0] * scratch[3, b] + rot[0, 1] * scratch[4, b] + rot[0, 2] * scratch[5, b]
        t += p[1] * s2 - p[2] * s1
        out[3, b] += t
        if b > 3:
            out[b, 3] += t
            t = rot[1, 0] * scratch[3, b] + rot[1, 1] * scratch[4, b] + rot[1, 2] * scratch[5, b]
            t += p[2] * s0 - p[0] * s2
            out[4, b] += t
            if b > 4:
                out[b, 4] += t
                t = rot[2, 0] * scratch[3, b] + rot[2, 1] * scratch[4, b] + rot[2, 2] * scratch[5, b]
                out[5, 5] += t + (p[0] * s1 - p[1] * s0)


@numba.njit(cache=True, inline="always")
def crba(arm, work, mass):  # pragma: no cover - compiled
    """``mass`` (n, n) = M + M_A at the configuration of the last forward pass: the CRBA on the
    bodies' total inertias (rigid + added, constant in their frames), the composites carried to
    each parent's frame (``X^T I X``), ``M_ij = S_i^T X I^c_j S_j``."""
    rot, pos, composite, tmp6, tmp, tmp2 = work[0], work[1], work[8], work[14], work[11], work[12]
    parents, axes, total = work[26][0], work[26][3], work[26][5]
    nj = parents.shape[0]
    for i in range(1, nj):
        for a in range(6):
            for b in range(6):
                composite[i, a, b] = total[i, a, b]
    for i in range(nj - 1, 0, -1):
        par = parents[i]
        crba_column(i, parents, axes, rot, pos, composite[i], 0, -1, mass, tmp, tmp2)
        if par > 0:
            _add_to_world(composite[i], rot[i], pos[i], composite[par], tmp6)


@numba.njit(cache=True, inline="always")
def mass_times(arm, work, qdd, out):  # pragma: no cover - compiled
    """``out`` (n,) = M(q) qdd, the rigid body's (no water), at the last forward pass's q: the
    RNEA with no velocity and no gravity (work's acc/force rows are overwritten)."""
    rot, pos, acc, force = work[0], work[1], work[4], work[5]
    parents, axes, rigid = work[26][0], work[26][3], work[26][4]
    nj = parents.shape[0]
    for i in range(1, nj):
        motion_to_child(rot[i], pos[i], acc[parents[i]], acc[i])
        for a in range(3):
            acc[i, 3 + a] += axes[i, a] * qdd[i - 1]
        for a in range(6):
            s = 0.0
            for b in range(6):
                s += rigid[i, a, b] * acc[i, b]
            force[i, a] = s
    for i in range(nj - 1, 0, -1):
        par = parents[i]
        out[i - 1] = axes[i, 0] * force[i, 3] + axes[i, 1] * force[i, 4] + axes[i, 2] * force[i, 5]
        if par > 0:
            force_to_parent(rot[i], pos[i], force[i], force[par])


@numba.njit(cache=True)
def rigid_terms(q, v, arm, work, nle, water_force, drag_force, mass, water_velocity):  # pragma: no cover
    """Everything at (q, v) but the solve: ``nle`` = C v + G (n,), the water's generalised forces
    (``water_force``: buoyancy, axial drag, -h_A, constant-C_d drag; ``drag_force``: the Reynolds
    drag), ``mass`` = M + M_A (n, n), the water moving at ``water_velocity`` (3,)."""
    _forward(q, v, arm, work)
    _body_forces(arm, work)
    _water_wrenches(arm, water_velocity, work)
    _backward(arm, work, nle, water_force, drag_force)
    crba(arm, work, mass)


@numba.njit(cache=True)
def evaluate(t, q, v, tau, arm, work, out_acc, out_dist, out_drag):  # pragma: no cover - compiled
    """q'' (``out_acc``) and the disturbance ``M q'' + nle - tau`` (``out_dist``) at (t, q, v)
    under tau, the plant's equation (module docstring); ``out_drag`` the Reynolds drag's
    generalised force (zeros under a constant C_d), which the disturbance does not yet hold
    (the caller adds it, as the reference does)."""
    n = q.shape[0]
    strips = arm.strips
    joint_acceleration, nle, water_force, applied, rhs = work[19], work[20], work[21], work[22], work[23]
    mass, water_velocity = work[24], work[25]
    current_at(t, work[27][4], work[27][5], joint_acceleration, water_velocity)
    rigid_terms(q, v, arm, work, nle, water_force, out_drag, mass, water_velocity)
    reynolds = strips.drag_model == DRAG_REYNOLDS
    for i in range(n):
        applied[i] = tau[i] + out_drag[i] if reynolds else tau[i]
    joint_friction = applied  # replaced when the friction model is on
    if arm.friction_on:
        coulomb, breakaway, viscous, stribeck_velocity, width = work[28]
        joint_friction = friction_torque(v, coulomb, breakaway, viscous, stribeck_velocity, width)
        for i in range(n):
            applied[i] -= joint_friction[i]
    uniform = arm.uniform
    for i in range(n):
        rhs[i] = applied[i] - nle[i] + water_force[i] - uniform * v[i]
    cholesky_solve_into(mass, rhs, out_acc)
    for i in range(n):
        out_acc[i] += joint_acceleration[i]
    mass_times(arm, work, out_acc, out_dist)
    for a in range(n):
        out_dist[a] = out_dist[a] + nle[a] - applied[a]
        if arm.friction_on:
            out_dist[a] -= joint_friction[a]


@numba.njit(cache=True)
def step_kernel(t, x, tau, steps, h, arm):  # pragma: no cover - compiled
    """The whole control period: ``steps`` classic RK4 steps of h (s) from (t, x = [q, v] (2n,))
    under the held tau (n,). Returns ``(x_next (2n,), disturbance (n,) averaged with the RK4
    weights, the first stage's disturbance (n,))``, the reference plant's
    (:meth:`hydroarm.model.arm.plant.UnderwaterPlant.step`) bookkeeping; all NaN once the state
    stops being finite (a diverging run)."""
    n = tau.shape[0]
    work = scratch(arm)
    reynolds = arm.strips.drag_model == DRAG_REYNOLDS
    state = x.copy()
    xs = x.copy()
    ks = np.empty((4, 2 * n))
    dists = np.empty((4, n))
    average = np.zeros(n)
    start = np.empty(n)
    acc, dist, drag = np.empty(n), np.empty(n), np.empty(n)
    time = t
    for step in range(steps):
        half = time + 0.5 * h
        for stage in range(4):
            stage_time = time if stage == 0 else (time + h if stage == 3 else half)
            evaluate(stage_time, xs[:n], xs[n:], tau, arm, work, acc, dist, drag)
            rk4_disturbance_stage(stage, h, state, xs, ks, acc, dist, dists, average, drag, reynolds)
        finite = True
        for i in range(2 * n):
            if not np.isfinite(state[i]):
                finite = False
        if not finite:
            nan = np.full(n, np.nan)
            return np.full(2 * n, np.nan), nan, nan.copy()
        if step == 0:
            for i in range(n):
                start[i] = dists[0, i]
        time += h
    for i in range(n):
        average[i] /= 6.0 * steps
    return state, average, start


@numba.njit(cache=True)
def replicate(arm):  # pragma: no cover - compiled
    """A private copy of ``arm`` (every array copied, the strips too: :func:`replicate_strips`):
    what one thread of :func:`batch_step_kernel` steps its copies with, so that threads do not
    contend on the shared arrays' reference counts. The same values: the same numbers to the bit."""
    tree = (arm.parents.copy(), arm.place_rotation.copy(), arm.place_translation.copy(), arm.axes.copy(),
            arm.rigid.copy(), arm.total.copy())  # fmt: skip
    friction = (arm.coulomb.copy(), arm.breakaway.copy(), arm.viscous.copy(), arm.stribeck_velocity.copy(),
                arm.width.copy())  # fmt: skip
    return new_fast_arm(tree, arm.gravity.copy(), replicate_strips(arm.strips), arm.uniform, arm.friction_on, friction)


@numba.njit(cache=True, parallel=True)
def batch_step_kernel(t, x, tau, steps, h, arms, which, chunks):  # pragma: no cover - compiled
    """:func:`step_kernel` for N copies at once, across the cores: ``x`` (N, 2n), ``tau`` (N, n),
    copy c stepped with ``arms[which[c]]`` (a typed list of :class:`FastArm`: one shared, or one
    per water or mass setting). Returns ``(x_next (N, 2n), disturbance (N, n), start (N, n))``;
    each copy's numbers are :func:`step_kernel`'s bit for bit.

    The copies are split into ``chunks`` contiguous runs (one per thread), and each run steps
    with its own :func:`replicate` of the setting it meets (made again when ``which`` changes
    along the run): stepping every copy with the one shared ``arms[k]``, the threads spent their
    time incrementing its arrays' shared reference counts (64 copies on 2 threads of a 2-core
    Xeon: 1.4x one thread's rate shared, 2.1x replicated)."""
    count, n = tau.shape
    out = np.empty((count, 2 * n))
    dist = np.empty((count, n))
    start = np.empty((count, n))
    size = (count + chunks - 1) // chunks
    for chunk in numba.prange(chunks):
        first, last = chunk * size, min(count, (chunk + 1) * size)
        if first >= last:
            continue
        current = which[first]
        local = replicate(arms[current])
        for c in range(first, last):
            if which[c] != current:
                current = which[c]
                local = replicate(arms[current])
            state, average, begin = step_kernel(t[c], x[c], tau[c], steps, h, local)
            out[c] = state
            dist[c] = average
            start[c] = begin
    return out, dist, start
