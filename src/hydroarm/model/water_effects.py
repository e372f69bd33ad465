"""The water's effects on one wetted cylinder, one compiled function each, in any frame.

Every plant evaluates the water cylinder by cylinder through :func:`cylinder_water`: the
fixed-base arm and the floating arm in the world frame from the joint Jacobian
(:func:`hydroarm.model.strips.jacobian_frame`: the generalised force on the joints), the fast
vehicle path in the frame of the body that carries the cylinder
(:func:`hydroarm.model.uvms_fast_kernels.body_frame`: the body wrench about its origin). The
frame is a :data:`StripFrame`; an effect reads the cylinder's kinematics from it and hands its
point forces to :func:`project_force` (and couples to :func:`project_couple`), which map them
onto the frame's generalised coordinates. Along the cylinder ``p(s) = p0 + s e`` (s in [0, L])
the velocity is ``vel0 + s velr`` (``velr = omega x e``, normal to e).

The effects (their physics: :mod:`hydroarm.model.water` and docs/model.md):

* :func:`drag`: Morison ``-1/2 rho C_d D |v_n| v_n`` per length, C_d constant or C_d(Re)
  (:mod:`hydroarm.model.reynolds`), the integral split at the kink of ``|v_n|``;
* :func:`axial_drag`: ``-1/2 rho C_a A |u_a| u_a e`` on the whole cylinder, u_a the axial
  velocity relative to the water (the same all along it);
* :func:`added_mass`: ``-rho C_m A a_n`` (Morison) or the Lagrangian of
  ``1/2 int rho C_m A |P u|^2 ds`` (Kirchhoff, :func:`kirchhoff_bias`);
* :func:`buoyancy`: ``rho g V`` up at the midpoint.

A new effect is one switch (a field of :class:`~hydroarm.model.strips.Strips` set from
:class:`~hydroarm.model.water.Water`) and one function here, called from :func:`cylinder_water`
(docs/architecture.md, "Where to add").
"""

from __future__ import annotations

from collections import namedtuple

import numba
import numpy as np

from hydroarm.model.reynolds import interpolate

DRAG_CONSTANT, DRAG_REYNOLDS = 0, 1
"""``Strips.drag_model``: a constant C_d per cylinder, or C_d(Re) along every strip."""

MORISON, KIRCHHOFF = 0, 1
"""``Strips.added_mass_model``: Morison's ``-m_a a_n``, or the energy-consistent Kirchhoff form."""

StripFrame = namedtuple(
    "StripFrame",
    ["body", "j0", "jr", "jw", "nj0", "njr", "p0", "e", "vel0", "velr", "om", "dl", "da", "flow", "up", "zero",
     "a_n", "b_n", "bias0", "bias1"],
)  # fmt: skip
StripFrame.__doc__ = """One cylinder's kinematics in the frame the water is evaluated in (a workspace).

``body`` False: the world frame, generalised velocity v (n,), ``j0``/``jr`` (3, n) the point
Jacobian ``J_p(s) = j0 + s jr``, ``jw`` (3, n) the link's angular Jacobian (Kirchhoff only),
``nj0``/``njr`` their parts normal to e (:func:`normal_jacobian`). ``body`` True: the frame of
the body carrying the cylinder, generalised velocity its twist (6,), the Jacobians implied
(``[I, -[p]x]``). ``p0``, ``e`` (3,): the start point and unit axis; ``vel0``, ``velr``: the
point velocity ``vel0 + s velr``; ``om``: the link's angular velocity; ``dl``, ``da``: the
velocity-product acceleration (linear at the frame origin, angular); ``flow``: the water's
velocity; ``up``: the world's +z; ``zero`` (3,) zeros; ``a_n``, ``b_n``, ``bias0``, ``bias1``
scratch (:func:`normal_velocity`, :func:`acceleration_bias`). Units SI."""


@numba.njit(cache=True)
def apply_placement(rot, pos, local, out):  # pragma: no cover - compiled
    """out = pos + rot @ local for 3-vectors."""
    for i in range(3):
        out[i] = pos[i] + rot[i, 0] * local[0] + rot[i, 1] * local[1] + rot[i, 2] * local[2]


@numba.njit(cache=True)
def project_force(frame, s, f0, f1, f2, out):  # pragma: no cover - compiled
    """Add the generalised force of the point force (f0, f1, f2) at ``p(s)`` to ``out``:
    ``J_p(s)^T f`` (world) or the body wrench ``(f, p(s) x f)`` (body)."""
    if frame.body:
        p0, e = frame.p0, frame.e
        r0, r1, r2 = p0[0] + s * e[0], p0[1] + s * e[1], p0[2] + s * e[2]
        out[0] += f0
        out[1] += f1
        out[2] += f2
        out[3] += r1 * f2 - r2 * f1
        out[4] += r2 * f0 - r0 * f2
        out[5] += r0 * f1 - r1 * f0
        return
    j0, jr = frame.j0, frame.jr
    for c in range(out.shape[0]):
        out[c] += (j0[0, c] + s * jr[0, c]) * f0 + (j0[1, c] + s * jr[1, c]) * f1 + (j0[2, c] + s * jr[2, c]) * f2


@numba.njit(cache=True)
def project_couple(frame, c0, c1, c2, out):  # pragma: no cover - compiled
    """Add the generalised force of the couple (c0, c1, c2) on the link to ``out``: ``J_w^T c``."""
    if frame.body:
        out[3] += c0
        out[4] += c1
        out[5] += c2
        return
    jw = frame.jw
    for c in range(out.shape[0]):
        out[c] += jw[0, c] * c0 + jw[1, c] * c1 + jw[2, c] * c2


@numba.njit(cache=True)
def normal_velocity(frame):  # pragma: no cover - compiled
    """``a_n + s b_n``: the velocity relative to the water normal to the axis; returns the s
    where ``|a_n + s b_n|`` is smallest (-1 when b_n = 0)."""
    a_n, b_n, e, vel0, velr, flow = frame.a_n, frame.b_n, frame.e, frame.vel0, frame.velr, frame.flow
    for i in range(3):
        a_n[i] = vel0[i] - flow[i]
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
    return split


@numba.njit(cache=True)
def _drag_piece(strips, k, s0, s1, frame, out):  # pragma: no cover - compiled
    """Add int_{s0}^{s1} J_p(s)^T f(s) ds to ``out``, f = -c |v_n| v_n, v_n = a_n + s b_n, with
    c = ``drag_per_length[k]`` or ``reynolds_drag[k] * C_d(Re(s))``."""
    a_n, b_n = frame.a_n, frame.b_n
    nodes, weights = strips.nodes, strips.weights
    reynolds = strips.drag_model == DRAG_REYNOLDS
    width = s1 - s0
    for m in range(nodes.shape[0]):
        s = s0 + width * nodes[m]
        w = width * weights[m]
        v0 = a_n[0] + s * b_n[0]
        v1 = a_n[1] + s * b_n[1]
        v2 = a_n[2] + s * b_n[2]
        speed = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        if reynolds:
            if speed <= 0.0:
                continue
            log_re = np.log10(speed * strips.diameter[k] / strips.viscosity)
            coefficient = strips.reynolds_drag[k] * interpolate(log_re, strips.curve_log_re, strips.curve_cd)
        else:
            coefficient = strips.drag_per_length[k]
        if frame.body:  # the fast vehicle path's order of the products (its numbers, bit for bit)
            scale = -coefficient * width * weights[m] * speed
        else:
            scale = -coefficient * w * speed
        project_force(frame, s, scale * v0, scale * v1, scale * v2, out)


@numba.njit(cache=True)
def drag(strips, k, frame, out):  # pragma: no cover - compiled
    """The Morison drag on cylinder k (module docstring), added to ``out``."""
    coefficient = strips.drag_per_length[k] if strips.drag_model == DRAG_CONSTANT else strips.reynolds_drag[k]
    if not coefficient > 0.0:
        return
    split = normal_velocity(frame)
    length = strips.length[k]
    if 0.0 < split < length:
        _drag_piece(strips, k, 0.0, split, frame, out)
        _drag_piece(strips, k, split, length, frame, out)
    else:
        _drag_piece(strips, k, 0.0, length, frame, out)


@numba.njit(cache=True)
def axial_drag(strips, k, frame, out):  # pragma: no cover - compiled
    """The axial drag of cylinder k, ``-1/2 rho C_a A |u_a| u_a e`` with u_a = (vel0 - flow).e (the
    same at every point: velr is normal to e), at its start point (any axis point has the same
    moment), added to ``out``."""
    coefficient = strips.axial_drag[k]
    if not coefficient > 0.0:
        return
    e, vel0, flow = frame.e, frame.vel0, frame.flow
    along = (vel0[0] - flow[0]) * e[0] + (vel0[1] - flow[1]) * e[1] + (vel0[2] - flow[2]) * e[2]
    scale = -coefficient * abs(along) * along
    project_force(frame, 0.0, scale * e[0], scale * e[1], scale * e[2], out)


@numba.njit(cache=True)
def normal_jacobian(frame):  # pragma: no cover - compiled
    """``nj0 + s njr = (I - e e^T) J_p(s)`` (world frame)."""
    e, j0, jr, nj0, njr = frame.e, frame.j0, frame.jr, frame.nj0, frame.njr
    for c in range(j0.shape[1]):
        along0 = e[0] * j0[0, c] + e[1] * j0[1, c] + e[2] * j0[2, c]
        alongr = e[0] * jr[0, c] + e[1] * jr[1, c] + e[2] * jr[2, c]
        for i in range(3):
            nj0[i, c] = j0[i, c] - e[i] * along0
            njr[i, c] = jr[i, c] - e[i] * alongr


@numba.njit(cache=True)
def acceleration_bias(frame):  # pragma: no cover - compiled
    """``bias0 + s bias1``: each point's classical acceleration at q'' = 0,
    ``dl + da x p(s) + om x v(s)``."""
    p0, e, vel0, velr = frame.p0, frame.e, frame.vel0, frame.velr
    om0, om1, om2 = frame.om[0], frame.om[1], frame.om[2]
    dl0, dl1, dl2 = frame.dl[0], frame.dl[1], frame.dl[2]
    da0, da1, da2 = frame.da[0], frame.da[1], frame.da[2]
    bias0, bias1 = frame.bias0, frame.bias1
    bias0[0] = dl0 + da1 * p0[2] - da2 * p0[1] + om1 * vel0[2] - om2 * vel0[1]
    bias0[1] = dl1 + da2 * p0[0] - da0 * p0[2] + om2 * vel0[0] - om0 * vel0[2]
    bias0[2] = dl2 + da0 * p0[1] - da1 * p0[0] + om0 * vel0[1] - om1 * vel0[0]
    bias1[0] = da1 * e[2] - da2 * e[1] + om1 * velr[2] - om2 * velr[1]
    bias1[1] = da2 * e[0] - da0 * e[2] + om2 * velr[0] - om0 * velr[2]
    bias1[2] = da0 * e[1] - da1 * e[0] + om0 * velr[1] - om1 * velr[0]


@numba.njit(cache=True)
def added_mass(strips, k, frame, mass, bias, force):  # pragma: no cover - compiled
    """The added mass of cylinder k (Morison's ``-m_a a_n`` per length, plus :func:`kirchhoff_bias`
    under the Kirchhoff model).

    World frame: its inertia ``int m_a J^T P J ds`` into the upper triangle of ``mass`` (skipped
    when ``mass`` is empty) and its velocity term ``h_A = int m_a J^T P a(s) ds`` into ``bias``
    (a the classical acceleration at q'' = 0; the force is ``-M_A q'' - h_A``), by the cylinder's
    Gauss rule. Body frame: the inertia is constant there (built once, in the rigid body's), and
    the force of the velocity term, ``-h_A`` as a body wrench, goes into ``force`` beside the
    other effects; the integrand being a polynomial in s, its integral is taken in closed form
    (the fast vehicle path's arithmetic, kept bit for bit)."""
    m_a = strips.mass_per_length[k]
    if not m_a > 0.0:
        return
    length = strips.length[k]
    if frame.body:
        _added_mass_wrench(m_a, length, frame, force)
        if strips.added_mass_model == KIRCHHOFF:
            kirchhoff_bias(strips, k, frame, -m_a * length, force)
        return
    acceleration_bias(frame)
    coefficient = m_a * length
    nodes, weights = strips.nodes, strips.weights
    bias0, bias1 = frame.bias0, frame.bias1
    normal_jacobian(frame)
    nj0, njr = frame.nj0, frame.njr
    n = bias.shape[0]
    for m in range(nodes.shape[0]):
        s = length * nodes[m]
        w = coefficient * weights[m]
        for a in range(n):
            na0 = nj0[0, a] + s * njr[0, a]
            na1 = nj0[1, a] + s * njr[1, a]
            na2 = nj0[2, a] + s * njr[2, a]
            bias[a] += w * (
                na0 * (bias0[0] + s * bias1[0]) + na1 * (bias0[1] + s * bias1[1]) + na2 * (bias0[2] + s * bias1[2])
            )
            if mass.shape[0] > 0:
                for b in range(a, n):
                    mass[a, b] += w * (
                        na0 * (nj0[0, b] + s * njr[0, b])
                        + na1 * (nj0[1, b] + s * njr[1, b])
                        + na2 * (nj0[2, b] + s * njr[2, b])
                    )
    if strips.added_mass_model == KIRCHHOFF:
        kirchhoff_bias(strips, k, frame, coefficient, bias)


@numba.njit(cache=True)
def _added_mass_wrench(m_a, length, frame, out):  # pragma: no cover - compiled
    """Body frame: add the body wrench ``-int m_a G(s)^T P a(s) ds`` to ``out`` (6,), a(s) = d + s k
    the classical acceleration at q'' = 0 (d at the start point, k its rate along s), in closed
    form with the moments ``int 1, s, s^2 ds`` = L, L^2/2, L^3/3."""
    vel, om, e = frame.vel0, frame.om, frame.e
    r0, r1, r2 = frame.p0[0], frame.p0[1], frame.p0[2]
    e0, e1, e2 = e[0], e[1], e[2]
    w0, w1, w2 = om[0], om[1], om[2]
    p0, p1, p2 = vel[0], vel[1], vel[2]
    q0, q1, q2 = frame.velr[0], frame.velr[1], frame.velr[2]
    al0, al1, al2 = frame.da[0], frame.da[1], frame.da[2]
    x0, x1, x2 = al1 * r2 - al2 * r1, al2 * r0 - al0 * r2, al0 * r1 - al1 * r0
    y0, y1, y2 = w1 * p2 - w2 * p1, w2 * p0 - w0 * p2, w0 * p1 - w1 * p0
    d0, d1, d2 = frame.dl[0] + x0 + y0, frame.dl[1] + x1 + y1, frame.dl[2] + x2 + y2  # acceleration at s = 0
    x0, x1, x2 = al1 * e2 - al2 * e1, al2 * e0 - al0 * e2, al0 * e1 - al1 * e0
    y0, y1, y2 = w1 * q2 - w2 * q1, w2 * q0 - w0 * q2, w0 * q1 - w1 * q0
    k0, k1, k2 = x0 + y0, x1 + y1, x2 + y2  # its rate along s
    l1, l2, l3 = length, 0.5 * length * length, length * length * length / 3.0
    g0, g1, g2 = l1 * d0 + l2 * k0, l1 * d1 + l2 * k1, l1 * d2 + l2 * k2
    h0, h1, h2 = l2 * d0 + l3 * k0, l2 * d1 + l3 * k1, l2 * d2 + l3 * k2
    along = g0 * e0 + g1 * e1 + g2 * e2
    g0, g1, g2 = -m_a * (g0 - along * e0), -m_a * (g1 - along * e1), -m_a * (g2 - along * e2)
    along = h0 * e0 + h1 * e1 + h2 * e2
    h0, h1, h2 = -m_a * (h0 - along * e0), -m_a * (h1 - along * e1), -m_a * (h2 - along * e2)
    out[0] += g0
    out[1] += g1
    out[2] += g2
    out[3] += r1 * g2 - r2 * g1 + (e1 * h2 - e2 * h1)
    out[4] += r2 * g0 - r0 * g2 + (e2 * h0 - e0 * h2)
    out[5] += r0 * g1 - r1 * g0 + (e0 * h1 - e1 * h0)


@numba.njit(cache=True)
def kirchhoff_bias(strips, k, frame, coefficient, out):  # pragma: no cover - compiled
    """What the Kirchhoff added mass adds to Morison's velocity term, into ``out``.

    The Lagrangian of ``T_A = 1/2 int m_a |P u|^2 ds`` (u the point's velocity relative to still
    water, P = I - e e^T) is, per link, Kirchhoff's equations for the constant body inertia
    ``M_b = int m_a G^T P G ds``; per point the force is Morison's ``-m_a P a`` plus
    ``-m_a (e (e.(om x u)) - (e.u) (om x e))``, and a couple ``m_a (e.u) (u x e)`` per length
    (docs/model.md). So ``h_A`` gains ``int [J_p^T m_a (e (e.(om x u)) - (e.u)(om x e))
    - J_w^T m_a (e.u)(u x e)] ds`` (polynomials of degree <= 2 in s: exact with 2 Gauss points).
    ``coefficient`` = m_a L (its negative adds ``-h_A``, the force, as the body frame does)."""
    e, vel0, velr = frame.e, frame.vel0, frame.velr
    om0, om1, om2 = frame.om[0], frame.om[1], frame.om[2]
    ex0, ex1, ex2 = om1 * e[2] - om2 * e[1], om2 * e[0] - om0 * e[2], om0 * e[1] - om1 * e[0]  # om x e
    length = strips.length[k]
    nodes, weights = strips.nodes, strips.weights
    for m in range(nodes.shape[0]):
        s = length * nodes[m]
        w = coefficient * weights[m]
        u0, u1, u2 = vel0[0] + s * velr[0], vel0[1] + s * velr[1], vel0[2] + s * velr[2]
        turn = e[0] * (om1 * u2 - om2 * u1) + e[1] * (om2 * u0 - om0 * u2) + e[2] * (om0 * u1 - om1 * u0)
        axial = e[0] * u0 + e[1] * u1 + e[2] * u2
        project_force(
            frame, s, w * (turn * e[0] - axial * ex0), w * (turn * e[1] - axial * ex1), w * (turn * e[2] - axial * ex2),
            out,
        )  # fmt: skip
        scale = -w * axial
        project_couple(frame, scale * (u1 * e[2] - u2 * e[1]), scale * (u2 * e[0] - u0 * e[2]),
                       scale * (u0 * e[1] - u1 * e[0]), out)  # fmt: skip


@numba.njit(cache=True)
def buoyancy(strips, k, frame, out):  # pragma: no cover - compiled
    """The buoyancy of cylinder k, ``rho g V`` along the world's +z at its midpoint, added to ``out``."""
    lift = strips.buoyancy_force[k]
    up = frame.up
    project_force(frame, 0.5 * strips.length[k], lift * up[0], lift * up[1], lift * up[2], out)


@numba.njit(cache=True)
def cylinder_water(strips, k, frame, mass, bias, force, drag_force):  # pragma: no cover - compiled
    """Every switched-on effect of the water on cylinder k, its kinematics in ``frame``: the drag
    into ``drag_force``, the added mass into ``mass`` and ``bias`` (world frame) or ``force``
    (body frame; :func:`added_mass`), the others into ``force``. The effects' order is fixed
    (the numbers depend on it)."""
    if strips.drag:
        drag(strips, k, frame, drag_force)
    if strips.axial:
        axial_drag(strips, k, frame, force)
    if strips.added_mass:
        added_mass(strips, k, frame, mass, bias, force)
    if strips.buoyancy:
        buoyancy(strips, k, frame, force)
