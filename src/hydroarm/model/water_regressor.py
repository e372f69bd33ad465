"""The water's generalised force as a linear regression in a few coefficients per wetted cylinder.

The Morison strip integrals of :mod:`hydroarm.model.water` are linear in three coefficients
of each cylinder k (C cylinders)::

    drag_k      = 1/2 rho C_d,k D_k      (kg/m^2)   on   int J_p^T |v_n| v_n ds
    mass_k      = rho C_m,k A_k          (kg/m)     on   int J_p^T a_n ds
    buoyancy_k  = rho g V_k              (N)        on   J_p(mid)^T e_z

so the water's generalised force (N m, (n,)) at joint state (q, v) and acceleration a is::

    w(q, v, a) = Phi(q, v, a) theta,   theta = [drag_1..C, mass_1..C, buoyancy_1..C]   (3C,)

(the current left out: a state model cannot know it). Column k of each block is the water
kernel of :mod:`hydroarm.model.strips` with unit coefficient on cylinder k alone, so the basis
is the plant's own strip geometry and quadrature (:class:`~hydroarm.model.strips.StripGeometry`):
drag ``f(q, v)``, added mass ``-(M_A,k(q) a + h_A,k(q, v))``, buoyancy ``f(q)``.

:meth:`WaterRegressor.physical` turns theta back into C_d, C_m and the displaced volume V (m^3)
of every cylinder, with the water density and gravity the regressor was built with.
"""

from __future__ import annotations

import numba
import numpy as np
import pinocchio as pin

from hydroarm.model.arm import Arm
from hydroarm.model.strips import StripGeometry, _apply, _drag_piece, forward_kinematics, water_terms_kernel
from hydroarm.model.water import Water

BLOCKS = ("drag", "added_mass", "buoyancy")


class WaterRegressor:
    """The basis ``Phi(q, v, a)`` (n, 3C) of the water on ``arm`` (module docstring).

    ``water``: its density, gravity and quadrature (the coefficients C_d, C_m of it are not
    used: they are what a fit finds). ``n_parameters`` = 3C; ``diameters``, ``areas`` (C,) of
    the wetted cylinders. Owns a Pinocchio workspace: one per thread.
    """

    def __init__(self, arm: Arm, water: Water | None = None):
        self.arm = arm
        self.water = water if water is not None else Water()
        self.n = arm.n_joints
        geometry = StripGeometry(arm, self.water)
        self.geometry = geometry
        self.n_cylinders = c = geometry.joint_ids.shape[0]
        self.n_parameters = 3 * c
        self.diameters = np.asarray([cyl.diameter for cyl in arm.cylinders], dtype=float)
        self.areas = np.asarray([cyl.area for cyl in arm.cylinders], dtype=float)
        chain = (geometry.parents, geometry.placement_rotation, geometry.placement_translation,
                 geometry.axes, geometry.idx_v)  # fmt: skip
        self._per_cylinder = []
        for k in range(c):
            part = slice(k, k + 1)
            self._per_cylinder.append(
                (
                    *chain,
                    geometry.joint_ids[part],
                    geometry.start[part],
                    geometry.axis[part],
                    geometry.length[part],
                    geometry.support[part],
                    np.ones(1),
                    np.ones(1),
                    np.ones(1),
                    geometry.nodes,
                    geometry.weights,
                )  # fmt: skip
            )
        self._constants = (*chain, geometry.joint_ids, geometry.start, geometry.axis, geometry.length,
                           geometry.support)  # fmt: skip
        self.data = arm.create_data()
        self._still = np.zeros(3)

    def terms(self, theta: np.ndarray, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(M_A (n, n), f (n,))`` of theta (3C,) at q, v (n,): the water's force is ``f - M_A a``
        (added-mass inertia apart, ``f`` = drag + buoyancy - h_A), in one pass of the strip kernel;
        every coefficient is clipped at zero first (a drag, added mass or volume is never
        negative; the kernel skips a cylinder whose coefficient is not positive)."""
        n, c = self.n, self.n_cylinders
        q = np.ascontiguousarray(q, dtype=float)
        v = np.ascontiguousarray(v, dtype=float)
        theta = np.maximum(np.asarray(theta, dtype=float), 0.0)
        data = self.data
        pin.computeJointJacobiansTimeVariation(self.arm.model, data, q, v)
        mass, bias, force = water_terms_kernel(
            q, v, self._still, data.J.reshape(6, n), data.dJ.reshape(6, n), *self._constants,
            np.ascontiguousarray(theta[:c]), np.ascontiguousarray(theta[c : 2 * c]),
            np.ascontiguousarray(theta[2 * c :]), self.geometry.nodes, self.geometry.weights, True, True, True,
        )  # fmt: skip
        return mass, force - bias

    def predict(self, theta: np.ndarray, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """``Phi(q, v, a) theta`` (n,) N m (:meth:`terms`: coefficients clipped at zero); equals
        :meth:`basis` @ theta for theta >= 0."""
        mass, rest = self.terms(theta, q, v)
        return rest - mass @ np.asarray(a, dtype=float)

    def basis(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """``Phi`` (n, 3C) at joint state q, v (n,) rad, rad/s and acceleration a (n,) rad/s^2:
        columns ``[drag_1..C, added_mass_1..C, buoyancy_1..C]`` (N m per unit coefficient), in
        one compiled pass (:func:`basis_kernel`; :meth:`basis_reference` is its twin through
        the plant's own kernel, cylinder by cylinder)."""
        n = self.n
        q = np.ascontiguousarray(q, dtype=float)
        v = np.ascontiguousarray(v, dtype=float)
        data = self.data
        pin.computeJointJacobiansTimeVariation(self.arm.model, data, q, v)
        g = self.geometry
        return basis_kernel(
            q, v, np.ascontiguousarray(a, dtype=float), data.J.reshape(6, n), data.dJ.reshape(6, n),
            g.parents, g.placement_rotation, g.placement_translation, g.axes, g.idx_v,
            g.joint_ids, g.start, g.axis, g.length, g.support, g.nodes, g.weights,
        )  # fmt: skip

    def basis_reference(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """:meth:`basis` through :func:`~hydroarm.model.strips.water_terms_kernel`, one cylinder
        and one effect at a time (slow; the tests compare the two)."""
        n, c = self.n, self.n_cylinders
        q = np.ascontiguousarray(q, dtype=float)
        v = np.ascontiguousarray(v, dtype=float)
        a = np.asarray(a, dtype=float)
        data = self.data
        pin.computeJointJacobiansTimeVariation(self.arm.model, data, q, v)
        jac, djac = data.J.reshape(6, n), data.dJ.reshape(6, n)
        phi = np.empty((n, 3 * c))
        for k, constants in enumerate(self._per_cylinder):
            mass, bias, drag = water_terms_kernel(q, v, self._still, jac, djac, *constants, True, True, False)
            phi[:, k] = drag
            phi[:, c + k] = -(mass @ a) - bias
            _, _, buoyancy = water_terms_kernel(q, v, self._still, jac, djac, *constants, False, False, True)
            phi[:, 2 * c + k] = buoyancy
        return phi

    def parameters(self, water: Water) -> np.ndarray:
        """theta (3C,) of ``water`` on this arm (its C_d, C_m, rho, g and the cylinders' volumes;
        an effect switched off gives zeros): what the plant's water is in this basis."""
        geometry = StripGeometry(self.arm, water)
        return np.concatenate([
            geometry.drag_per_length if water.drag else np.zeros(self.n_cylinders),
            geometry.mass_per_length if water.added_mass else np.zeros(self.n_cylinders),
            geometry.buoyancy_force if water.buoyancy else np.zeros(self.n_cylinders),
        ])  # fmt: skip

    def physical(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        """``{"cd", "cm", "volume"}`` (C,) each from theta (3C,): C_d = 2 drag / (rho D),
        C_m = mass / (rho A), V = buoyancy / (rho g) (m^3)."""
        c, w = self.n_cylinders, self.water
        theta = np.asarray(theta, dtype=float)
        volume = theta[2 * c :] / (w.rho * w.gravity) if w.gravity > 0 else np.full(c, np.nan)
        return {
            "cd": 2.0 * theta[:c] / (w.rho * self.diameters),
            "cm": theta[c : 2 * c] / (w.rho * self.areas),
            "volume": volume,
        }


@numba.njit(cache=True)
def basis_kernel(
    q, v, a, jac, djac, parents, placement_rotation, placement_translation, axes, idx_v,
    joint_ids, start, axis, length, support, nodes, weights,
):  # fmt: skip  # pragma: no cover - compiled
    """``Phi`` (n, 3C) in one pass: per cylinder, the strip integrals of
    :func:`~hydroarm.model.strips.water_terms_kernel` with unit coefficients, still water (the
    same operations: drag split at the kink of ``|v_n|``, added mass ``-(M_A,k a + h_A,k)``,
    buoyancy ``J_p(mid)^T e_z``)."""
    n = v.shape[0]
    c_count = joint_ids.shape[0]
    phi = np.zeros((n, 3 * c_count))
    rot, pos = forward_kinematics(q, parents, placement_rotation, placement_translation, axes, idx_v)
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
    column = np.empty(n)
    for k in range(c_count):
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
        vel0 = np.zeros(3)
        velr = np.zeros(3)
        for i in range(3):
            for c in range(n):
                vel0[i] += j0[i, c] * v[c]
                velr[i] += jr[i, c] * v[c]
        # drag, unit coefficient
        for i in range(3):
            a_n[i] = vel0[i]
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
        column[:] = 0.0
        if 0.0 < split < L:
            _drag_piece(0.0, split, a_n, b_n, j0, jr, 1.0, nodes, weights, column)
            _drag_piece(split, L, a_n, b_n, j0, jr, 1.0, nodes, weights, column)
        else:
            _drag_piece(0.0, L, a_n, b_n, j0, jr, 1.0, nodes, weights, column)
        for c in range(n):
            phi[c, k] = column[c]
        # added mass, unit coefficient: -(M_A,k a + h_A,k)
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
        for m in range(nodes.shape[0]):
            s = L * nodes[m]
            w = L * weights[m]
            # normal acceleration at s: sum_b N_b(s) a_b + bias(s)
            acc0 = bias0[0] + s * bias1[0]
            acc1 = bias0[1] + s * bias1[1]
            acc2 = bias0[2] + s * bias1[2]
            for b in range(n):
                acc0 += (nj0[0, b] + s * njr[0, b]) * a[b]
                acc1 += (nj0[1, b] + s * njr[1, b]) * a[b]
                acc2 += (nj0[2, b] + s * njr[2, b]) * a[b]
            for c in range(n):
                phi[c, c_count + k] -= w * (
                    (nj0[0, c] + s * njr[0, c]) * acc0 + (nj0[1, c] + s * njr[1, c]) * acc1
                    + (nj0[2, c] + s * njr[2, c]) * acc2
                )  # fmt: skip
        # buoyancy, unit coefficient: the midpoint's vertical Jacobian row
        half = 0.5 * L
        for c in range(n):
            phi[c, 2 * c_count + k] = j0[2, c] + half * jr[2, c]
    return phi
