"""The water's effects on one wetted cylinder, one compiled function each, in any frame.

Every plant evaluates the water cylinder by cylinder through :func:`cylinder_water`: the
fixed-base arm and the floating arm in the world frame from the joint Jacobian
(:func:`hydroarm.model.water.strips.jacobian_frame`: the generalised force on the joints), the fast
vehicle path in the frame of the body that carries the cylinder
(:func:`hydroarm.model.vehicle.fast_kernels.body_frame`: the body wrench about its origin). The
cylinder's kinematics, coefficients and quadrature sit in a *frame*, one 2-D array with the named
rows below (one array, so that the compiled code reads it without reference counting); an
effect reads them and hands its point forces to :func:`project_force` (couples to
:func:`project_couple`), which map them onto the frame's generalised coordinates. Along the
cylinder ``p(s) = p0 + s e`` (s in [0, L]) the velocity is ``vel0 + s velr`` (``velr = omega x
e``, normal to e).

The effects (their physics: :mod:`hydroarm.model.water.morison` and docs/model.md):

* :func:`drag`: Morison ``-1/2 rho C_d D |v_n| v_n`` per length, C_d constant or C_d(Re)
  (:mod:`hydroarm.model.water.reynolds`), the integral split at the kink of ``|v_n|``;
* :func:`axial_drag`: ``-1/2 rho C_a A |u_a| u_a e`` on the whole cylinder, u_a the axial
  velocity relative to the water (the same all along it);
* :func:`added_mass`: ``-rho C_m A a_n`` (Morison) or the Lagrangian of
  ``1/2 int rho C_m A |P u|^2 ds`` (Kirchhoff, :func:`kirchhoff_bias`);
* :func:`buoyancy`: ``rho g V`` up at the midpoint.

A new effect is one switch (a field of :class:`~hydroarm.model.water.strips.Strips` set from
:class:`~hydroarm.model.water.morison.Water`, with its coefficient a column of ``Strips.table``) and one
function here, called from :func:`cylinder_water` (docs/architecture.md, "Where to add").
"""

from __future__ import annotations

import numba
import numpy as np

from hydroarm.model.water.reynolds import interpolate

DRAG_CONSTANT, DRAG_REYNOLDS = 0, 1
"""``Strips.drag_model``: a constant C_d per cylinder, or C_d(Re) along every strip."""

MORISON, KIRCHHOFF = 0, 1
"""``Strips.added_mass_model``: Morison's ``-m_a a_n``, or the energy-consistent Kirchhoff form."""

LENGTH, DRAG, MASS, BUOYANCY, AXIAL, REYNOLDS, DIAMETER = range(7)
"""Columns of ``Strips.table`` (one row per cylinder) and of the frame's ``CYL`` row: length L (m),
1/2 rho C_d D (kg/m^2), rho C_m A (kg/m), rho g V (N), 1/2 rho C_a A (kg/m), 1/2 rho D kappa(L/D)
(kg/m^2, the Reynolds drag's), D (m)."""
COLUMNS = 7

J0, JR, JW, NJ0, NJR = 0, 3, 6, 9, 12
"""Rows of a frame (3 each, one column per generalised velocity; world frames only): the point
Jacobian ``J_p(s) = j0 + s jr``, the link's angular Jacobian ``jw`` (Kirchhoff only), their parts
normal to e ``nj0 + s njr`` (:func:`normal_jacobian`)."""
P0, E, VEL0, VELR, OM, DL, DA, FLOW, UP, AN, BN, BIAS0, BIAS1 = range(15, 28)
"""Rows of a frame holding 3-vectors (columns 0-2): the start point, the unit axis, the point
velocity ``vel0 + s velr``, the link's angular velocity, the velocity-product acceleration
(linear at the frame origin, angular), the water's velocity, the world's +z, and scratch
(:func:`normal_velocity`, :func:`acceleration_bias`)."""
CYL, KIND, NODES, WEIGHTS, CURVE_X, CURVE_Y = range(28, 34)
"""Rows of a frame: the cylinder's ``Strips.table`` row; ``[body (1) or world (0), Gauss points,
curve points, generalised velocities n]``; the Gauss-Legendre rule on [0, 1]; the C_d(Re) curve
(log10 Re, C_d)."""
ROWS = 34


def frame_width(n: int, points: int, curve: int) -> int:
    """Columns of a frame for n generalised velocities, ``points`` Gauss points, a curve of
    ``curve`` points."""
    return max(n, COLUMNS, points, curve, 3)


@numba.njit(cache=True)
def new_frame(n, body, nodes, weights, curve_x, curve_y):  # pragma: no cover - compiled
    """A frame (module docstring) for n generalised velocities (world) or a body twist (body),
    with the quadrature and the C_d(Re) curve filled in."""
    points, curve = nodes.shape[0], curve_x.shape[0]
    frame = np.zeros((ROWS, max(n, COLUMNS, points, curve, 3)))
    frame[KIND, 0] = 1.0 if body else 0.0
    frame[KIND, 1] = points
    frame[KIND, 2] = curve
    frame[KIND, 3] = n
    for m in range(points):
        frame[NODES, m] = nodes[m]
        frame[WEIGHTS, m] = weights[m]
    for m in range(curve):
        frame[CURVE_X, m] = curve_x[m]
        frame[CURVE_Y, m] = curve_y[m]
    frame[UP, 2] = 1.0
    return frame


@numba.njit(cache=True, inline="always")
def project_force(frame, s, f0, f1, f2, out):  # pragma: no cover - compiled
    """Add the generalised force of the point force (f0, f1, f2) at ``p(s)`` to ``out``:
    ``J_p(s)^T f`` (world) or the body wrench ``(f, p(s) x f)`` (body)."""
    if frame[KIND, 0] > 0.0:
        r0, r1, r2 = frame[P0, 0] + s * frame[E, 0], frame[P0, 1] + s * frame[E, 1], frame[P0, 2] + s * frame[E, 2]
        add_wrench(r0, r1, r2, f0, f1, f2, out)
        return
    for c in range(out.shape[0]):
        out[c] += (
            (frame[J0, c] + s * frame[JR, c]) * f0
            + (frame[J0 + 1, c] + s * frame[JR + 1, c]) * f1
            + (frame[J0 + 2, c] + s * frame[JR + 2, c]) * f2
        )


@numba.njit(cache=True, inline="always")
def add_wrench(r0, r1, r2, f0, f1, f2, out):  # pragma: no cover - compiled
    """out (6,) += the wrench ``(f, r x f)`` of the force f at the point r (body frames)."""
    out[0] += f0
    out[1] += f1
    out[2] += f2
    out[3] += r1 * f2 - r2 * f1
    out[4] += r2 * f0 - r0 * f2
    out[5] += r0 * f1 - r1 * f0


@numba.njit(cache=True, inline="always")
def project_couple(frame, c0, c1, c2, out):  # pragma: no cover - compiled
    """Add the generalised force of the couple (c0, c1, c2) on the link to ``out``: ``J_w^T c``."""
    if frame[KIND, 0] > 0.0:
        out[3] += c0
        out[4] += c1
        out[5] += c2
        return
    for c in range(out.shape[0]):
        out[c] += frame[JW, c] * c0 + frame[JW + 1, c] * c1 + frame[JW + 2, c] * c2


@numba.njit(cache=True, inline="always")
def normal_velocity(frame):  # pragma: no cover - compiled
    """``a_n + s b_n`` (rows AN, BN): the velocity relative to the water normal to the axis; returns
    the s where ``|a_n + s b_n|`` is smallest (-1 when b_n = 0)."""
    for i in range(3):
        frame[AN, i] = frame[VEL0, i] - frame[FLOW, i]
    along = frame[AN, 0] * frame[E, 0] + frame[AN, 1] * frame[E, 1] + frame[AN, 2] * frame[E, 2]
    for i in range(3):
        frame[AN, i] -= along * frame[E, i]
    along = frame[VELR, 0] * frame[E, 0] + frame[VELR, 1] * frame[E, 1] + frame[VELR, 2] * frame[E, 2]
    for i in range(3):
        frame[BN, i] = frame[VELR, i] - along * frame[E, i]
    bb = frame[BN, 0] * frame[BN, 0] + frame[BN, 1] * frame[BN, 1] + frame[BN, 2] * frame[BN, 2]
    split = -1.0
    if bb > 0.0:
        split = -(frame[AN, 0] * frame[BN, 0] + frame[AN, 1] * frame[BN, 1] + frame[AN, 2] * frame[BN, 2]) / bb
    return split


@numba.njit(cache=True, inline="always")
def _drag_piece(reynolds, viscosity, s0, s1, frame, out):  # pragma: no cover - compiled
    """Add int_{s0}^{s1} J_p(s)^T f(s) ds to ``out``, f = -c |v_n| v_n, v_n = a_n + s b_n, with
    c = the cylinder's 1/2 rho C_d D, or 1/2 rho D kappa C_d(Re(s)) (``reynolds``, water's
    kinematic ``viscosity`` m^2/s)."""
    a0, a1, a2 = frame[AN, 0], frame[AN, 1], frame[AN, 2]
    b0, b1, b2 = frame[BN, 0], frame[BN, 1], frame[BN, 2]
    constant, per_cd, diameter = frame[CYL, DRAG], frame[CYL, REYNOLDS], frame[CYL, DIAMETER]
    body = frame[KIND, 0] > 0.0
    curve = int(frame[KIND, 2])
    p00, p01, p02 = frame[P0, 0], frame[P0, 1], frame[P0, 2]  # read once: ``out`` may alias ``frame``
    e0, e1, e2 = frame[E, 0], frame[E, 1], frame[E, 2]
    width = s1 - s0
    # body frames sum the wrench in registers (the same additions in the same order as into ``out``)
    w0, w1, w2, w3, w4, w5 = (
        (out[0], out[1], out[2], out[3], out[4], out[5]) if body else (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    )
    for m in range(int(frame[KIND, 1])):
        s = s0 + width * frame[NODES, m]
        weight = frame[WEIGHTS, m]
        v0 = a0 + s * b0
        v1 = a1 + s * b1
        v2 = a2 + s * b2
        speed = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        coefficient = constant
        if reynolds:
            if speed <= 0.0:
                continue
            coefficient = per_cd * interpolate(np.log10(speed * diameter / viscosity), frame, CURVE_X, CURVE_Y, curve)
        if body:  # the fast vehicle path's order of the products (its numbers, bit for bit)
            scale = -coefficient * width * weight * speed
            f0, f1, f2 = scale * v0, scale * v1, scale * v2
            r0, r1, r2 = p00 + s * e0, p01 + s * e1, p02 + s * e2
            w0 += f0
            w1 += f1
            w2 += f2
            w3 += r1 * f2 - r2 * f1
            w4 += r2 * f0 - r0 * f2
            w5 += r0 * f1 - r1 * f0
        else:
            scale = -coefficient * (width * weight) * speed
            project_force(frame, s, scale * v0, scale * v1, scale * v2, out)
    if body:
        out[0], out[1], out[2], out[3], out[4], out[5] = w0, w1, w2, w3, w4, w5


@numba.njit(cache=True, inline="always")
def drag(strips, frame, out):  # pragma: no cover - compiled
    """The Morison drag on the frame's cylinder (module docstring), added to ``out``."""
    reynolds = strips.drag_model == DRAG_REYNOLDS
    coefficient = frame[CYL, REYNOLDS] if reynolds else frame[CYL, DRAG]
    if not coefficient > 0.0:
        return
    split = normal_velocity(frame)
    length = frame[CYL, LENGTH]
    viscosity = strips.viscosity
    if 0.0 < split < length:
        _drag_piece(reynolds, viscosity, 0.0, split, frame, out)
        _drag_piece(reynolds, viscosity, split, length, frame, out)
    else:
        _drag_piece(reynolds, viscosity, 0.0, length, frame, out)


@numba.njit(cache=True, inline="always")
def axial_drag(strips, frame, out):  # pragma: no cover - compiled
    """The axial drag of the frame's cylinder, ``-1/2 rho C_a A |u_a| u_a e`` with
    u_a = (vel0 - flow).e (the same at every point: velr is normal to e), at its start point (any
    axis point has the same moment), added to ``out``."""
    coefficient = frame[CYL, AXIAL]
    if not coefficient > 0.0:
        return
    along = 0.0
    for i in range(3):
        along += (frame[VEL0, i] - frame[FLOW, i]) * frame[E, i]
    scale = -coefficient * abs(along) * along
    project_force(frame, 0.0, scale * frame[E, 0], scale * frame[E, 1], scale * frame[E, 2], out)


@numba.njit(cache=True, inline="always")
def normal_jacobian(frame):  # pragma: no cover - compiled
    """Rows NJ0, NJR: ``nj0 + s njr = (I - e e^T) J_p(s)`` (world frame), for n columns."""
    e0, e1, e2 = frame[E, 0], frame[E, 1], frame[E, 2]
    for c in range(int(frame[KIND, 3])):
        along0 = e0 * frame[J0, c] + e1 * frame[J0 + 1, c] + e2 * frame[J0 + 2, c]
        alongr = e0 * frame[JR, c] + e1 * frame[JR + 1, c] + e2 * frame[JR + 2, c]
        for i in range(3):
            frame[NJ0 + i, c] = frame[J0 + i, c] - frame[E, i] * along0
            frame[NJR + i, c] = frame[JR + i, c] - frame[E, i] * alongr


@numba.njit(cache=True, inline="always")
def acceleration_bias(frame):  # pragma: no cover - compiled
    """Rows BIAS0, BIAS1: ``bias0 + s bias1``, each point's classical acceleration at q'' = 0,
    ``dl + da x p(s) + om x v(s)``."""
    p0, p1, p2 = frame[P0, 0], frame[P0, 1], frame[P0, 2]
    e0, e1, e2 = frame[E, 0], frame[E, 1], frame[E, 2]
    v0, v1, v2 = frame[VEL0, 0], frame[VEL0, 1], frame[VEL0, 2]
    r0, r1, r2 = frame[VELR, 0], frame[VELR, 1], frame[VELR, 2]
    om0, om1, om2 = frame[OM, 0], frame[OM, 1], frame[OM, 2]
    dl0, dl1, dl2 = frame[DL, 0], frame[DL, 1], frame[DL, 2]
    da0, da1, da2 = frame[DA, 0], frame[DA, 1], frame[DA, 2]
    frame[BIAS0, 0] = dl0 + da1 * p2 - da2 * p1 + om1 * v2 - om2 * v1
    frame[BIAS0, 1] = dl1 + da2 * p0 - da0 * p2 + om2 * v0 - om0 * v2
    frame[BIAS0, 2] = dl2 + da0 * p1 - da1 * p0 + om0 * v1 - om1 * v0
    frame[BIAS1, 0] = da1 * e2 - da2 * e1 + om1 * r2 - om2 * r1
    frame[BIAS1, 1] = da2 * e0 - da0 * e2 + om2 * r0 - om0 * r2
    frame[BIAS1, 2] = da0 * e1 - da1 * e0 + om0 * r1 - om1 * r0


@numba.njit(cache=True, inline="always")
def added_mass(strips, frame, mass, bias, force):  # pragma: no cover - compiled
    """The added mass of the frame's cylinder (Morison's ``-m_a a_n`` per length, plus
    :func:`kirchhoff_bias` under the Kirchhoff model).

    World frame: its inertia ``int m_a J^T P J ds`` into the upper triangle of ``mass`` (skipped
    when ``mass`` is empty) and its velocity term ``h_A = int m_a J^T P a(s) ds`` into ``bias``
    (a the classical acceleration at q'' = 0; the force is ``-M_A q'' - h_A``), by the cylinder's
    Gauss rule. Body frame: the inertia is constant there (built once, in the rigid body's), and
    the force of the velocity term, ``-h_A`` as a body wrench, goes into ``force`` beside the
    other effects; the integrand being a polynomial in s, its integral is taken in closed form
    (the fast vehicle path's arithmetic, kept bit for bit)."""
    m_a = frame[CYL, MASS]
    if not m_a > 0.0:
        return
    length = frame[CYL, LENGTH]
    kirchhoff = strips.added_mass_model == KIRCHHOFF
    if frame[KIND, 0] > 0.0:
        _added_mass_wrench(m_a, length, frame, force)
        if kirchhoff:
            _kirchhoff_wrench(m_a, length, frame, force)
        return
    acceleration_bias(frame)
    coefficient = m_a * length
    normal_jacobian(frame)
    n = bias.shape[0]
    b00, b01, b02 = frame[BIAS0, 0], frame[BIAS0, 1], frame[BIAS0, 2]
    b10, b11, b12 = frame[BIAS1, 0], frame[BIAS1, 1], frame[BIAS1, 2]
    with_inertia = mass.shape[0] > 0
    for m in range(int(frame[KIND, 1])):
        s = length * frame[NODES, m]
        w = coefficient * frame[WEIGHTS, m]
        for a in range(n):
            na0 = frame[NJ0, a] + s * frame[NJR, a]
            na1 = frame[NJ0 + 1, a] + s * frame[NJR + 1, a]
            na2 = frame[NJ0 + 2, a] + s * frame[NJR + 2, a]
            bias[a] += w * (na0 * (b00 + s * b10) + na1 * (b01 + s * b11) + na2 * (b02 + s * b12))
            if with_inertia:
                for b in range(a, n):
                    mass[a, b] += w * (
                        na0 * (frame[NJ0, b] + s * frame[NJR, b])
                        + na1 * (frame[NJ0 + 1, b] + s * frame[NJR + 1, b])
                        + na2 * (frame[NJ0 + 2, b] + s * frame[NJR + 2, b])
                    )
    if kirchhoff:
        kirchhoff_bias(frame, coefficient, bias)


@numba.njit(cache=True, inline="always")
def _added_mass_wrench(m_a, length, frame, out):  # pragma: no cover - compiled
    """Body frame: add the body wrench ``-int m_a G(s)^T P a(s) ds`` to ``out`` (6,), a(s) = d + s k
    the classical acceleration at q'' = 0 (d at the start point, k its rate along s), in closed
    form with the moments ``int 1, s, s^2 ds`` = L, L^2/2, L^3/3."""
    r0, r1, r2 = frame[P0, 0], frame[P0, 1], frame[P0, 2]
    e0, e1, e2 = frame[E, 0], frame[E, 1], frame[E, 2]
    w0, w1, w2 = frame[OM, 0], frame[OM, 1], frame[OM, 2]
    p0, p1, p2 = frame[VEL0, 0], frame[VEL0, 1], frame[VEL0, 2]
    q0, q1, q2 = frame[VELR, 0], frame[VELR, 1], frame[VELR, 2]
    al0, al1, al2 = frame[DA, 0], frame[DA, 1], frame[DA, 2]
    x0, x1, x2 = al1 * r2 - al2 * r1, al2 * r0 - al0 * r2, al0 * r1 - al1 * r0
    y0, y1, y2 = w1 * p2 - w2 * p1, w2 * p0 - w0 * p2, w0 * p1 - w1 * p0
    d0, d1, d2 = frame[DL, 0] + x0 + y0, frame[DL, 1] + x1 + y1, frame[DL, 2] + x2 + y2  # acceleration at s = 0
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


@numba.njit(cache=True, inline="always")
def _kirchhoff_wrench(m_a, length, frame, out):  # pragma: no cover - compiled
    """Body frame: add the body wrench of :func:`kirchhoff_bias`'s force (``-h_A``'s Kirchhoff
    part) to ``out`` (6,) in closed form, as :func:`_added_mass_wrench` does Morison's. With
    u(s) = u0 + s u_r, the turn ``e.(om x u)`` and the axial ``e.u`` are linear in s, the force
    per length ``-m_a (turn e - axial (om x e))`` too, its moment about the body's origin and the
    couple ``m_a axial (u x e)`` quadratic: their integrals over [0, L] are sums of the moments
    ``int 1, s, s^2 ds`` = L, L^2/2, L^3/3 (the Gauss rule gives the same to round-off with two
    points or more: the cylinder's drag points; with one it is the midpoint rule's approximation,
    which the body frame replaces by the integral)."""
    e0, e1, e2 = frame[E, 0], frame[E, 1], frame[E, 2]
    om0, om1, om2 = frame[OM, 0], frame[OM, 1], frame[OM, 2]
    a0, a1, a2 = frame[VEL0, 0], frame[VEL0, 1], frame[VEL0, 2]
    b0, b1, b2 = frame[VELR, 0], frame[VELR, 1], frame[VELR, 2]
    ex0, ex1, ex2 = om1 * e2 - om2 * e1, om2 * e0 - om0 * e2, om0 * e1 - om1 * e0  # om x e
    # turn = e.(om x u) = u.(e x om) = -u.(om x e); axial = e.u (each at s = 0 and its rate)
    turn0, turn1 = -(a0 * ex0 + a1 * ex1 + a2 * ex2), -(b0 * ex0 + b1 * ex1 + b2 * ex2)
    axial0, axial1 = e0 * a0 + e1 * a1 + e2 * a2, e0 * b0 + e1 * b1 + e2 * b2
    l1, l2, l3 = length, 0.5 * length * length, length * length * length / 3.0
    turn_1, axial_1 = turn0 * l1 + turn1 * l2, axial0 * l1 + axial1 * l2  # int f ds
    axial_s = axial0 * l2 + axial1 * l3  # int s axial ds
    f0 = -m_a * (turn_1 * e0 - axial_1 * ex0)
    f1 = -m_a * (turn_1 * e1 - axial_1 * ex1)
    f2 = -m_a * (turn_1 * e2 - axial_1 * ex2)
    # the force's moment: p(s) x f(s) with p = r + s e, f = F0 + s F1: r x int f + e x int s f,
    # and e x int s f = m_a axial_s (e x (om x e)) (e x e = 0)
    r0, r1, r2 = frame[P0, 0], frame[P0, 1], frame[P0, 2]
    k0, k1, k2 = e1 * ex2 - e2 * ex1, e2 * ex0 - e0 * ex2, e0 * ex1 - e1 * ex0  # e x (om x e)
    # the couple: m_a int axial(s) (u(s) x e) ds = m_a (axial_1 (u0 x e) + axial_s (u_r x e))
    c0 = m_a * (axial_1 * (a1 * e2 - a2 * e1) + axial_s * (b1 * e2 - b2 * e1))
    c1 = m_a * (axial_1 * (a2 * e0 - a0 * e2) + axial_s * (b2 * e0 - b0 * e2))
    c2 = m_a * (axial_1 * (a0 * e1 - a1 * e0) + axial_s * (b0 * e1 - b1 * e0))
    out[0] += f0
    out[1] += f1
    out[2] += f2
    out[3] += r1 * f2 - r2 * f1 + m_a * axial_s * k0 + c0
    out[4] += r2 * f0 - r0 * f2 + m_a * axial_s * k1 + c1
    out[5] += r0 * f1 - r1 * f0 + m_a * axial_s * k2 + c2


@numba.njit(cache=True, inline="always")
def kirchhoff_bias(frame, coefficient, out):  # pragma: no cover - compiled
    """What the Kirchhoff added mass adds to Morison's velocity term, into ``out``.

    The Lagrangian of ``T_A = 1/2 int m_a |P u|^2 ds`` (u the point's velocity relative to still
    water, P = I - e e^T) is, per link, Kirchhoff's equations for the constant body inertia
    ``M_b = int m_a G^T P G ds``; per point the force is Morison's ``-m_a P a`` plus
    ``-m_a (e (e.(om x u)) - (e.u) (om x e))``, and a couple ``m_a (e.u) (u x e)`` per length
    (docs/model.md). So ``h_A`` gains ``int [J_p^T m_a (e (e.(om x u)) - (e.u)(om x e))
    - J_w^T m_a (e.u)(u x e)] ds`` (polynomials of degree <= 2 in s: exact with 2 Gauss points).
    ``coefficient`` = m_a L (its negative adds ``-h_A``, the force). The body frame takes the same
    integrals in closed form (:func:`_kirchhoff_wrench`); this Gauss sum is the world frame's."""
    e0, e1, e2 = frame[E, 0], frame[E, 1], frame[E, 2]
    om0, om1, om2 = frame[OM, 0], frame[OM, 1], frame[OM, 2]
    ex0, ex1, ex2 = om1 * e2 - om2 * e1, om2 * e0 - om0 * e2, om0 * e1 - om1 * e0  # om x e
    length = frame[CYL, LENGTH]
    for m in range(int(frame[KIND, 1])):
        s = length * frame[NODES, m]
        w = coefficient * frame[WEIGHTS, m]
        u0, u1, u2 = (
            frame[VEL0, 0] + s * frame[VELR, 0],
            frame[VEL0, 1] + s * frame[VELR, 1],
            frame[VEL0, 2] + s * frame[VELR, 2],
        )
        turn = e0 * (om1 * u2 - om2 * u1) + e1 * (om2 * u0 - om0 * u2) + e2 * (om0 * u1 - om1 * u0)
        axial = e0 * u0 + e1 * u1 + e2 * u2
        project_force(
            frame, s, w * (turn * e0 - axial * ex0), w * (turn * e1 - axial * ex1), w * (turn * e2 - axial * ex2), out
        )
        scale = -w * axial
        project_couple(
            frame, scale * (u1 * e2 - u2 * e1), scale * (u2 * e0 - u0 * e2), scale * (u0 * e1 - u1 * e0), out
        )


@numba.njit(cache=True, inline="always")
def buoyancy(strips, frame, out):  # pragma: no cover - compiled
    """The buoyancy of the frame's cylinder, ``rho g V`` along the world's +z at its midpoint,
    added to ``out``."""
    lift = frame[CYL, BUOYANCY]
    project_force(frame, 0.5 * frame[CYL, LENGTH], lift * frame[UP, 0], lift * frame[UP, 1], lift * frame[UP, 2], out)


@numba.njit(cache=True, inline="always")
def cylinder_water(strips, frame, mass, bias, force, drag_force):  # pragma: no cover - compiled
    """Every switched-on effect of the water on the frame's cylinder: the drag into
    ``drag_force``, the added mass into ``mass`` and ``bias`` (world frame) or ``force`` (body
    frame; :func:`added_mass`), the others into ``force``. The effects' order is fixed (the
    numbers depend on it). ``strips`` gives the switches and models."""
    if strips.drag:
        drag(strips, frame, drag_force)
    if strips.axial:
        axial_drag(strips, frame, force)
    if strips.added_mass:
        added_mass(strips, frame, mass, bias, force)
    if strips.buoyancy:
        buoyancy(strips, frame, force)
