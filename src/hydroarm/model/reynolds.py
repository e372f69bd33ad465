"""Morison drag with a Reynolds-dependent coefficient: a water a constant-C_d learner does not share.

With ``Water.drag_model = "reynolds"`` the drag coefficient varies along every strip of every
wetted cylinder with the local Reynolds number of the normal flow::

    Re(s) = |v_n(s)| D / nu,      f_d(s) = -1/2 rho C_d(Re(s)) kappa(L/D) D |v_n(s)| v_n(s)

``C_d(Re)``: the steady-flow drag coefficient of a smooth circular cylinder, the curve of
DNV-RP-C205 (Environmental conditions and environmental loads), section 6.7, Fig. 6-6, as points
read from the figure (:data:`LOG_RE`, :data:`CD_SMOOTH`; linear in log10 Re between them, held
constant beyond the ends): about 1.0-1.2 in the subcritical range, the drag crisis near
Re = 3-5e5 (down to about 0.3), then the smooth post-critical value 0.65 by Re = 1e7.
``kappa(L/D)``: the reduction factor of a cylinder of finite length L/D (flow round its free
ends), the same section's table (:data:`ASPECT_RATIO`, :data:`ASPECT_FACTOR`; linear between
entries, 1 for an infinitely long cylinder). The water's own ``cd`` is not used then (a
cylinder's ``cd`` override in the arm file neither): the curve is the drag.

The points are read from a figure: they reproduce its shape (plateau, crisis, recovery), not
three significant digits. The integrand is no longer a polynomial in s times ``|v_n| v_n``, so
each piece between the kink of ``|v_n|`` and the ends is integrated by the water's Gauss-Legendre
rule as before, C_d evaluated at every node.
"""

from __future__ import annotations

import numba
import numpy as np

from hydroarm.model.strips import _apply, forward_kinematics

LOG_RE = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 5.3, 5.5, 5.7, 6.0, 6.5, 7.0])
"""log10 Re of the points of the smooth-cylinder curve."""

CD_SMOOTH = np.array([2.8, 1.4, 1.0, 1.1, 1.2, 1.2, 0.6, 0.3, 0.4, 0.55, 0.65])
"""C_d of a smooth circular cylinder in steady flow at :data:`LOG_RE` (DNV-RP-C205 Fig. 6-6, read
from the figure)."""

ASPECT_RATIO = np.array([2.0, 5.0, 10.0, 20.0, 40.0, 50.0, 100.0, 1e4])
ASPECT_FACTOR = np.array([0.58, 0.62, 0.68, 0.74, 0.82, 0.87, 0.98, 1.0])
"""kappa(L/D), the reduction factor of a finite cylinder's drag (DNV-RP-C205 section 6.7)."""


def drag_coefficient(reynolds: np.ndarray | float) -> np.ndarray:
    """C_d(Re) of a smooth circular cylinder (module docstring); Re <= 0 gives the low-Re end."""
    log_re = np.log10(np.maximum(np.asarray(reynolds, dtype=float), 1e-300))
    return np.interp(log_re, LOG_RE, CD_SMOOTH)


def aspect_factor(length_over_diameter: np.ndarray | float) -> np.ndarray:
    """kappa(L/D) (module docstring); L/D below 2 takes the factor of 2."""
    return np.interp(np.asarray(length_over_diameter, dtype=float), ASPECT_RATIO, ASPECT_FACTOR)


@numba.njit(cache=True)
def _interp(x, xs, ys):  # pragma: no cover - compiled
    if x <= xs[0]:
        return ys[0]
    last = xs.shape[0] - 1
    if x >= xs[last]:
        return ys[last]
    i = 0
    while xs[i + 1] < x:
        i += 1
    w = (x - xs[i]) / (xs[i + 1] - xs[i])
    return ys[i] + w * (ys[i + 1] - ys[i])


@numba.njit(cache=True)
def _piece(s0, s1, a_n, b_n, j0, jr, half_rho_d_kappa, diameter, nu, nodes, weights, log_re, cd, force):
    """Add int_{s0}^{s1} (J0 + s Jr)^T f(s) ds, f = -1/2 rho kappa D C_d(Re) |v_n| v_n."""  # pragma: no cover
    n = force.shape[0]
    width = s1 - s0
    for m in range(nodes.shape[0]):
        s = s0 + width * nodes[m]
        w = width * weights[m]
        v0 = a_n[0] + s * b_n[0]
        v1 = a_n[1] + s * b_n[1]
        v2 = a_n[2] + s * b_n[2]
        speed = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        if speed <= 0.0:
            continue
        coefficient = _interp(np.log10(speed * diameter / nu), log_re, cd)
        scale = -half_rho_d_kappa * coefficient * w * speed
        f0, f1, f2 = scale * v0, scale * v1, scale * v2
        for c in range(n):
            force[c] += (j0[0, c] + s * jr[0, c]) * f0 + (j0[1, c] + s * jr[1, c]) * f1 + (j0[2, c] + s * jr[2, c]) * f2


@numba.njit(cache=True)
def reynolds_drag_kernel(
    q, v, water_velocity, jac,
    parents, placement_rotation, placement_translation, axes, idx_v,
    joint_ids, start, axis, length, support, half_rho_d_kappa, diameters, nu, nodes, weights, log_re, cd,
):  # fmt: skip  # pragma: no cover - compiled
    """The generalised drag force (n,) N m with C_d(Re) along every strip (module docstring).

    Same geometry as :func:`~hydroarm.model.strips.water_terms_kernel` (``J_p(s) = J0 + s Jr``,
    the normal velocity affine in s, the integral split at the kink of ``|v_n|``);
    ``half_rho_d_kappa`` (C,) = 1/2 rho D kappa(L/D), ``diameters`` (C,) m, ``nu`` m^2/s."""
    n = v.shape[0]
    rot, pos = forward_kinematics(q, parents, placement_rotation, placement_translation, axes, idx_v)
    force = np.zeros(n)
    j0 = np.empty((3, n))
    jr = np.empty((3, n))
    p0 = np.empty(3)
    e = np.empty(3)
    zero = np.zeros(3)
    a_n = np.empty(3)
    b_n = np.empty(3)
    for k in range(joint_ids.shape[0]):
        j = joint_ids[k]
        L = length[k]
        _apply(rot[j], pos[j], start[k], p0)
        _apply(rot[j], zero, axis[k], e)
        for c in range(n):
            if support[k, c] != 0.0:
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
        vel0 = np.zeros(3)
        velr = np.zeros(3)
        for i in range(3):
            for c in range(n):
                vel0[i] += j0[i, c] * v[c]
                velr[i] += jr[i, c] * v[c]
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
        d = diameters[k]
        if 0.0 < split < L:
            _piece(0.0, split, a_n, b_n, j0, jr, half_rho_d_kappa[k], d, nu, nodes, weights, log_re, cd, force)
            _piece(split, L, a_n, b_n, j0, jr, half_rho_d_kappa[k], d, nu, nodes, weights, log_re, cd, force)
        else:
            _piece(0.0, L, a_n, b_n, j0, jr, half_rho_d_kappa[k], d, nu, nodes, weights, log_re, cd, force)
    return force


class ReynoldsDrag:
    """The Reynolds-dependent drag of one (arm, water) pair: constant arrays and :meth:`force`."""

    def __init__(self, arm, water, geometry):
        diameters = np.asarray([c.diameter for c in arm.cylinders], dtype=float)
        lengths = np.asarray(geometry.length, dtype=float)
        self.kappa = aspect_factor(lengths / diameters)
        self.half_rho_d_kappa = 0.5 * water.rho * diameters * self.kappa
        self.diameters = diameters
        self.nu = float(water.kinematic_viscosity)
        g = geometry
        self._constants = (
            g.parents, g.placement_rotation, g.placement_translation, g.axes, g.idx_v,
            g.joint_ids, g.start, g.axis, g.length, g.support,
            self.half_rho_d_kappa, self.diameters, self.nu, g.nodes, g.weights, LOG_RE, CD_SMOOTH,
        )  # fmt: skip

    def force(self, q: np.ndarray, v: np.ndarray, water_velocity: np.ndarray, jac: np.ndarray) -> np.ndarray:
        """The drag's generalised force (n,) N m at q, v (n,), the water's velocity (3,) m/s and
        the world joint Jacobian ``jac`` (6, n) at q (Pinocchio's, computed by the caller)."""
        return reynolds_drag_kernel(
            np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(v, dtype=float),
            np.ascontiguousarray(water_velocity, dtype=float), jac, *self._constants,
        )  # fmt: skip
