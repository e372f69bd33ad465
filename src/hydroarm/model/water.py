"""The water: Morison strip theory on every wetted cylinder, buoyancy, currents.

Per unit length of a cylinder of diameter D and cross-section A = pi D^2/4,
at a point with velocity v relative to the water and acceleration a:

* drag (Morison):       f_d = -1/2 rho C_d D |v_n| v_n
* added mass (Morison): f_a = -rho C_m A a_n
* buoyancy:             rho g V upward at the cylinder's midpoint

where ``_n`` is the component normal to the cylinder axis. The line integrals
are computed with Gauss-Legendre quadrature (``Water.quadrature_points`` per
cylinder) and mapped to joint torques through the point Jacobians,
``tau = sum_c int J_p(s)^T f(s) ds``: this generalises the paper's hand-derived
Appendix B. Because f_a depends on q'', the added mass enters the dynamics as a
configuration-dependent inertia ``M_A(q) = sum rho C_m A w J_p^T (I - e e^T) J_p``
plus a velocity term ``h_A(q, v)``; the generalised added-mass force is
``-M_A(q) q'' - h_A(q, v)``.

Currents (``Water.current``):

* ``paper`` (default): the joint-velocity disturbance d(t) of the paper's eq. (22),
  applied as a joint acceleration d(t) / T_ref inside the plant's integration
  (docs/paper-reading.md, section 2). It is not a water force: see :func:`paper_current_acceleration`.
* ``uniform``: a world-frame water velocity ``V_c(t) = mean + amplitude sin(2 pi f t + phase)``
  (m/s); drag acts on the velocity relative to it.
* ``none``: still water.

All world quantities are in the base frame (z up). Forces in N, torques in N m.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import pinocchio as pin
import pydantic

from hydroarm.config import FrozenModel
from hydroarm.model.arm import Arm
from hydroarm.model.current import CurrentConfig, CurrentField, current_velocity, paper_current_acceleration
from hydroarm.model.reynolds import ReynoldsDrag
from hydroarm.model.strips import StripGeometry, underwater_dynamics_kernel, water_terms_kernel

__all__ = [
    "CurrentConfig",
    "HydroTorques",
    "Water",
    "WaterModel",
    "added_mass_matrix",
    "current_velocity",
    "hydrodynamic_torques",
    "paper_current_acceleration",
]


class Water(FrozenModel):
    """Water properties and the quadrature of the strip integrals.

    ``rho`` (kg/m^3), ``cd`` (Morison drag coefficient, the paper's C_r),
    ``cm`` (added-mass coefficient; 2.0 is the paper's choice, twice the
    potential-flow value of a circular cylinder), ``quadrature_points``
    Gauss-Legendre points per cylinder (see ``docs/model.md`` for the
    convergence study behind the default), ``gravity`` (m/s^2, for buoyancy),
    ``drag``/``added_mass``/``buoyancy`` switch each effect.
    """

    rho: float = pydantic.Field(1000.0, gt=0.0, le=2000.0, description="water density (kg/m^3)")
    cd: float = pydantic.Field(
        1.0, ge=0.0, le=10.0, description="Morison drag coefficient C_d of every cylinder (-), the paper's C_r"
    )
    cm: float = pydantic.Field(2.0, ge=0.0, le=10.0, description="Morison added-mass coefficient C_m (-)")
    quadrature_points: int = pydantic.Field(
        8, ge=1, le=256, description="Gauss-Legendre points per cylinder in the strip integrals (-)"
    )
    gravity: float = pydantic.Field(9.81, ge=0.0, le=100.0, description="gravity for the buoyancy (m/s^2)")
    drag: bool = pydantic.Field(True, description="switch: the Morison drag on the arm (on/off)")
    drag_model: Literal["constant", "reynolds"] = pydantic.Field(
        "constant",
        description="constant: C_d = cd; reynolds: C_d(Re) of a smooth cylinder along every strip (DNV-RP-C205)",
    )
    kinematic_viscosity: float = pydantic.Field(
        1.0e-6, gt=0.0, le=1e-3, description="nu of the water, for drag_model = reynolds (m^2/s)"
    )
    added_mass: bool = pydantic.Field(True, description="switch: the added mass of the water (on/off)")
    buoyancy: bool = pydantic.Field(True, description="switch: the buoyancy of the wetted cylinders (on/off)")
    current: CurrentConfig = pydantic.Field(CurrentConfig(), description="the ocean current (section)")

    def off(self) -> Water:
        """The same settings with every water effect and the current switched off."""
        return self.model_copy(
            update={"drag": False, "added_mass": False, "buoyancy": False, "current": CurrentConfig(model="none")}
        )


@dataclass(frozen=True)
class HydroTorques:
    """Generalised forces (N m), each shape (n,), that the water exerts on the arm.

    ``M q'' + C q' + G = tau + drag + added_mass + buoyancy``. ``added_mass`` is
    ``-M_A(q) a - h_A(q, v)`` at the acceleration ``a`` it was evaluated with.
    """

    drag: np.ndarray
    added_mass: np.ndarray
    buoyancy: np.ndarray

    @property
    def total(self) -> np.ndarray:
        return self.drag + self.added_mass + self.buoyancy


class WaterModel:
    """The water acting on one arm: precomputed strip geometry, the current, and a workspace.

    Build once per (arm, water) pair; it owns its Pinocchio workspace (``data``), so
    it is not shared between threads. ``kernel_constants``: the constant arguments of
    the compiled kernels (:meth:`StripGeometry.kernel_constants`); ``current``: the
    :class:`~hydroarm.model.current.CurrentField`.
    """

    def __init__(self, arm: Arm, water: Water):
        self.arm = arm
        self.water = water
        self.geometry = StripGeometry(arm, water)
        self.kernel_constants = self.geometry.kernel_constants()
        self.current = CurrentField(water.current, arm.n_joints)
        self.data = arm.create_data()
        self.reynolds = (
            ReynoldsDrag(arm, water, self.geometry) if water.drag and water.drag_model == "reynolds" else None
        )
        """The Reynolds-dependent drag (:mod:`hydroarm.model.reynolds`), None for a constant C_d."""

    def _kernel(self, q, v, t, drag, added_mass, buoyancy):
        data = self.data
        pin.computeJointJacobiansTimeVariation(self.arm.model, data, q, v)
        n = self.arm.n_joints
        water_velocity = self.current.at(t)[1]
        mass, bias, force = water_terms_kernel(
            q, v, water_velocity, data.J.reshape(6, n), data.dJ.reshape(6, n),
            *self.kernel_constants,
            drag and self.reynolds is None, added_mass, buoyancy,
        )  # fmt: skip
        if drag and self.reynolds is not None:
            force = force + self.reynolds.force(q, v, water_velocity, data.J.reshape(6, n))
        return mass, bias, force

    def dynamics(
        self, q: np.ndarray, v: np.ndarray, tau: np.ndarray, t: float, friction: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """True ``(q'', disturbance)`` of the arm in this water: see
        :func:`~hydroarm.model.strips.underwater_dynamics_kernel`.

        One CRBA, one NLE and one Jacobian-derivative call to Pinocchio, then
        the compiled kernel (water, current, friction, the (M + M_A) solve).
        """
        model, data = self.arm.model, self.data
        w = self.water
        pin.crba(model, data, q)
        nonlinear = pin.nonLinearEffects(model, data, q, v)
        pin.computeJointJacobiansTimeVariation(model, data, q, v)
        joint_acc, water_velocity = self.current.at(t)
        jac = data.J.reshape(6, self.arm.n_joints)
        if self.reynolds is not None:  # the drag as a generalised force beside tau
            drag = self.reynolds.force(q, v, water_velocity, jac)
            acc, disturbance = underwater_dynamics_kernel(
                q, v, np.asarray(tau, dtype=float) + drag, water_velocity, joint_acc, friction, data.M, nonlinear,
                jac, data.dJ.reshape(6, self.arm.n_joints), *self.kernel_constants, False, w.added_mass, w.buoyancy,
            )  # fmt: skip
            return acc, disturbance + drag
        return underwater_dynamics_kernel(
            q, v, tau, water_velocity, joint_acc, friction, data.M, nonlinear,
            jac, data.dJ.reshape(6, self.arm.n_joints),
            *self.kernel_constants, w.drag, w.added_mass, w.buoyancy,
        )  # fmt: skip

    def terms(self, q: np.ndarray, v: np.ndarray, t: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(M_A (n, n), h_A (n,), f (n,))``: water generalised force = ``-M_A q'' - h_A + f``.

        ``f`` collects drag (relative to the current at time t, s) and buoyancy.
        """
        w = self.water
        return self._kernel(q, v, t, w.drag, w.added_mass, w.buoyancy)

    def torques(self, q: np.ndarray, v: np.ndarray, a: np.ndarray, t: float = 0.0) -> HydroTorques:
        """Each water effect separately at (q, v, a) and time t; see :class:`HydroTorques`."""
        w = self.water
        n = self.arm.n_joints
        _, _, drag = self._kernel(q, v, t, w.drag, False, False)
        _, _, buoyancy = self._kernel(q, v, t, False, False, w.buoyancy)
        mass, bias, _ = self._kernel(q, v, t, False, w.added_mass, False)
        added = -(mass @ a) - bias if w.added_mass else np.zeros(n)
        return HydroTorques(drag=drag, added_mass=added, buoyancy=buoyancy)


def hydrodynamic_torques(
    arm: Arm, water: Water, q: np.ndarray, v: np.ndarray, a: np.ndarray, t: float = 0.0
) -> HydroTorques:
    """Generalised forces of drag, added mass and buoyancy on ``arm`` at (q, v, a).

    Convenience wrapper; for repeated calls build a :class:`WaterModel` once.
    q, v, a: shape (n,) in rad, rad/s, rad/s^2. Returns :class:`HydroTorques` (N m).
    """
    n = arm.n_joints
    q, v, a = (_check_vector(x, n, name) for x, name in ((q, "q"), (v, "v"), (a, "a")))
    return WaterModel(arm, water).torques(q, v, a, t)


def added_mass_matrix(arm: Arm, water: Water, q: np.ndarray) -> np.ndarray:
    """M_A(q) (kg m^2), shape (n, n), symmetric positive semidefinite."""
    n = arm.n_joints
    q = _check_vector(q, n, "q")
    return WaterModel(arm, water)._kernel(q, np.zeros(n), 0.0, False, True, False)[0]


def _check_vector(x: np.ndarray, n: int, name: str) -> np.ndarray:
    arr = np.asarray(x, dtype=float)
    if arr.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr}")
    return arr
