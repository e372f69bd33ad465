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

Beside the paper's model, two settings (off by default, the numbers then unchanged):

* ``added_mass_model = "kirchhoff"``: the generalised force of the Lagrangian of
  ``T_A = 1/2 sum int rho C_m A |(I - e e^T) u|^2 ds`` (u the point's velocity): the same M_A,
  another h_A, so that the water's added mass conserves energy (the Morison form does not on
  rotating links; docs/model.md);
* axial drag: ``-1/2 rho C_a A |u_a| u_a`` along the axis of every cylinder whose arm file gives
  an axial coefficient ``cd_axial`` (C_a; u_a the axial velocity relative to the water), switch
  ``axial_drag``.

Each effect is one compiled function of :mod:`hydroarm.model.water.effects`; the loop over the
cylinders and the compiled structure every plant reads are in :mod:`hydroarm.model.water.strips`.

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
from typing import Any, Literal

import numpy as np
import pinocchio as pin
import pydantic

from hydroarm.config import FrozenModel
from hydroarm.model.arm.description import Arm
from hydroarm.model.water.current import CurrentConfig, CurrentField, current_velocity, paper_current_acceleration
from hydroarm.model.water.strips import StripGeometry, underwater_dynamics, water_terms

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


DENSITY_RANGE: tuple[float, float] = (0.0, 2000.0)
"""kg/m^3: the allowed water density, exclusive of 0 (:func:`density_setting`)."""


def density_setting(default: float, what: str) -> Any:
    """The one definition of a water density setting (kg/m^3, in (0, 2000]): ``Water.rho`` of a
    fixed arm or a vehicle run, and the replay's ``water_density`` (the tank's water)."""
    return pydantic.Field(default, gt=DENSITY_RANGE[0], le=DENSITY_RANGE[1], description=f"{what} (kg/m^3)")


class Water(FrozenModel):
    """Water properties and the quadrature of the strip integrals.

    ``rho`` (kg/m^3), ``cd`` (Morison drag coefficient, the paper's C_r),
    ``cm`` (added-mass coefficient; 2.0 is the paper's choice, twice the
    potential-flow value of a circular cylinder), ``quadrature_points``
    Gauss-Legendre points per cylinder (see ``docs/model.md`` for the
    convergence study behind the default), ``gravity`` (m/s^2, for buoyancy),
    ``drag``/``added_mass``/``buoyancy``/``axial_drag`` switch each effect, ``drag_model`` and
    ``added_mass_model`` choose their forms.
    """

    rho: float = density_setting(1000.0, "water density")
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
    added_mass_model: Literal["morison", "kirchhoff"] = pydantic.Field(
        "morison",
        description="morison: -rho C_m A a_n per length (the paper's); kirchhoff: the same inertia from the "
        "Lagrangian of the water's kinetic energy, which conserves energy on rotating links",
    )
    buoyancy: bool = pydantic.Field(True, description="switch: the buoyancy of the wetted cylinders (on/off)")
    axial_drag: bool = pydantic.Field(
        True, description="switch: the axial drag of the cylinders whose arm file gives cd_axial > 0 (on/off)"
    )
    current: CurrentConfig = pydantic.Field(CurrentConfig(), description="the ocean current (section)")

    def off(self) -> Water:
        """The same settings with every water effect and the current switched off."""
        return self.model_copy(
            update={"drag": False, "added_mass": False, "buoyancy": False, "axial_drag": False,
                    "current": CurrentConfig(model="none")}
        )  # fmt: skip


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
    """The water acting on one arm: its compiled strips, the current, and a workspace.

    Build once per (arm, water) pair; it owns its Pinocchio workspace (``data``), so
    it is not shared between threads. ``strips``: the :class:`~hydroarm.model.water.strips.Strips`
    every kernel reads (``geometry`` its arrays); ``current``: the
    :class:`~hydroarm.model.water.current.CurrentField`.
    """

    def __init__(self, arm: Arm, water: Water):
        self.arm = arm
        self.water = water
        self.geometry = StripGeometry(arm, water)
        self.strips = self.geometry.compiled
        self.current = CurrentField(water.current, arm.n_joints)
        self.data = arm.create_data()

    def _kernel(self, q, v, t, drag, added_mass, buoyancy, axial):
        data = self.data
        pin.computeJointJacobiansTimeVariation(self.arm.model, data, q, v)
        n = self.arm.n_joints
        water_velocity = self.current.at(t)[1]
        strips = self.geometry.switched(drag, added_mass, buoyancy, axial)
        mass, bias, force, tau_force = water_terms(
            strips, q, v, water_velocity, data.J.reshape(6, n), data.dJ.reshape(6, n)
        )
        if drag and self.water.drag_model == "reynolds":
            force = force + tau_force
        return mass, bias, force

    def dynamics(
        self, q: np.ndarray, v: np.ndarray, tau: np.ndarray, t: float, friction: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """True ``(q'', disturbance)`` of the arm in this water: see
        :func:`~hydroarm.model.water.strips.underwater_dynamics`.

        One CRBA, one NLE and one Jacobian-derivative call to Pinocchio, then
        the compiled kernel (water, current, friction, the (M + M_A) solve).
        """
        model, data = self.arm.model, self.data
        pin.crba(model, data, q)
        nonlinear = pin.nonLinearEffects(model, data, q, v)
        pin.computeJointJacobiansTimeVariation(model, data, q, v)
        n = self.arm.n_joints
        rigid = (data.M, nonlinear, data.J.reshape(6, n), data.dJ.reshape(6, n))
        return underwater_dynamics(self.strips, q, v, np.asarray(tau, dtype=float), float(t), float(friction), rigid)

    def terms(self, q: np.ndarray, v: np.ndarray, t: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(M_A (n, n), h_A (n,), f (n,))``: water generalised force = ``-M_A q'' - h_A + f``.

        ``f`` collects drag (relative to the current at time t, s), axial drag and buoyancy.
        """
        w = self.water
        return self._kernel(q, v, t, w.drag, w.added_mass, w.buoyancy, w.axial_drag)

    def torques(self, q: np.ndarray, v: np.ndarray, a: np.ndarray, t: float = 0.0) -> HydroTorques:
        """Each water effect separately at (q, v, a) and time t; see :class:`HydroTorques`
        (the axial drag is in ``drag``)."""
        w = self.water
        n = self.arm.n_joints
        _, _, drag = self._kernel(q, v, t, w.drag, False, False, w.axial_drag)
        _, _, buoyancy = self._kernel(q, v, t, False, False, w.buoyancy, False)
        mass, bias, _ = self._kernel(q, v, t, False, w.added_mass, False, False)
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
    return WaterModel(arm, water)._kernel(q, np.zeros(n), 0.0, False, True, False, False)[0]


def _check_vector(x: np.ndarray, n: int, name: str) -> np.ndarray:
    arr = np.asarray(x, dtype=float)
    if arr.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr}")
    return arr
