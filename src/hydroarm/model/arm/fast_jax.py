"""The batched fixed-base plant's control period in JAX (float64): the GPU path of docs/model.md.

The same mathematics as the compiled CPU plant (:mod:`hydroarm.model.arm.fast_kernels`), operation
for operation where the arithmetic is the same: the forward pass over the tree, the rigid body
forces, the water of every wetted cylinder in its body's frame (constant-C_d Morison drag with
its Gauss points vectorised, axial drag, the added mass's velocity term, Morison's or
Kirchhoff's, in closed form as the body frame takes them, buoyancy), the
backward pass, the CRBA on the rigid + added inertias, an unrolled Cholesky solve of the n x n
system (no vendor solve), the joint friction and the viscous friction, the paper's joint
current and the uniform current, the disturbance ``M q'' + nle - tau`` and the RK4 bookkeeping of
:func:`~hydroarm.model.arm.fast_kernels.step_kernel`.

The tree (parents, placements, axes, inertias) and the strips' coefficients are static: the
loops over bodies and cylinders unroll at trace time; the RK4's four stages are one
``lax.fori_loop`` body (one evaluation traced, not four) inside a ``lax.fori_loop`` over the
inner steps; ``jax.vmap`` maps the copies and ``jax.jit`` compiles the period.

This module imports only NumPy and JAX: it is loaded by file path on a machine with JAX but
without hydroarm's other dependencies (``scripts/gpu_plant.py --run``). Its constants are the
dict :func:`hydroarm.model.arm.fast_export.export_constants` makes from a
:class:`~hydroarm.model.arm.fast.FastArmDynamics` (NumPy arrays, ``np.savez``-able).
What the compiled plant models and this does not (the Reynolds drag, a floating base) is refused
by :func:`check_constants`.
"""

from __future__ import annotations

import numpy as np

REQUIRED = (
    "parents", "place_rotation", "place_translation", "axes", "rigid", "total", "gravity",
    "joint_ids", "start", "axis", "table", "nodes", "weights", "switches", "floating",
    "current_joint", "current_world", "uniform", "friction_on",
    "coulomb", "breakaway", "viscous", "stribeck_velocity", "width",
)  # fmt: skip
"""The keys of the constants dict (the FastArm's fields and its strips')."""

LENGTH, DRAG, MASS, BUOYANCY, AXIAL = 0, 1, 2, 3, 4
"""Columns of ``table`` (:data:`hydroarm.model.water.effects.LENGTH` ...)."""


def check_constants(constants: dict) -> None:
    """Raise ValueError naming what this path does not cover (module docstring) or a missing key."""
    missing = [k for k in REQUIRED if k not in constants]
    if missing:
        raise ValueError(f"fast_jax: the constants lack {missing} (make them with export_constants)")
    drag, added_mass, buoyancy, axial, drag_model, added_mass_model = (int(s) for s in constants["switches"])
    if drag and drag_model != 0:
        raise ValueError("fast_jax: water.drag_model = 'reynolds' is not on the JAX path (only 'constant')")
    if added_mass_model not in (0, 1):
        raise ValueError(f"fast_jax: added_mass_model {added_mass_model} is neither Morison (0) nor Kirchhoff (1)")
    if bool(constants["floating"]):
        raise ValueError("fast_jax: a floating base is not on the JAX path (the fixed-base arm only)")
    parents = np.asarray(constants["parents"])
    if parents[0] != 0 or np.any(parents[1:] >= np.arange(1, parents.size)):
        raise ValueError("fast_jax: parents must precede their children (Pinocchio's order)")


def _f(a):
    """A NumPy array of constants as nested Python floats (exact: IEEE doubles either way)."""
    return np.asarray(a, dtype=float).tolist()


class _Arm:
    """The constants as Python floats and ints, read at trace time."""

    def __init__(self, c: dict):
        check_constants(c)
        self.parents = [int(p) for p in np.asarray(c["parents"])]
        self.nj = len(self.parents)
        self.n = self.nj - 1
        self.place_rotation, self.place_translation = _f(c["place_rotation"]), _f(c["place_translation"])
        self.axes, self.rigid, self.total = _f(c["axes"]), _f(c["rigid"]), _f(c["total"])
        self.gravity = _f(c["gravity"])
        self.joint_ids = [int(j) for j in np.asarray(c["joint_ids"])]
        self.start, self.axis, self.table = _f(c["start"]), _f(c["axis"]), _f(c["table"])
        self.nodes = np.asarray(c["nodes"], dtype=float)
        self.weights = np.asarray(c["weights"], dtype=float)
        switches = [int(s) for s in c["switches"]]
        self.drag, self.added_mass, self.buoyancy, self.axial = (bool(s) for s in switches[:4])
        self.kirchhoff = switches[5] == 1
        self.current_joint = np.asarray(c["current_joint"], dtype=float).reshape(3, -1)
        self.current_world = _f(c["current_world"])
        self.uniform = float(c["uniform"])
        self.friction_on = bool(c["friction_on"])
        self.friction = tuple(np.asarray(c[k], dtype=float) for k in
                              ("coulomb", "breakaway", "viscous", "stribeck_velocity", "width"))  # fmt: skip


# --- spatial algebra on Python lists of scalars (the numba kernels' expressions, same order) ---------


def _rotation(axis, angle, jnp):
    """Rodrigues (:func:`hydroarm.model.water.strips.rotation_into`): 3 x 3 nested lists."""
    c, s = jnp.cos(angle), jnp.sin(angle)
    x, y, z = axis
    t = 1.0 - c
    return [
        [c + x * x * t, x * y * t - z * s, x * z * t + y * s],
        [y * x * t + z * s, c + y * y * t, y * z * t - x * s],
        [z * x * t - y * s, z * y * t + x * s, c + z * z * t],
    ]


def _motion_to_child(rot, pos, m):
    """X m (:func:`hydroarm.model.dynamics.tree_kernels.motion_to_child`)."""
    w0, w1, w2 = m[3], m[4], m[5]
    l0 = m[0] + w1 * pos[2] - w2 * pos[1]
    l1 = m[1] + w2 * pos[0] - w0 * pos[2]
    l2 = m[2] + w0 * pos[1] - w1 * pos[0]
    lin = [rot[0][i] * l0 + rot[1][i] * l1 + rot[2][i] * l2 for i in range(3)]
    ang = [rot[0][i] * w0 + rot[1][i] * w1 + rot[2][i] * w2 for i in range(3)]
    return lin + ang


def _force_to_parent(rot, pos, f, out):
    """out + X^T f (:func:`hydroarm.model.dynamics.tree_kernels.force_to_parent`); out None: from zero."""
    r0 = rot[0][0] * f[0] + rot[0][1] * f[1] + rot[0][2] * f[2]
    r1 = rot[1][0] * f[0] + rot[1][1] * f[1] + rot[1][2] * f[2]
    r2 = rot[2][0] * f[0] + rot[2][1] * f[1] + rot[2][2] * f[2]
    add = [
        r0,
        r1,
        r2,
        rot[0][0] * f[3] + rot[0][1] * f[4] + rot[0][2] * f[5] + pos[1] * r2 - pos[2] * r1,
        rot[1][0] * f[3] + rot[1][1] * f[4] + rot[1][2] * f[5] + pos[2] * r0 - pos[0] * r2,
        rot[2][0] * f[3] + rot[2][1] * f[4] + rot[2][2] * f[5] + pos[0] * r1 - pos[1] * r0,
    ]
    if out is None:
        return add
    return [out[a] + add[a] for a in range(6)]


def _matvec6(inertia, x):
    """inertia (6 x 6 floats) x, summed left to right from 0.0 as the kernels do."""
    out = []
    for a in range(6):
        s = inertia[a][0] * x[0]
        for b in range(1, 6):
            s = s + inertia[a][b] * x[b]
        out.append(s)
    return out


def _body_force(inertia, acc, vel):
    """I a + v x* (I v) (:func:`hydroarm.model.dynamics.tree_kernels.body_force`)."""
    out = _matvec6(inertia, acc)
    sc = _matvec6(inertia, vel)
    w0, w1, w2 = vel[3], vel[4], vel[5]
    return [
        out[0] + (w1 * sc[2] - w2 * sc[1]),
        out[1] + (w2 * sc[0] - w0 * sc[2]),
        out[2] + (w0 * sc[1] - w1 * sc[0]),
        out[3] + (w1 * sc[5] - w2 * sc[4] + vel[1] * sc[2] - vel[2] * sc[1]),
        out[4] + (w2 * sc[3] - w0 * sc[5] + vel[2] * sc[0] - vel[0] * sc[2]),
        out[5] + (w0 * sc[4] - w1 * sc[3] + vel[0] * sc[1] - vel[1] * sc[0]),
    ]


def _add_to_world(inertia, rot, p, out):
    """out + X^T inertia X (:func:`hydroarm.model.arm.fast_kernels._add_to_world`), 6 x 6 lists."""
    sc = []
    for a in range(6):
        row = [inertia[a][0] * rot[b][0] + inertia[a][1] * rot[b][1] + inertia[a][2] * rot[b][2] for b in range(3)]
        row += [inertia[a][3] * rot[b][0] + inertia[a][4] * rot[b][1] + inertia[a][5] * rot[b][2] for b in range(3)]
        l0, l1, l2 = row[0], row[1], row[2]
        row[3] = row[3] + -(l1 * p[2] - l2 * p[1])
        row[4] = row[4] + -(l2 * p[0] - l0 * p[2])
        row[5] = row[5] + -(l0 * p[1] - l1 * p[0])
        sc.append(row)
    out = [list(r) for r in out]
    for b in range(6):
        s = [rot[a][0] * sc[0][b] + rot[a][1] * sc[1][b] + rot[a][2] * sc[2][b] for a in range(3)]
        t = [rot[a][0] * sc[3][b] + rot[a][1] * sc[4][b] + rot[a][2] * sc[5][b] for a in range(3)]
        out[0][b] = out[0][b] + s[0]
        out[1][b] = out[1][b] + s[1]
        out[2][b] = out[2][b] + s[2]
        out[3][b] = out[3][b] + (t[0] + (p[1] * s[2] - p[2] * s[1]))
        out[4][b] = out[4][b] + (t[1] + (p[2] * s[0] - p[0] * s[2]))
        out[5][b] = out[5][b] + (t[2] + (p[0] * s[1] - p[1] * s[0]))
    return out


# --- the passes -------------------------------------------------------------------------------------


def _forward(arm: _Arm, q, v, jnp):
    """Placements rot/pos, world rotations, twists, velocity-product accelerations per body."""
    nj = arm.nj
    eye = [[1.0 if a == b else 0.0 for b in range(3)] for a in range(3)]
    rot, pos, rot_world = [eye] + [None] * (nj - 1), [[0.0] * 3] + [None] * (nj - 1), [eye] + [None] * (nj - 1)
    vel, acc = [[0.0] * 6] + [None] * (nj - 1), [[0.0] * 6] + [None] * (nj - 1)
    for i in range(1, nj):
        par = arm.parents[i]
        rj = _rotation(arm.axes[i], q[i - 1], jnp)
        pr = arm.place_rotation[i]
        pos[i] = arm.place_translation[i]
        rot[i] = [[pr[a][0] * rj[0][b] + pr[a][1] * rj[1][b] + pr[a][2] * rj[2][b] for b in range(3)] for a in range(3)]
        rw = rot_world[par]
        rot_world[i] = [[rw[a][0] * rot[i][0][b] + rw[a][1] * rot[i][1][b] + rw[a][2] * rot[i][2][b] for b in range(3)]
                        for a in range(3)]  # fmt: skip
        if par == 0:  # the root is at rest: X 0 = 0 exactly
            vi, ai = [0.0] * 6, [0.0] * 6
        else:
            vi, ai = _motion_to_child(rot[i], pos[i], vel[par]), _motion_to_child(rot[i], pos[i], acc[par])
        s0, s1, s2 = arm.axes[i][0] * v[i - 1], arm.axes[i][1] * v[i - 1], arm.axes[i][2] * v[i - 1]
        vi = vi[:3] + [vi[3] + s0, vi[4] + s1, vi[5] + s2]
        ai = [
            ai[0] + (vi[1] * s2 - vi[2] * s1),
            ai[1] + (vi[2] * s0 - vi[0] * s2),
            ai[2] + (vi[0] * s1 - vi[1] * s0),
            ai[3] + (vi[4] * s2 - vi[5] * s1),
            ai[4] + (vi[5] * s0 - vi[3] * s2),
            ai[5] + (vi[3] * s1 - vi[4] * s0),
        ]
        vel[i], acc[i] = vi, ai
    return rot, pos, rot_world, vel, acc


def _body_forces(arm: _Arm, rot_world, vel, acc):
    """The rigid RNEA's body forces ``I (a + a_g) + v x* I v``."""
    g0, g1, g2 = arm.gravity
    force = [[0.0] * 6]
    for i in range(1, arm.nj):
        rw = rot_world[i]
        tmp = [acc[i][a] - (rw[0][a] * g0 + rw[1][a] * g1 + rw[2][a] * g2) for a in range(3)] + acc[i][3:]
        force.append(_body_force(arm.rigid[i], tmp, vel[i]))
    return force


def _cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _drag_pieces(arm, k, an, bn, split, jnp):
    """The constant-C_d drag's point forces and their points over both pieces of the cylinder
    (:func:`hydroarm.model.water.effects._drag_piece`), the Gauss points vectorised: lists
    (f0, f1, f2, r0, r1, r2) of (pieces x points) arrays, in the kernel's summation order."""
    length, coefficient = arm.table[k][LENGTH], arm.table[k][DRAG]
    inside = (split > 0.0) & (split < length)
    cut = jnp.where(inside, split, length)
    p0, e = arm.start[k], arm.axis[k]
    out = []
    for s0, s1 in ((0.0, cut), (cut, length)):  # one piece [0, L] and an empty one when not inside
        width = s1 - s0
        s = s0 + width * arm.nodes
        weight = arm.weights
        v0, v1, v2 = an[0] + s * bn[0], an[1] + s * bn[1], an[2] + s * bn[2]
        speed = jnp.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        scale = -coefficient * width * weight * speed
        f0, f1, f2 = scale * v0, scale * v1, scale * v2
        r0, r1, r2 = p0[0] + s * e[0], p0[1] + s * e[1], p0[2] + s * e[2]
        out.append((f0, f1, f2, r0, r1, r2))
    return out


def _added_mass_wrench(m_a, length, p, e, om, vel0, velr, dl, da):
    """-int m_a G^T P a ds (:func:`hydroarm.model.water.effects._added_mass_wrench`), 6 list."""
    r0, r1, r2 = p
    e0, e1, e2 = e
    w0, w1, w2 = om
    p0, p1, p2 = vel0
    q0, q1, q2 = velr
    al0, al1, al2 = da
    x0, x1, x2 = al1 * r2 - al2 * r1, al2 * r0 - al0 * r2, al0 * r1 - al1 * r0
    y0, y1, y2 = w1 * p2 - w2 * p1, w2 * p0 - w0 * p2, w0 * p1 - w1 * p0
    d0, d1, d2 = dl[0] + x0 + y0, dl[1] + x1 + y1, dl[2] + x2 + y2
    x0, x1, x2 = al1 * e2 - al2 * e1, al2 * e0 - al0 * e2, al0 * e1 - al1 * e0
    y0, y1, y2 = w1 * q2 - w2 * q1, w2 * q0 - w0 * q2, w0 * q1 - w1 * q0
    k0, k1, k2 = x0 + y0, x1 + y1, x2 + y2
    l1, l2, l3 = length, 0.5 * length * length, length * length * length / 3.0
    g0, g1, g2 = l1 * d0 + l2 * k0, l1 * d1 + l2 * k1, l1 * d2 + l2 * k2
    h0, h1, h2 = l2 * d0 + l3 * k0, l2 * d1 + l3 * k1, l2 * d2 + l3 * k2
    along = g0 * e0 + g1 * e1 + g2 * e2
    g0, g1, g2 = -m_a * (g0 - along * e0), -m_a * (g1 - along * e1), -m_a * (g2 - along * e2)
    along = h0 * e0 + h1 * e1 + h2 * e2
    h0, h1, h2 = -m_a * (h0 - along * e0), -m_a * (h1 - along * e1), -m_a * (h2 - along * e2)
    return [g0, g1, g2, r1 * g2 - r2 * g1 + (e1 * h2 - e2 * h1), r2 * g0 - r0 * g2 + (e2 * h0 - e0 * h2),
            r0 * g1 - r1 * g0 + (e0 * h1 - e1 * h0)]  # fmt: skip


def _kirchhoff_wrench(m_a, length, p, e, om, vel0, velr):
    """Kirchhoff's addition to the velocity term, closed form
    (:func:`hydroarm.model.water.effects._kirchhoff_wrench`), 6 list."""
    e0, e1, e2 = e
    om0, om1, om2 = om
    a0, a1, a2 = vel0
    b0, b1, b2 = velr
    ex0, ex1, ex2 = om1 * e2 - om2 * e1, om2 * e0 - om0 * e2, om0 * e1 - om1 * e0
    turn0, turn1 = -(a0 * ex0 + a1 * ex1 + a2 * ex2), -(b0 * ex0 + b1 * ex1 + b2 * ex2)
    axial0, axial1 = e0 * a0 + e1 * a1 + e2 * a2, e0 * b0 + e1 * b1 + e2 * b2
    l1, l2, l3 = length, 0.5 * length * length, length * length * length / 3.0
    turn_1, axial_1 = turn0 * l1 + turn1 * l2, axial0 * l1 + axial1 * l2
    axial_s = axial0 * l2 + axial1 * l3
    f0 = -m_a * (turn_1 * e0 - axial_1 * ex0)
    f1 = -m_a * (turn_1 * e1 - axial_1 * ex1)
    f2 = -m_a * (turn_1 * e2 - axial_1 * ex2)
    r0, r1, r2 = p
    k0, k1, k2 = e1 * ex2 - e2 * ex1, e2 * ex0 - e0 * ex2, e0 * ex1 - e1 * ex0
    c0 = m_a * (axial_1 * (a1 * e2 - a2 * e1) + axial_s * (b1 * e2 - b2 * e1))
    c1 = m_a * (axial_1 * (a2 * e0 - a0 * e2) + axial_s * (b2 * e0 - b0 * e2))
    c2 = m_a * (axial_1 * (a0 * e1 - a1 * e0) + axial_s * (b0 * e1 - b1 * e0))
    return [f0, f1, f2, r1 * f2 - r2 * f1 + m_a * axial_s * k0 + c0, r2 * f0 - r0 * f2 + m_a * axial_s * k1 + c1,
            r0 * f1 - r1 * f0 + m_a * axial_s * k2 + c2]  # fmt: skip


def _add_wrench(out, r, f):
    return [out[0] + f[0], out[1] + f[1], out[2] + f[2], out[3] + (r[1] * f[2] - r[2] * f[1]),
            out[4] + (r[2] * f[0] - r[0] * f[2]), out[5] + (r[0] * f[1] - r[1] * f[0])]  # fmt: skip


def _cylinder(arm: _Arm, k, w, vel, acc, rot_world, flow_world, jnp):
    """Cylinder k's water wrench added to its body's ``w`` (6 list): drag, axial drag, added
    mass, buoyancy in :func:`hydroarm.model.water.effects.cylinder_water`'s order."""
    table, p, e = arm.table[k], arm.start[k], arm.axis[k]
    om, dl, da = vel[3:], acc[:3], acc[3:]
    up = rot_world[2]
    vel0 = [vel[i] + c for i, c in enumerate(_cross(om, p))]
    velr = _cross(om, e)
    flow = [rot_world[0][i] * flow_world[0] + rot_world[1][i] * flow_world[1] + rot_world[2][i] * flow_world[2]
            for i in range(3)]  # fmt: skip
    if arm.drag and table[DRAG] > 0.0:
        an = [vel0[i] - flow[i] for i in range(3)]
        along = an[0] * e[0] + an[1] * e[1] + an[2] * e[2]
        an = [an[i] - along * e[i] for i in range(3)]
        along = velr[0] * e[0] + velr[1] * e[1] + velr[2] * e[2]
        bn = [velr[i] - along * e[i] for i in range(3)]
        bb = bn[0] * bn[0] + bn[1] * bn[1] + bn[2] * bn[2]
        dot = an[0] * bn[0] + an[1] * bn[1] + an[2] * bn[2]
        split = jnp.where(bb > 0.0, -dot / jnp.where(bb > 0.0, bb, 1.0), -1.0)
        for f0, f1, f2, r0, r1, r2 in _drag_pieces(arm, k, an, bn, split, jnp):
            for m in range(arm.nodes.size):
                w = _add_wrench(w, (r0[..., m], r1[..., m], r2[..., m]), (f0[..., m], f1[..., m], f2[..., m]))
    if arm.axial and table[AXIAL] > 0.0:
        along = (vel0[0] - flow[0]) * e[0] + (vel0[1] - flow[1]) * e[1] + (vel0[2] - flow[2]) * e[2]
        scale = -table[AXIAL] * jnp.abs(along) * along
        w = _add_wrench(w, [p[i] + 0.0 * e[i] for i in range(3)], [scale * e[0], scale * e[1], scale * e[2]])
    if arm.added_mass and table[MASS] > 0.0:
        wrench = _added_mass_wrench(table[MASS], table[LENGTH], p, e, om, vel0, velr, dl, da)
        w = [w[a] + wrench[a] for a in range(6)]
        if arm.kirchhoff:
            wrench = _kirchhoff_wrench(table[MASS], table[LENGTH], p, e, om, vel0, velr)
            w = [w[a] + wrench[a] for a in range(6)]
    if arm.buoyancy:
        s, lift = 0.5 * table[LENGTH], table[BUOYANCY]
        w = _add_wrench(w, [p[i] + s * e[i] for i in range(3)], [lift * up[0], lift * up[1], lift * up[2]])
    return w


def _backward(arm: _Arm, rot, pos, force, water):
    """RNEA's backward pass: nle and the water's generalised force, (n,) lists."""
    n = arm.n
    force, water = list(force), list(water)
    nle, water_force = [None] * n, [None] * n
    for i in range(arm.nj - 1, 0, -1):
        par = arm.parents[i]
        a0, a1, a2 = arm.axes[i]
        nle[i - 1] = a0 * force[i][3] + a1 * force[i][4] + a2 * force[i][5]
        water_force[i - 1] = a0 * water[i][3] + a1 * water[i][4] + a2 * water[i][5]
        if par > 0:
            force[par] = _force_to_parent(rot[i], pos[i], force[i], force[par])
            water[par] = _force_to_parent(rot[i], pos[i], water[i], water[par])
    return nle, water_force


def _crba(arm: _Arm, rot, pos):
    """M + M_A (n x n lists; :func:`hydroarm.model.arm.fast_kernels.crba`)."""
    n = arm.n
    mass = [[None] * n for _ in range(n)]
    composite = [None] + [arm.total[i] for i in range(1, arm.nj)]
    for i in range(arm.nj - 1, 0, -1):
        par, k = arm.parents[i], i - 1
        a0, a1, a2 = arm.axes[i]
        c = composite[i]
        tmp = [c[a][3] * a0 + c[a][4] * a1 + c[a][5] * a2 for a in range(6)]
        mass[k][k] = a0 * tmp[3] + a1 * tmp[4] + a2 * tmp[5]
        j = i
        while arm.parents[j] > 0:
            tmp = _force_to_parent(rot[j], pos[j], tmp, None)
            j = arm.parents[j]
            value = arm.axes[j][0] * tmp[3] + arm.axes[j][1] * tmp[4] + arm.axes[j][2] * tmp[5]
            mass[j - 1][k] = value
            mass[k][j - 1] = value
        if par > 0:
            composite[par] = _add_to_world(composite[i], rot[i], pos[i], composite[par])
    return mass


def _cholesky_solve(a, b, jnp):
    """a^-1 b, a symmetric positive definite (n x n lists), unrolled
    (:func:`hydroarm.model.dynamics.fixed_order.cholesky_solve_into`)."""
    n = len(b)
    low = [[None] * n for _ in range(n)]
    for j in range(n):
        s = a[j][j]
        for k in range(j):
            s = s - low[j][k] * low[j][k]
        d = jnp.sqrt(s)
        low[j][j] = d
        for i in range(j + 1, n):
            s = a[i][j]
            for k in range(j):
                s = s - low[i][k] * low[j][k]
            low[i][j] = s / d
    out = [None] * n
    for i in range(n):
        s = b[i]
        for k in range(i):
            s = s - low[i][k] * out[k]
        out[i] = s / low[i][i]
    for i in range(n - 1, -1, -1):
        s = out[i]
        for k in range(i + 1, n):
            s = s - low[k][i] * out[k]
        out[i] = s / low[i][i]
    return out


def _mass_times(arm: _Arm, rot, pos, qdd):
    """M(q) qdd, the rigid body's (:func:`hydroarm.model.arm.fast_kernels.mass_times`)."""
    acc, force = [[0.0] * 6] + [None] * arm.n, [None] * arm.nj
    for i in range(1, arm.nj):
        par = arm.parents[i]
        ai = [0.0] * 6 if par == 0 else _motion_to_child(rot[i], pos[i], acc[par])
        acc[i] = ai[:3] + [ai[3 + a] + arm.axes[i][a] * qdd[i - 1] for a in range(3)]
        force[i] = _matvec6(arm.rigid[i], acc[i])
    out = [None] * arm.n
    for i in range(arm.nj - 1, 0, -1):
        par = arm.parents[i]
        out[i - 1] = arm.axes[i][0] * force[i][3] + arm.axes[i][1] * force[i][4] + arm.axes[i][2] * force[i][5]
        if par > 0:
            force[par] = _force_to_parent(rot[i], pos[i], force[i], force[par])
    return out


def evaluate(arm: _Arm, t, q, v, tau, jnp):
    """``(q'' (n,), disturbance (n,))`` of one copy at (t, q, v) under tau: the numba
    :func:`~hydroarm.model.arm.fast_kernels.evaluate` (constant-C_d drag: no separate drag term)."""
    n = arm.n
    cj, cw = arm.current_joint, arm.current_world
    joint_acceleration = cj[0] * jnp.cos(cj[1] * t + cj[2])
    wave = jnp.sin(cw[6] * t + cw[7])
    flow = [cw[i] + cw[3 + i] * wave for i in range(3)]
    qs, vs, taus = [q[i] for i in range(n)], [v[i] for i in range(n)], [tau[i] for i in range(n)]
    rot, pos, rot_world, vel, acc = _forward(arm, qs, vs, jnp)
    force = _body_forces(arm, rot_world, vel, acc)
    water = [[0.0] * 6 for _ in range(arm.nj)]
    if arm.drag or arm.axial or arm.added_mass or arm.buoyancy:
        for k, i in enumerate(arm.joint_ids):
            water[i] = _cylinder(arm, k, water[i], vel[i], acc[i], rot_world[i], flow, jnp)
    nle, water_force = _backward(arm, rot, pos, force, water)
    mass = _crba(arm, rot, pos)
    applied = list(taus)
    friction = None
    if arm.friction_on:
        coulomb, breakaway, viscous, stribeck, width = arm.friction
        ratio = v / stribeck
        level = coulomb + (breakaway - coulomb) * jnp.exp(-ratio * ratio)
        friction = level * jnp.tanh(v / width) + viscous * v
        applied = [applied[i] - friction[i] for i in range(n)]
    rhs = [applied[i] - nle[i] + water_force[i] - arm.uniform * vs[i] for i in range(n)]
    qdd = _cholesky_solve(mass, rhs, jnp)
    qdd = [qdd[i] + joint_acceleration[i] for i in range(n)]
    dist = _mass_times(arm, rot, pos, qdd)
    dist = [dist[a] + nle[a] - applied[a] for a in range(n)]
    if friction is not None:
        dist = [dist[a] - friction[a] for a in range(n)]
    return jnp.stack(qdd), jnp.stack(dist)


def make_period(constants: dict, steps: int, h: float):
    """``period(t (N,), x (N, 2n), tau (N, n)) -> (x_next (N, 2n), disturbance (N, n), first
    stage's disturbance (N, n))``, jitted: ``steps`` RK4 steps of h (s) per copy, the numba
    :func:`~hydroarm.model.arm.fast_kernels.batch_step_kernel`'s result (NaN rows for copies
    that stopped being finite). Turns on JAX's float64 (``jax_enable_x64``)."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    from jax import lax

    arm = _Arm(constants)
    n, steps, h = arm.n, int(steps), float(h)
    if steps < 1 or not h > 0.0:
        raise ValueError(f"fast_jax: steps = {steps} must be >= 1 and h = {h} > 0")

    def one_copy(t, x, tau):
        def stage_body(stage, carry, time, state):
            xs, ks, dists = carry
            stage_time = jnp.where(stage == 0, time, jnp.where(stage == 3, time + h, time + 0.5 * h))
            acc, dist = evaluate(arm, stage_time, xs[:n], xs[n:], tau, jnp)
            k = jnp.concatenate([xs[n:], acc])
            scale = jnp.where(stage == 2, h, 0.5 * h)
            return state + scale * k, ks.at[stage].set(k), dists.at[stage].set(dist)

        def step_body(step, carry):
            state, time, average, start, finite = carry
            init = (state, jnp.zeros((4, 2 * n)), jnp.zeros((4, n)))
            _, ks, d = lax.fori_loop(0, 4, lambda s, c: stage_body(s, c, time, state), init)
            state = state + (h / 6.0) * (ks[0] + 2.0 * ks[1] + 2.0 * ks[2] + ks[3])
            average = average + (d[0] + 2.0 * d[1] + 2.0 * d[2] + d[3])
            finite = finite & jnp.all(jnp.isfinite(state))
            start = jnp.where(step == 0, d[0], start)
            return state, time + h, average, start, finite

        init = (x, t, jnp.zeros(n), jnp.zeros(n), jnp.array(True))
        state, _, average, start, finite = lax.fori_loop(0, steps, step_body, init)
        average = average / (6.0 * steps)
        return jnp.where(finite, state, jnp.nan), jnp.where(finite, average, jnp.nan), jnp.where(finite, start, jnp.nan)

    return jax.jit(jax.vmap(one_copy))


__all__ = ["REQUIRED", "check_constants", "evaluate", "make_period"]
