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

import numpy as np
import pinocchio as pin

from hydroarm.model.arm import Arm
from hydroarm.model.strips import StripGeometry, water_terms_kernel
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
        columns ``[drag_1..C, added_mass_1..C, buoyancy_1..C]`` (N m per unit coefficient)."""
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
