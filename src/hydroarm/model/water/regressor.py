"""The water's generalised force as a linear regression in a few coefficients per wetted cylinder.

The Morison strip integrals of :mod:`hydroarm.model.water.morison` are linear in three coefficients
of each cylinder k (C cylinders)::

    drag_k      = 1/2 rho C_d,k D_k      (kg/m^2)   on   int J_p^T |v_n| v_n ds
    mass_k      = rho C_m,k A_k          (kg/m)     on   int J_p^T a_n ds
    buoyancy_k  = rho g V_k              (N)        on   J_p(mid)^T e_z

so the water's generalised force (N m, (n,)) at joint state (q, v) and acceleration a is::

    w(q, v, a) = Phi(q, v, a) theta,   theta = [drag_1..C, mass_1..C, buoyancy_1..C]   (3C,)

(the current left out: a state model cannot know it). Column k of each block is the water
kernel of :mod:`hydroarm.model.water.strips` with unit coefficient on cylinder k alone, so the basis
is the plant's own strip geometry and quadrature (:class:`~hydroarm.model.water.strips.StripGeometry`):
drag ``f(q, v)``, added mass ``-(M_A,k(q) a + h_A,k(q, v))`` (Morison's, or Kirchhoff's when the
water's ``added_mass_model`` says so), buoyancy ``f(q)``. The axial drag is not in the basis.
:func:`basis_kernel` runs the plant's strip loop (:func:`~hydroarm.model.water.strips.jacobian_frame`,
the effects of :mod:`hydroarm.model.water.effects`) with unit coefficients, the added mass in the
regressor's own form (the acceleration inside the integral).

:meth:`WaterRegressor.physical` turns theta back into C_d, C_m and the displaced volume V (m^3)
of every cylinder, with the water density and gravity the regressor was built with.
"""

from __future__ import annotations

import numba
import numpy as np
import pinocchio as pin

from hydroarm.model.arm.description import Arm
from hydroarm.model.dynamics import fixed_order
from hydroarm.model.water.effects import (
    BIAS0,
    BIAS1,
    BUOYANCY,
    CYL,
    DRAG,
    DRAG_CONSTANT,
    KIND,
    KIRCHHOFF,
    LENGTH,
    MASS,
    NJ0,
    NJR,
    NODES,
    WEIGHTS,
    acceleration_bias,
    buoyancy,
    drag,
    kirchhoff_bias,
    normal_jacobian,
)
from hydroarm.model.water.morison import Water
from hydroarm.model.water.strips import StripGeometry, forward_kinematics, jacobian_frame, water_terms, world_frame

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
        # the regressor's own strips: constant C_d, no axial drag, every effect on; the terms' coefficients
        # are written into _theta (owned here) before each call, the basis' are ones
        regressor = geometry.replace(drag=True, added_mass=True, buoyancy=True, axial=False, drag_model=DRAG_CONSTANT)
        terms = regressor.replace(drag_per_length=np.zeros(c), mass_per_length=np.zeros(c), buoyancy_force=np.zeros(c))
        self._terms_strips = terms.compile()
        self._table = terms.table  # the compiled coefficients, written before each call of terms()
        ones = np.ones(c)
        unit = regressor.replace(drag_per_length=ones, mass_per_length=ones, buoyancy_force=ones)
        self._unit_strips = unit.compile()
        self._per_cylinder = []
        for k in range(c):
            part = slice(k, k + 1)
            fields = ("joint_ids", "start", "axis", "length", "support", "drag_per_length", "mass_per_length",
                      "buoyancy_force", "axial_drag", "reynolds_drag", "diameter")  # fmt: skip
            self._per_cylinder.append(unit.replace(**{name: getattr(unit, name)[part] for name in fields}))
        self.data = arm.create_data()
        self._still = np.zeros(3)

    def terms(self, theta: np.ndarray, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(M_A (n, n), f (n,))`` of theta (3C,) at q, v (n,): the water's force is ``f - M_A a``
        (added-mass inertia apart, ``f`` = drag + buoyancy - h_A), in one pass of the strip kernel;
        every coefficient is clipped at zero first (a drag, added mass or volume is never
        negative; the kernel skips a cylinder whose coefficient is not positive)."""
        c = self.n_cylinders
        q = np.ascontiguousarray(q, dtype=float)
        v = np.ascontiguousarray(v, dtype=float)
        theta = np.maximum(np.asarray(theta, dtype=float), 0.0)
        table = self._table
        table[:, DRAG], table[:, MASS], table[:, BUOYANCY] = theta[:c], theta[c : 2 * c], theta[2 * c :]
        jac, djac = self.joint_jacobians(q, v)
        mass, bias, force, _ = water_terms(self._terms_strips, q, v, self._still, jac, djac)
        return mass, force - bias

    def joint_jacobians(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(J (6, n), dJ (6, n))``: every joint's Jacobian and its time derivative at q, v (n,)
        (Pinocchio's ``computeJointJacobiansTimeVariation``, stacked as the strip kernels take
        them): views into this regressor's workspace, valid until its next call."""
        data = self.data
        pin.computeJointJacobiansTimeVariation(self.arm.model, data, q, v)
        return data.J.reshape(6, self.n), data.dJ.reshape(6, self.n)

    def compiled_terms(self, theta: np.ndarray):
        """``(strips, still)``: the compiled strips with theta's coefficients (clipped at zero)
        written in and the still water, for a compiled caller of
        :func:`~hydroarm.model.water.strips.water_terms` (the arguments :meth:`terms` gives it); valid
        until the next call of :meth:`terms`, :meth:`terms_along` or this."""
        c = self.n_cylinders
        theta = np.maximum(np.asarray(theta, dtype=float), 0.0)
        table = self._table
        table[:, DRAG], table[:, MASS], table[:, BUOYANCY] = theta[:c], theta[c : 2 * c], theta[2 * c :]
        return self._terms_strips, self._still

    def terms_along(self, theta: np.ndarray, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`terms` at every state of a plan, q, v (N, n): ``(M_A (N, n, n), f (N, n))`` in one
        call of the compiled kernel (:func:`terms_along_kernel`; the same numbers as N calls)."""
        c = self.n_cylinders
        horizon, n = q.shape
        q = np.ascontiguousarray(q, dtype=float)
        v = np.ascontiguousarray(v, dtype=float)
        theta = np.maximum(np.asarray(theta, dtype=float), 0.0)
        table = self._table
        table[:, DRAG], table[:, MASS], table[:, BUOYANCY] = theta[:c], theta[c : 2 * c], theta[2 * c :]
        jac = np.empty((horizon, 6, n))
        djac = np.empty((horizon, 6, n))
        for k in range(horizon):
            jac[k], djac[k] = self.joint_jacobians(q[k], v[k])
        return terms_along_kernel(self._terms_strips, q, v, self._still, jac, djac)

    def predict(self, theta: np.ndarray, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """``Phi(q, v, a) theta`` (n,) N m (:meth:`terms`: coefficients clipped at zero); equals
        :meth:`basis` @ theta for theta >= 0."""
        mass, rest = self.terms(theta, q, v)
        return rest - fixed_order.matvec(mass, np.ascontiguousarray(a, dtype=float))

    def basis(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """``Phi`` (n, 3C) at joint state q, v (n,) rad, rad/s and acceleration a (n,) rad/s^2:
        columns ``[drag_1..C, added_mass_1..C, buoyancy_1..C]`` (N m per unit coefficient), in
        one compiled pass (:func:`basis_kernel`; :meth:`basis_reference` is its twin through
        the plant's own kernel, cylinder by cylinder)."""
        q = np.ascontiguousarray(q, dtype=float)
        v = np.ascontiguousarray(v, dtype=float)
        jac, djac = self.joint_jacobians(q, v)
        return basis_kernel(self._unit_strips, q, v, np.ascontiguousarray(a, dtype=float), jac, djac)

    def basis_reference(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """:meth:`basis` through :func:`~hydroarm.model.water.strips.water_terms`, one cylinder
        and one effect at a time (slow; the tests compare the two)."""
        n, c = self.n, self.n_cylinders
        q = np.ascontiguousarray(q, dtype=float)
        v = np.ascontiguousarray(v, dtype=float)
        a = np.asarray(a, dtype=float)
        jac, djac = self.joint_jacobians(q, v)
        phi = np.empty((n, 3 * c))
        for k, single in enumerate(self._per_cylinder):
            mass, bias, drag_force, _ = water_terms(single.switched(True, True, False, False), q, v, self._still,
                                                    jac, djac)  # fmt: skip
            phi[:, k] = drag_force
            phi[:, c + k] = -(mass @ a) - bias
            _, _, lift, _ = water_terms(single.switched(False, False, True, False), q, v, self._still, jac, djac)
            phi[:, 2 * c + k] = lift
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
def terms_along_kernel(strips, q, v, water_velocity, jac, djac):  # pragma: no cover - compiled
    """``(M_A (N, n, n), f - h_A (N, n))``: :func:`~hydroarm.model.water.strips.water_terms` at each of
    the N states q, v (N, n) with their Jacobians jac, djac (N, 6, n), in one compiled loop."""
    horizon, n = v.shape
    mass = np.empty((horizon, n, n))
    rest = np.empty((horizon, n))
    for k in range(horizon):
        added, bias, force, _ = water_terms(strips, q[k], v[k], water_velocity, jac[k], djac[k])
        mass[k] = added
        for i in range(n):
            rest[k, i] = force[i] - bias[i]
    return mass, rest


@numba.njit(cache=True)
def basis_kernel(strips, q, v, a, jac, djac):  # pragma: no cover - compiled
    """``Phi`` (n, 3C) in one pass: per cylinder, the strip integrals of
    :func:`~hydroarm.model.water.strips.water_terms` with the unit coefficients of ``strips``, still
    water (the same operations: drag split at the kink of ``|v_n|``, added mass
    ``-(M_A,k a + h_A,k)`` with the acceleration inside the integral, buoyancy ``J_p(mid)^T e_z``)."""
    n = v.shape[0]
    c_count = strips.joint_ids.shape[0]
    phi = np.zeros((n, 3 * c_count))
    rot, pos = forward_kinematics(strips, q)
    frame = world_frame(strips, n, np.zeros(3))
    column = np.empty(n)
    kirchhoff = strips.added_mass_model == KIRCHHOFF
    for k in range(c_count):
        jacobian_frame(strips, k, rot, pos, jac, djac, v, frame)
        L = frame[CYL, LENGTH]
        column[:] = 0.0
        drag(strips, frame, column)
        for c in range(n):
            phi[c, k] = column[c]
        # added mass, unit coefficient: -(M_A,k a + h_A,k)
        acceleration_bias(frame)
        normal_jacobian(frame)
        for m in range(int(frame[KIND, 1])):
            s = L * frame[NODES, m]
            w = L * frame[WEIGHTS, m]
            # normal acceleration at s: sum_b N_b(s) a_b + bias(s)
            acc0 = frame[BIAS0, 0] + s * frame[BIAS1, 0]
            acc1 = frame[BIAS0, 1] + s * frame[BIAS1, 1]
            acc2 = frame[BIAS0, 2] + s * frame[BIAS1, 2]
            for b in range(n):
                acc0 += (frame[NJ0, b] + s * frame[NJR, b]) * a[b]
                acc1 += (frame[NJ0 + 1, b] + s * frame[NJR + 1, b]) * a[b]
                acc2 += (frame[NJ0 + 2, b] + s * frame[NJR + 2, b]) * a[b]
            for c in range(n):
                phi[c, c_count + k] -= w * (
                    (frame[NJ0, c] + s * frame[NJR, c]) * acc0 + (frame[NJ0 + 1, c] + s * frame[NJR + 1, c]) * acc1
                    + (frame[NJ0 + 2, c] + s * frame[NJR + 2, c]) * acc2
                )  # fmt: skip
        if kirchhoff:
            column[:] = 0.0
            kirchhoff_bias(frame, L, column)
            for c in range(n):
                phi[c, c_count + k] -= column[c]
        # buoyancy, unit coefficient: the midpoint's vertical Jacobian row
        column[:] = 0.0
        buoyancy(strips, frame, column)
        for c in range(n):
            phi[c, 2 * c_count + k] = column[c]
    return phi
