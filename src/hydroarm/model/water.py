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
  (``SPEC.md`` section 2). It is not a water force: see :func:`paper_current_acceleration`.
* ``uniform``: a world-frame water velocity ``V_c(t) = mean + amplitude sin(2 pi f t + phase)``
  (m/s); drag acts on the velocity relative to it.
* ``none``: still water.

All world quantities are in the base frame (z up). Forces in N, torques in N m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated, Literal

import numba
import numpy as np
import pinocchio as pin
import pydantic

from hydroarm.model.arm import Arm
from hydroarm.config import FrozenModel
from hydroarm.model.integrator import rk4_second_order_stage

MAX_CURRENT_SPEED = 20.0
"""m/s: bound on every component of a uniform current's mean and amplitude."""

Velocity3 = Annotated[
    list[Annotated[float, pydantic.Field(ge=-MAX_CURRENT_SPEED, le=MAX_CURRENT_SPEED)]],
    pydantic.Field(min_length=3, max_length=3),
]

PAPER_CURRENT_AMPLITUDE_DEG_S = (0.5, 0.3, 0.4, 0.2, 0.1, 0.0)
PAPER_CURRENT_OMEGA = (0.1 * math.pi, 0.3 * math.pi, 0.2 * math.pi, 0.4 * math.pi, 0.5 * math.pi, 0.0)
PAPER_CURRENT_PHASE = (-0.2 * math.pi, -0.2 * math.pi, -0.3 * math.pi, -0.2 * math.pi, -0.25 * math.pi, 0.0)


class CurrentConfig(FrozenModel):
    """The ocean current model.

    ``model = "paper"``: eq. (22) joint-velocity kicks d(t) (deg/s), scaled by
    ``scale``, as the joint acceleration ``d(t) / reference_period`` (rad/s^2).
    ``model = "uniform"``: world-frame water velocity
    ``mean + amplitude * sin(2 pi frequency_hz t + phase)`` (m/s), in the drag.
    """

    model: Literal["paper", "uniform", "none"] = "paper"
    scale: float = pydantic.Field(1.0, ge=0.0, le=1000.0, description="multiplies the paper current")
    reference_period: float = pydantic.Field(
        0.01, gt=0.0, le=1.0, description="T_ref (s): the paper's simulation cycle"
    )
    mean: Velocity3 = pydantic.Field([0.0, 0.0, 0.0], description="uniform current, m/s, each within +-20")
    amplitude: Velocity3 = pydantic.Field([0.0, 0.0, 0.0], description="uniform current, m/s, each within +-20")
    frequency_hz: float = pydantic.Field(0.0, ge=0.0, le=100.0)
    phase: float = 0.0


class Water(FrozenModel):
    """Water properties and the quadrature of the strip integrals.

    ``rho`` (kg/m^3), ``cd`` (Morison drag coefficient, the paper's C_r),
    ``cm`` (added-mass coefficient; 2.0 is the paper's choice, twice the
    potential-flow value of a circular cylinder), ``quadrature_points``
    Gauss-Legendre points per cylinder (see ``docs/model.md`` for the
    convergence study behind the default), ``gravity`` (m/s^2, for buoyancy),
    ``drag``/``added_mass``/``buoyancy`` switch each effect.
    """

    rho: float = pydantic.Field(1000.0, gt=0.0, le=2000.0)
    cd: float = pydantic.Field(1.0, ge=0.0, le=10.0)
    cm: float = pydantic.Field(2.0, ge=0.0, le=10.0)
    quadrature_points: int = pydantic.Field(8, ge=1, le=256)
    gravity: float = pydantic.Field(9.81, ge=0.0, le=100.0)
    drag: bool = True
    added_mass: bool = True
    buoyancy: bool = True
    current: CurrentConfig = CurrentConfig()

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


def paper_current_acceleration(current: CurrentConfig, t: float, n_joints: int) -> np.ndarray:
    """Joint acceleration (rad/s^2), shape (n,), of the paper's current d(t) / T_ref.

    Eq. (22) gives d(t) in deg/s for six joints; joints beyond the sixth get zero.
    Zero unless ``current.model == "paper"``.
    """
    out = np.zeros(n_joints)
    if current.model != "paper" or current.scale == 0.0:
        return out
    m = min(n_joints, 6)
    amp = np.asarray(PAPER_CURRENT_AMPLITUDE_DEG_S[:m])
    omega = np.asarray(PAPER_CURRENT_OMEGA[:m])
    phase = np.asarray(PAPER_CURRENT_PHASE[:m])
    out[:m] = current.scale * np.deg2rad(amp * np.cos(omega * t + phase)) / current.reference_period
    return out


def current_velocity(current: CurrentConfig, t: float) -> np.ndarray:
    """World-frame water velocity V_c(t) (m/s), shape (3,); zero unless ``uniform``."""
    if current.model != "uniform":
        return np.zeros(3)
    phase = 2.0 * math.pi * current.frequency_hz * t + current.phase
    return np.asarray(current.mean) + np.asarray(current.amplitude) * math.sin(phase)


def revolute_axes(arm: Arm) -> np.ndarray:
    """Unit rotation axis of every joint in its own frame, shape (njoints, 3).

    Row 0 (the universe) is unused. Raises ValueError for joints that are not
    1-DOF revolute (the water kernel's forward kinematics supports only those).
    """
    axes = np.zeros((arm.model.njoints, 3))
    for i in range(1, arm.model.njoints):
        name = arm.model.joints[i].shortname()
        if name in ("JointModelRX", "JointModelRY", "JointModelRZ"):
            axes[i, "XYZ".index(name[-1])] = 1.0
        elif name == "JointModelRevoluteUnaligned":
            axes[i] = np.asarray(arm.model.joints[i].extract().axis)
        else:
            raise ValueError(f"joint {arm.model.names[i]}: type {name} is not supported (revolute only)")
    return axes


class StripGeometry:
    """Constant arrays of the strip integrals of one (arm, water) pair, one row per cylinder.

    ``joint_ids`` (C,): the Pinocchio joint whose body carries each cylinder;
    ``start`` (C, 3) and unit ``axis`` (C, 3) in that body frame; ``length``
    (C,) m; ``drag_per_length`` = 1/2 rho C_d D (kg/m^2); ``mass_per_length``
    = rho C_m A (kg/m); ``buoyancy_force`` = rho g V (N); ``support`` (C, n) the
    mask of joints that move each cylinder; ``nodes``/``weights`` the
    Gauss-Legendre rule on [0, 1] (weights sum to 1). Chain data for the
    kernel's forward kinematics: ``parents``, ``placement_rotation`` /
    ``placement_translation`` (Pinocchio's jointPlacements), ``axes`` and
    ``idx_v`` per joint.
    """

    def __init__(self, arm: Arm, water: Water):
        nodes, weights = np.polynomial.legendre.leggauss(water.quadrature_points)
        self.nodes = 0.5 * (nodes + 1.0)
        self.weights = 0.5 * weights
        cylinders = arm.cylinders
        n = arm.n_joints
        self.joint_ids = np.asarray([c.joint_id for c in cylinders], dtype=np.int64)
        self.start = np.asarray([c.start for c in cylinders], dtype=float).reshape(-1, 3)
        self.axis = np.asarray([c.axis for c in cylinders], dtype=float).reshape(-1, 3)
        self.length = np.asarray([c.length for c in cylinders], dtype=float)
        self.drag_per_length = np.asarray(
            [0.5 * water.rho * (water.cd if c.cd is None else c.cd) * c.diameter for c in cylinders],
            dtype=float,
        )
        self.mass_per_length = np.asarray(
            [water.rho * (water.cm if c.cm is None else c.cm) * c.area for c in cylinders], dtype=float
        )
        self.buoyancy_force = np.asarray(
            [water.rho * water.gravity * c.displaced_volume for c in cylinders], dtype=float
        )
        self.support = arm.cylinder_support.copy().reshape(-1, n)
        model = arm.model
        self.parents = np.asarray(model.parents, dtype=np.int64)
        self.placement_rotation = np.stack([model.jointPlacements[i].rotation for i in range(model.njoints)])
        self.placement_translation = np.stack(
            [model.jointPlacements[i].translation for i in range(model.njoints)]
        )
        self.axes = revolute_axes(arm)
        self.idx_v = np.asarray([-1] + [model.joints[i].idx_v for i in range(1, model.njoints)], dtype=np.int64)

    def kernel_constants(self) -> tuple:
        """The constant arguments of the compiled kernels, in their order."""
        return (
            self.parents, self.placement_rotation, self.placement_translation, self.axes, self.idx_v,
            self.joint_ids, self.start, self.axis, self.length, self.support,
            self.drag_per_length, self.mass_per_length, self.buoyancy_force, self.nodes, self.weights,
        )  # fmt: skip


@numba.njit(cache=True)
def _rotation(axis, angle):
    """Rodrigues: rotation by ``angle`` about unit ``axis``, (3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    x, y, z = axis[0], axis[1], axis[2]
    t = 1.0 - c
    out = np.empty((3, 3))
    out[0, 0] = c + x * x * t
    out[0, 1] = x * y * t - z * s
    out[0, 2] = x * z * t + y * s
    out[1, 0] = y * x * t + z * s
    out[1, 1] = c + y * y * t
    out[1, 2] = y * z * t - x * s
    out[2, 0] = z * x * t - y * s
    out[2, 1] = z * y * t + x * s
    out[2, 2] = c + z * z * t
    return out


@numba.njit(cache=True)
def _matmul3(a, b, out):
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]


@numba.njit(cache=True)
def _apply(rot, pos, local, out):
    """out = pos + rot @ local for 3-vectors (pos may be None-like zeros)."""
    for i in range(3):
        out[i] = pos[i] + rot[i, 0] * local[0] + rot[i, 1] * local[1] + rot[i, 2] * local[2]


@numba.njit(cache=True)
def forward_kinematics(q, parents, placement_rotation, placement_translation, axes, idx_v):
    """World placement of every joint frame: (R (nj, 3, 3), p (nj, 3)).

    Same as Pinocchio's ``data.oMi`` (a test checks it): computed here so the
    water kernel needs no per-joint Python access to Pinocchio's data.
    """
    nj = parents.shape[0]
    rot = np.zeros((nj, 3, 3))
    pos = np.zeros((nj, 3))
    local_rot = np.empty((3, 3))
    for i in range(3):
        rot[0, i, i] = 1.0
    for i in range(1, nj):
        par = parents[i]
        _matmul3(placement_rotation[i], _rotation(axes[i], q[idx_v[i]]), local_rot)
        _matmul3(rot[par], local_rot, rot[i])
        _apply(rot[par], pos[par], placement_translation[i], pos[i])
    return rot, pos


@numba.njit(cache=True)
def _drag_piece(s0, s1, a_n, b_n, j0, jr, coefficient, nodes, weights, force):
    """Add int_{s0}^{s1} (J0 + s Jr)^T f(s) ds to ``force``, f = -c |v_n| v_n, v_n = a_n + s b_n."""
    n = force.shape[0]
    width = s1 - s0
    for m in range(nodes.shape[0]):
        s = s0 + width * nodes[m]
        w = width * weights[m]
        v0 = a_n[0] + s * b_n[0]
        v1 = a_n[1] + s * b_n[1]
        v2 = a_n[2] + s * b_n[2]
        scale = -coefficient * w * np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        f0, f1, f2 = scale * v0, scale * v1, scale * v2
        for c in range(n):
            force[c] += (j0[0, c] + s * jr[0, c]) * f0 + (j0[1, c] + s * jr[1, c]) * f1 + (
                j0[2, c] + s * jr[2, c]
            ) * f2


@numba.njit(cache=True)
def water_terms_kernel(
    q, v, water_velocity, jac, djac,
    parents, placement_rotation, placement_translation, axes, idx_v,
    joint_ids, start, axis, length, support, drag_per_length, mass_per_length, buoyancy_force,
    nodes, weights, use_drag, use_added_mass, use_buoyancy,
):  # fmt: skip
    """Strip integrals over all cylinders: returns ``(M_A (n, n), h_A (n,), f (n,))``.

    ``jac``/``djac``: Pinocchio's world joint Jacobian (6, n) and its time
    derivative at (q, v), rows (linear, angular) at the world origin. Along a
    cylinder ``p(s) = p0 + s e`` (s in [0, L]) every kinematic quantity is
    affine in s: ``J_p(s) = J0 + s Jr`` with ``J0 = S (J_lin + J_ang x p0)``,
    ``Jr = S (J_ang x e)``; so the point velocity, its normal part and the
    acceleration bias are affine in s too. The added-mass and buoyancy
    integrands are then polynomials of degree <= 2 (exact with >= 2 Gauss
    points); the drag integrand ``|v_n| v_n`` has a kink where ``|v_n(s)|`` is
    smallest, so the drag integral is split there and each piece integrated by
    Gauss-Legendre. Water generalised force = ``-M_A q'' - h_A + f``, f = drag + buoyancy.
    """
    n = v.shape[0]
    rot, pos = forward_kinematics(q, parents, placement_rotation, placement_translation, axes, idx_v)
    mass = np.zeros((n, n))
    bias_force = np.zeros(n)
    force = np.zeros(n)
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
    for k in range(joint_ids.shape[0]):
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
        # velocity at s: vel0 + s * velr (velr = omega x e is normal to e)
        vel0 = np.zeros(3)
        velr = np.zeros(3)
        for i in range(3):
            for c in range(n):
                vel0[i] += j0[i, c] * v[c]
                velr[i] += jr[i, c] * v[c]
        if use_drag and drag_per_length[k] > 0.0:
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
            if 0.0 < split < L:
                _drag_piece(0.0, split, a_n, b_n, j0, jr, drag_per_length[k], nodes, weights, force)
                _drag_piece(split, L, a_n, b_n, j0, jr, drag_per_length[k], nodes, weights, force)
            else:
                _drag_piece(0.0, L, a_n, b_n, j0, jr, drag_per_length[k], nodes, weights, force)
        if use_added_mass and mass_per_length[k] > 0.0:
            # bias(s) = dJ_lin v + dJ_ang v x p(s) + omega x v(s) = bias0 + s bias1
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
            coefficient = mass_per_length[k] * L
            for m in range(nodes.shape[0]):
                s = L * nodes[m]
                w = coefficient * weights[m]
                for a in range(n):
                    na0 = nj0[0, a] + s * njr[0, a]
                    na1 = nj0[1, a] + s * njr[1, a]
                    na2 = nj0[2, a] + s * njr[2, a]
                    bias_force[a] += w * (
                        na0 * (bias0[0] + s * bias1[0])
                        + na1 * (bias0[1] + s * bias1[1])
                        + na2 * (bias0[2] + s * bias1[2])
                    )
                    for b in range(a, n):
                        mass[a, b] += w * (
                            na0 * (nj0[0, b] + s * njr[0, b])
                            + na1 * (nj0[1, b] + s * njr[1, b])
                            + na2 * (nj0[2, b] + s * njr[2, b])
                        )
        if use_buoyancy:
            half = 0.5 * L
            for c in range(n):
                force[c] += buoyancy_force[k] * (j0[2, c] + half * jr[2, c])
    for a in range(n):
        for b in range(a + 1, n):
            mass[b, a] = mass[a, b]
    return mass, bias_force, force


@numba.njit(cache=True)
def underwater_dynamics_kernel(
    q, v, tau, water_velocity, joint_acceleration, friction, mass_upper, nonlinear, jac, djac,
    parents, placement_rotation, placement_translation, axes, idx_v,
    joint_ids, start, axis, length, support, drag_per_length, mass_per_length, buoyancy_force,
    nodes, weights, use_drag, use_added_mass, use_buoyancy,
):  # fmt: skip
    """True acceleration and disturbance: returns ``(q'' (n,), disturbance (n,))``.

    Solves ``(M + M_A)(q'' - a_c) = tau - nle - h_A + f - b v`` with ``M`` from
    the upper triangle ``mass_upper`` (Pinocchio's CRBA), ``nle = C v + G``,
    ``a_c = joint_acceleration`` (the paper current), ``b = friction``.
    ``disturbance = M q'' + nle - tau``: the generalised force the dry model lacks.
    """
    n = v.shape[0]
    added, bias, force = water_terms_kernel(
        q, v, water_velocity, jac, djac,
        parents, placement_rotation, placement_translation, axes, idx_v,
        joint_ids, start, axis, length, support, drag_per_length, mass_per_length, buoyancy_force,
        nodes, weights, use_drag, use_added_mass, use_buoyancy,
    )  # fmt: skip
    mass = np.empty((n, n))
    for a in range(n):
        for b in range(a, n):
            mass[a, b] = mass_upper[a, b]
            mass[b, a] = mass_upper[a, b]
    rhs = tau - nonlinear + force - bias - friction * v
    acc = np.linalg.solve(mass + added, rhs) + joint_acceleration
    disturbance = mass @ acc + nonlinear - tau
    return acc, disturbance


@numba.njit(cache=True)
def rk4_stage_kernel(
    stage, t, h, x, xs, ks, dists, average, tau, friction, mass_upper, nonlinear, jac, djac,
    current_joint, current_world,
    parents, placement_rotation, placement_translation, axes, idx_v,
    joint_ids, start, axis, length, support, drag_per_length, mass_per_length, buoyancy_force,
    nodes, weights, use_drag, use_added_mass, use_buoyancy,
):  # fmt: skip  # pragma: no cover - compiled
    """One stage of a classic RK4 step of the true plant, everything but Pinocchio compiled.

    The caller evaluates Pinocchio (CRBA -> ``mass_upper``, NLE -> ``nonlinear``,
    Jacobians and their time variation -> ``jac``, ``djac``) at the stage state
    ``xs = [q, v]`` (2n,) and time ``t``; this evaluates the current at ``t`` and
    :func:`underwater_dynamics_kernel`, stores the disturbance ``dists[stage]`` and
    leaves the RK4 bookkeeping to :func:`hydroarm.model.integrator.rk4_second_order_stage`
    (``ks[stage] = [v, q'']``, ``xs`` the next stage's state); after the last stage
    (3) ``x`` itself becomes ``x + h/6 (k1 + 2 k2 + 2 k3 + k4)`` (``xs`` too) and
    ``average`` gets ``d1 + 2 d2 + 2 d3 + d4``. Same operations, in the same order,
    as :func:`hydroarm.model.integrator.rk4_step` driven by ``_RK4Model.step`` (the
    reference, which a test compares).

    Current: ``current_joint`` (3, n) = paper amplitude (rad/s^2, zero unless the
    paper current), angular frequency and phase: joint acceleration
    ``amplitude cos(omega t + phase)``; ``current_world`` (8,) = uniform mean (3),
    amplitude (3) (m/s, zero unless the uniform current), ``2 pi f`` and phase:
    water velocity ``mean + amplitude sin(2 pi f t + phase)``.
    """
    n = tau.shape[0]
    joint_acceleration = np.empty(n)
    for i in range(n):
        joint_acceleration[i] = current_joint[0, i] * np.cos(current_joint[1, i] * t + current_joint[2, i])
    wave = math.sin(current_world[6] * t + current_world[7])
    water_velocity = np.empty(3)
    for i in range(3):
        water_velocity[i] = current_world[i] + current_world[3 + i] * wave
    acc, disturbance = underwater_dynamics_kernel(
        xs[:n], xs[n:], tau, water_velocity, joint_acceleration, friction, mass_upper, nonlinear, jac, djac,
        parents, placement_rotation, placement_translation, axes, idx_v,
        joint_ids, start, axis, length, support, drag_per_length, mass_per_length, buoyancy_force,
        nodes, weights, use_drag, use_added_mass, use_buoyancy,
    )  # fmt: skip
    for i in range(n):
        dists[stage, i] = disturbance[i]
    rk4_second_order_stage(stage, h, x, xs, ks, acc)
    if stage < 3:
        return
    for i in range(2 * n):
        x[i] = xs[i]
    for i in range(n):
        average[i] += dists[0, i] + 2.0 * dists[1, i] + 2.0 * dists[2, i] + dists[3, i]


@dataclass
class WaterModel:
    """The water acting on one arm: precomputed strip geometry + evaluation.

    Build once per (arm, water) pair; :meth:`terms` is the fast path the plant
    calls at every integrator stage (one Pinocchio call + one compiled kernel).
    """

    arm: Arm
    water: Water

    def __post_init__(self) -> None:
        self.geometry = StripGeometry(self.arm, self.water)
        self._constants = self.geometry.kernel_constants()
        n = self.arm.n_joints
        current = self.water.current
        m = min(n, 6)
        self._current_amplitude = np.zeros(n)
        self._current_omega = np.zeros(n)
        self._current_phase = np.zeros(n)
        self._current_amplitude[:m] = (
            current.scale * np.deg2rad(PAPER_CURRENT_AMPLITUDE_DEG_S[:m]) / current.reference_period
        )
        self._current_omega[:m] = PAPER_CURRENT_OMEGA[:m]
        self._current_phase[:m] = PAPER_CURRENT_PHASE[:m]
        self._zero3 = np.zeros(3)
        self._zero_n = np.zeros(n)
        # The current as the compiled RK4 stage takes it (rk4_stage_kernel): zero amplitudes
        # for the models not in use, so each formula gives exactly 0 there.
        self.current_joint = np.zeros((3, n))
        if current.model == "paper":
            self.current_joint[0] = self._current_amplitude
        self.current_joint[1] = self._current_omega
        self.current_joint[2] = self._current_phase
        self.current_world = np.zeros(8)
        if current.model == "uniform":
            self.current_world[:3] = current.mean
            self.current_world[3:6] = current.amplitude
            self.current_world[6] = 2.0 * math.pi * current.frequency_hz
            self.current_world[7] = current.phase

    def _kernel(self, q, v, t, drag, added_mass, buoyancy):
        data = self.arm.data
        pin.computeJointJacobiansTimeVariation(self.arm.model, data, q, v)
        n = self.arm.n_joints
        return water_terms_kernel(
            q, v, current_velocity(self.water.current, t), data.J.reshape(6, n), data.dJ.reshape(6, n),
            *self._constants,
            drag, added_mass, buoyancy,
        )  # fmt: skip

    def dynamics(
        self, q: np.ndarray, v: np.ndarray, tau: np.ndarray, t: float, friction: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """True ``(q'', disturbance)`` of the arm in this water: see :func:`underwater_dynamics_kernel`.

        One CRBA, one NLE and one Jacobian-derivative call to Pinocchio, then
        the compiled kernel (water, current, friction, the (M + M_A) solve).
        """
        model, data = self.arm.model, self.arm.data
        w = self.water
        pin.crba(model, data, q)
        nonlinear = pin.nonLinearEffects(model, data, q, v)
        pin.computeJointJacobiansTimeVariation(model, data, q, v)
        current = self.water.current
        if current.model == "paper":
            joint_acc = self._current_amplitude * np.cos(self._current_omega * t + self._current_phase)
            water_velocity = self._zero3
        else:
            joint_acc = self._zero_n
            water_velocity = current_velocity(current, t)
        return underwater_dynamics_kernel(
            q, v, tau, water_velocity, joint_acc, friction, data.M, nonlinear,
            data.J.reshape(6, self.arm.n_joints), data.dJ.reshape(6, self.arm.n_joints),
            *self._constants, w.drag, w.added_mass, w.buoyancy,
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
