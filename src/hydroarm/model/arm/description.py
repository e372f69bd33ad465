"""The arm: a validated arm file -> a Pinocchio model plus its wetted cylinders.

An arm file (TOML or YAML, see ``hydroarm/arms/paper.toml``) lists one row per
link: standard (distal) Denavit-Hartenberg parameters, dry mass, centre of
gravity and inertia, and the diameter of the link's wetted cylinder.

Frames. Pinocchio joint ``i`` (1-based) rotates about the z axis of DH frame
``i-1``; its body frame is DH frame ``i-1`` turned by ``q_i``. The constant
transform from body frame ``i`` to DH frame ``i`` is
``X_i = Tz(d_i) Tx(a_i) Rx(alpha_i)``, which is also the placement of joint
``i+1`` in body frame ``i``. Link ``i``'s wetted cylinder runs in body frame
``i`` from the origin to ``X_i``'s translation ``(a_i, 0, d_i)``.

Units: SI throughout (m, kg, kg m^2, rad, N m). Base fixed, gravity along -z of
the base frame.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Annotated, Self

import numpy as np
import pinocchio as pin
import pydantic

from hydroarm.config import ConfigError, FrozenModel, field_error, per_joint
from hydroarm.model.dynamics import fixed_order

REFERENCE_WATER_DENSITY = 1000.0
"""kg/m^3: the density at which arm files state ``buoyancy_kg`` (Table A1's)."""

MAX_LENGTH = 100.0
"""m: bound on |a|, |d| and every centre-of-gravity coordinate of an arm file."""

Coordinate = Annotated[float, pydantic.Field(ge=-MAX_LENGTH, le=MAX_LENGTH)]
Vector3 = Annotated[list[Coordinate], pydantic.Field(min_length=3, max_length=3)]
InertiaEntry = Annotated[float, pydantic.Field(ge=-1e6, le=1e6)]
Inertia = Annotated[float, pydantic.Field(gt=0.0, le=1e6)]
TORQUE_LIMIT_MAX = 1e12
"""N m: the largest torque limit any file or setting may give (:data:`TorqueLimit`)."""

TorqueLimit = Annotated[float, pydantic.Field(gt=0.0, le=TORQUE_LIMIT_MAX)]
"""The one definition of an arm's torque limit (N m, in (0, 1e12]): a DH arm file's, a URDF arm's
hydrodynamics file's and the settings' ``torque_limit``; which one wins:
:meth:`Arm.with_torque_limit` (docs/settings.md's precedence table)."""
Armature = Annotated[float, pydantic.Field(ge=0.0, le=1e4)]


class LinkSpec(FrozenModel):
    """One DH row with the link's dry inertial data and wetted cylinder.

    Ranges: |a|, |d|, |com| <= 100 m; 0 < mass <= 1e5 kg; inertias in kg m^2
    up to 1e6; 0 < cylinder_diameter <= 10 m; 0 <= buoyancy_kg <= 1e6; 0 <= cd_axial <= 10.
    """

    name: str = pydantic.Field(min_length=1)
    a: Coordinate = pydantic.Field(description="DH a_i (m)")
    alpha_deg: float = pydantic.Field(ge=-360.0, le=360.0, description="DH alpha_i (deg)")
    d: Coordinate = pydantic.Field(description="DH d_i (m)")
    theta_offset_deg: float = pydantic.Field(0.0, ge=-360.0, le=360.0)
    mass: float = pydantic.Field(gt=0.0, le=1e5, description="dry mass (kg)")
    com: Vector3 = pydantic.Field(description="centre of gravity in DH frame i (m)")
    inertia_axial: Inertia | None = pydantic.Field(
        None, description="moment of inertia about the cylinder axis through the CoG (kg m^2)"
    )
    inertia_transverse: Inertia | None = pydantic.Field(
        None, description="moment of inertia about any perpendicular axis through the CoG"
    )
    inertia: list[Annotated[list[InertiaEntry], pydantic.Field(min_length=3, max_length=3)]] | None = pydantic.Field(
        None,
        min_length=3,
        max_length=3,
        description="full inertia tensor about the CoG in DH frame i (kg m^2)",
    )
    cylinder_diameter: float = pydantic.Field(gt=0.0, le=10.0, description="wetted cylinder diameter (m)")
    buoyancy_kg: float | None = pydantic.Field(
        None, ge=0.0, le=1e6, description="displaced water mass at 1000 kg/m^3; default: the cylinder's volume"
    )
    cd_axial: float = pydantic.Field(
        0.0, ge=0.0, le=10.0, description="axial drag coefficient C_a of the cylinder, on its end area; 0 = none (-)"
    )

    @pydantic.model_validator(mode="after")
    def _check(self) -> Self:
        if math.hypot(self.a, self.d) <= 1e-9:
            raise field_error(
                "a", self.a, f"a and d (= {self.d!r}) are both zero: the link's cylinder has no length; "
                "give a non-zero a or d"
            )  # fmt: skip
        axisym = self.inertia_axial is not None or self.inertia_transverse is not None
        if axisym and self.inertia is not None:
            raise field_error(
                "inertia", self.inertia, "give either inertia_axial/inertia_transverse or inertia, not both"
            )
        if axisym:
            if self.inertia_axial is None or self.inertia_transverse is None:
                missing = "inertia_axial" if self.inertia_axial is None else "inertia_transverse"
                raise field_error(
                    missing, None, "inertia_axial and inertia_transverse go together: give both (kg m^2, > 0)"
                )
            if self.inertia_axial > 2.0 * self.inertia_transverse:
                raise field_error(
                    "inertia_axial",
                    self.inertia_axial,
                    f"must be <= 2 * inertia_transverse = 2 * {self.inertia_transverse!r} (triangle inequality)",
                )
        elif self.inertia is None:
            raise field_error(
                "inertia", None, "missing: give inertia_axial and inertia_transverse, or inertia (kg m^2)"
            )
        else:
            tensor = np.asarray(self.inertia)
            if not np.allclose(tensor, tensor.T, rtol=0.0, atol=1e-12):
                raise field_error("inertia", self.inertia, "must be symmetric")
            eig = np.linalg.eigvalsh(tensor)
            if eig[0] <= 0.0:
                raise field_error("inertia", self.inertia, f"must be positive definite (eigenvalues {eig.tolist()})")
            if eig[2] > eig[0] + eig[1] + 1e-12:
                raise field_error(
                    "inertia",
                    self.inertia,
                    "violates the triangle inequality (largest eigenvalue <= sum of the others): not a rigid body",
                )
        return self

    @property
    def cylinder_end(self) -> np.ndarray:
        """End of the wetted cylinder in the link's body frame (m), shape (3,)."""
        return self.dh_transform().translation.copy()

    @property
    def cylinder_length(self) -> float:
        return float(math.hypot(self.a, self.d))

    def dh_transform(self) -> pin.SE3:
        """X_i = Rz(theta_offset) Tz(d) Tx(a) Rx(alpha): body frame i -> DH frame i."""
        rz = pin.utils.rotate("z", math.radians(self.theta_offset_deg))
        rot = rz @ pin.utils.rotate("x", math.radians(self.alpha_deg))
        return pin.SE3(rot, rz @ np.array([self.a, 0.0, self.d]))

    def inertia_in_body_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """(CoG (3,), inertia about CoG (3, 3)) in the link's body frame."""
        transform = self.dh_transform()
        com = transform.act(np.asarray(self.com, dtype=float))
        if self.inertia is not None:
            rot = transform.rotation
            tensor = rot @ np.asarray(self.inertia, dtype=float) @ rot.T
        else:
            axis = self.cylinder_end / self.cylinder_length
            outer = np.outer(axis, axis)
            tensor = self.inertia_axial * outer + self.inertia_transverse * (np.eye(3) - outer)
        return com, tensor


class ArmSpec(FrozenModel):
    """A whole arm file: 1 to 12 links with distinct names; ``gravity`` in (0, 100] m/s^2;
    ``torque_limit`` in (0, 1e12] N m, one value or one per link; ``armature`` in [0, 1e4]
    kg m^2, one value or one per link: each joint's reflected rotor inertia (the motor rotor's
    inertia times the gear ratio squared, Pinocchio's ``model.armature``: added to M(q)'s
    diagonal, in the plant and in every model a controller builds from the arm)."""

    name: str
    description: str = ""
    source: str = ""
    gravity: float = pydantic.Field(9.81, gt=0.0, le=100.0, description="m/s^2 along -z of the base")
    torque_limit: list[TorqueLimit] | TorqueLimit = pydantic.Field(
        description="|tau_i| <= limit (N m): one value or one per joint"
    )
    armature: list[Armature] | Armature = pydantic.Field(
        0.0, description="reflected rotor inertia per joint (kg m^2): one value or one per joint; 0 = none"
    )
    links: list[LinkSpec] = pydantic.Field(min_length=1, max_length=12)

    @pydantic.model_validator(mode="after")
    def _check(self) -> Self:
        for field in ("torque_limit", "armature"):
            value = getattr(self, field)
            if isinstance(value, list) and len(value) != len(self.links):
                raise field_error(
                    field,
                    value,
                    f"{len(value)} values for {len(self.links)} links: give one value or a list of {len(self.links)}",
                )
        names = [link.name for link in self.links]
        for index, name in enumerate(names):
            if name in names[:index]:
                raise field_error(
                    f"links.{index}.name", name, f"link names must differ (links.{names.index(name)} too)"
                )
        return self


@dataclass(frozen=True)
class WettedCylinder:
    """A cylinder of the arm that the water acts on, fixed to one moving link.

    ``start`` and ``end`` are in the body frame of Pinocchio joint ``joint_id``
    (m); ``diameter`` in m; ``displaced_volume`` in m^3 (buoyancy acts at the
    midpoint); ``cd``/``cm`` override the water's coefficients when not None; ``cd_axial`` the
    axial drag coefficient C_a on the end area (0: no axial drag).
    """

    name: str
    joint_id: int
    start: np.ndarray
    end: np.ndarray
    diameter: float
    displaced_volume: float
    cd: float | None = None
    cm: float | None = None
    cd_axial: float = 0.0

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.end - self.start))

    @property
    def axis(self) -> np.ndarray:
        """Unit axis in the body frame, shape (3,)."""
        return (self.end - self.start) / self.length

    @property
    def area(self) -> float:
        """Cross-section area pi D^2 / 4 (m^2)."""
        return math.pi * self.diameter**2 / 4.0

    def coefficients(self, water) -> tuple[float, float]:
        """``(C_d, C_m)`` of this cylinder in ``water`` (a :class:`~hydroarm.model.water.morison.Water`):
        its own (from the hydrodynamics file) where given, else the water's (:func:`coefficient`)."""
        return coefficient(self.cd, water.cd), coefficient(self.cm, water.cm)


def coefficient(*sources: float | None) -> float | None:
    """The one rule of which C_d, C_m or C_a a wetted cylinder gets: the first of ``sources``
    given (not None), in order of precedence: the cylinder's own in a URDF arm's hydrodynamics
    file (``[[links.cylinders]]``), its link's there (``[[links]]``), the settings' (``water.cd``,
    ``water.cm``). The hydrodynamics file's two are merged when the arm is imported
    (:mod:`hydroarm.model.arm.urdf_import`), the water's when a plant is built
    (:meth:`WettedCylinder.coefficients`); docs/settings.md's precedence table states it, and
    ``hydroarm settings --resolved`` shows the result. None when none is given."""
    return next((value for value in sources if value is not None), None)


@dataclass
class Arm:
    """A fixed-base arm of revolute joints: constants only (Pinocchio model + wetted cylinders).

    Follows Pinocchio's model/data split: an ``Arm`` holds constants and is shared
    freely; whoever computes with it owns a workspace (``arm.create_data()``) and
    passes it as ``data=`` (the plant, :class:`~hydroarm.model.dynamics.nominal.NominalModel`
    and every controller own theirs). The dynamics methods below are free of
    state: without ``data`` they make a fresh workspace (convenient, slower).
    All dynamics here are the *dry* rigid body; the water is in
    :mod:`hydroarm.model.water.morison`. ``position_limit`` (n, 2) rad: [lower, upper] per
    joint when the arm file states them (URDF joint limits), else None.
    """

    name: str
    model: pin.Model
    cylinders: tuple[WettedCylinder, ...]
    torque_limit: np.ndarray
    spec: ArmSpec | None = None
    position_limit: np.ndarray | None = None

    def with_torque_limit(self, limit: float | list[float] | np.ndarray | None) -> Arm:
        """This arm with its actuators' torque limit replaced (N m: one value or one per joint);
        ``limit`` None: this arm itself. The model and the cylinders are shared (constants)."""
        if limit is None:
            return self
        values = per_joint(
            [float(x) for x in np.ravel(limit)] if np.ndim(limit) else float(limit), self.model.nv, "torque_limit"
        )
        return dataclasses.replace(self, torque_limit=values)

    def __post_init__(self) -> None:
        if self.model.nq != self.model.nv:
            raise ConfigError("only revolute/prismatic 1-DOF joints are supported (nq == nv)")
        self.torque_limit = np.broadcast_to(np.asarray(self.torque_limit, dtype=float), (self.model.nv,)).copy()
        if self.position_limit is not None:
            limits = np.asarray(self.position_limit, dtype=float)
            if limits.shape != (self.model.nv, 2) or np.any(limits[:, 0] > limits[:, 1]):
                raise ConfigError(
                    f"position_limit must be ({self.model.nv}, 2) with lower <= upper, got {limits.tolist()}"
                )
            self.position_limit = limits.copy()
        # support[c, j] = 1 if joint j moves cylinder c (joint j on the path to its link).
        support = np.zeros((len(self.cylinders), self.model.nv))
        for row, cylinder in enumerate(self.cylinders):
            for joint in self.model.supports[cylinder.joint_id]:
                if joint > 0:
                    support[row, self.model.joints[joint].idx_v] = 1.0
        self.cylinder_support = support

    # --- sizes -----------------------------------------------------------------
    @property
    def n_joints(self) -> int:
        return int(self.model.nv)

    @property
    def gravity_acceleration(self) -> float:
        return float(np.linalg.norm(self.model.gravity.linear))

    def create_data(self) -> pin.Data:
        """A new Pinocchio workspace for this arm's model."""
        return self.model.createData()

    def _data(self, data: pin.Data | None) -> pin.Data:
        return self.model.createData() if data is None else data

    # --- dry rigid-body dynamics ---------------------------------------------
    def mass_matrix(self, q: np.ndarray, *, data: pin.Data | None = None) -> np.ndarray:
        """Joint-space inertia M(q), shape (n, n), symmetric (CRBA)."""
        data = self._data(data)
        mass = pin.crba(self.model, data, _vec(q, self.n_joints, "q"))
        return fixed_order.symmetrize(mass)

    def coriolis_matrix(self, q: np.ndarray, v: np.ndarray, *, data: pin.Data | None = None) -> np.ndarray:
        """C(q, v), shape (n, n), with M' - 2C skew-symmetric."""
        data = self._data(data)
        return pin.computeCoriolisMatrix(
            self.model, data, _vec(q, self.n_joints, "q"), _vec(v, self.n_joints, "v")
        ).copy()

    def gravity(self, q: np.ndarray, *, data: pin.Data | None = None) -> np.ndarray:
        """G(q) (N m), shape (n,): the torque that holds the dry arm still."""
        data = self._data(data)
        return pin.computeGeneralizedGravity(self.model, data, _vec(q, self.n_joints, "q")).copy()

    def nonlinear_effects(self, q: np.ndarray, v: np.ndarray, *, data: pin.Data | None = None) -> np.ndarray:
        """C(q, v) v + G(q) (N m), shape (n,)."""
        data = self._data(data)
        return pin.nonLinearEffects(self.model, data, q, v).copy()

    def inverse_dynamics(
        self, q: np.ndarray, v: np.ndarray, a: np.ndarray, *, data: pin.Data | None = None
    ) -> np.ndarray:
        """tau = M a + C v + G (RNEA), shape (n,)."""
        data = self._data(data)
        n = self.n_joints
        return pin.rnea(self.model, data, _vec(q, n, "q"), _vec(v, n, "v"), _vec(a, n, "a")).copy()

    def forward_dynamics(
        self, q: np.ndarray, v: np.ndarray, tau: np.ndarray, *, data: pin.Data | None = None
    ) -> np.ndarray:
        """q'' = M^-1 (tau - C v - G) (ABA), shape (n,)."""
        data = self._data(data)
        n = self.n_joints
        return pin.aba(self.model, data, _vec(q, n, "q"), _vec(v, n, "v"), _vec(tau, n, "tau")).copy()

    def forward_dynamics_derivatives(
        self, q: np.ndarray, v: np.ndarray, tau: np.ndarray, *, data: pin.Data | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Analytical derivatives of ABA (Carpentier & Mansard 2018).

        Returns ``(qdd, dqdd_dq, dqdd_dv, dqdd_dtau)``: the acceleration (n,) and
        its Jacobians (n, n) each; ``dqdd_dtau`` is M(q)^-1.
        """
        data = self._data(data)
        pin.computeABADerivatives(self.model, data, q, v, tau)
        minv = fixed_order.symmetrize(data.Minv)
        return data.ddq.copy(), data.ddq_dq.copy(), data.ddq_dv.copy(), minv

    def inverse_dynamics_derivatives(
        self, q: np.ndarray, v: np.ndarray, a: np.ndarray, *, data: pin.Data | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Analytical derivatives of RNEA: ``(dtau_dq, dtau_dv, M)``, each (n, n)."""
        data = self._data(data)
        pin.computeRNEADerivatives(self.model, data, q, v, a)
        mass = fixed_order.symmetrize(data.M)
        return data.dtau_dq.copy(), data.dtau_dv.copy(), mass

    def kinetic_energy(self, q: np.ndarray, v: np.ndarray, *, data: pin.Data | None = None) -> float:
        """1/2 v^T M v (J)."""
        data = self._data(data)
        return float(pin.computeKineticEnergy(self.model, data, q, v))

    def potential_energy(self, q: np.ndarray, *, data: pin.Data | None = None) -> float:
        """Gravity potential of the dry arm (J), zero at the base height."""
        data = self._data(data)
        return float(pin.computePotentialEnergy(self.model, data, q))

    def joint_placements(self, q: np.ndarray, *, data: pin.Data | None = None) -> list[pin.SE3]:
        """World placement of every joint's body frame (Pinocchio ``oMi``), n items."""
        data = self._data(data)
        pin.forwardKinematics(self.model, data, _vec(q, self.n_joints, "q"))
        return [data.oMi[i].copy() for i in range(1, self.model.njoints)]

    def cylinder_endpoints(self, q: np.ndarray, *, data: pin.Data | None = None) -> np.ndarray:
        """World coordinates of every cylinder's ends, shape (n_cylinders, 2, 3) (m)."""
        data = self._data(data)
        pin.forwardKinematics(self.model, data, _vec(q, self.n_joints, "q"))
        out = np.empty((len(self.cylinders), 2, 3))
        for row, cylinder in enumerate(self.cylinders):
            placement = data.oMi[cylinder.joint_id]
            out[row, 0] = placement.act(cylinder.start)
            out[row, 1] = placement.act(cylinder.end)
        return out


def _vec(x: np.ndarray, n: int, name: str) -> np.ndarray:
    arr = np.asarray(x, dtype=float)
    if arr.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {arr.shape}")
    return arr


def build_arm(spec: ArmSpec) -> Arm:
    """Build the Pinocchio model and wetted cylinders of an :class:`ArmSpec`."""
    model = pin.Model()
    model.name = spec.name
    model.gravity = pin.Motion(np.array([0.0, 0.0, -spec.gravity]), np.zeros(3))
    parent = 0
    placement = pin.SE3.Identity()
    cylinders = []
    for index, link in enumerate(spec.links):
        joint_id = model.addJoint(parent, pin.JointModelRZ(), placement, f"joint{index + 1}")
        com, tensor = link.inertia_in_body_frame()
        model.appendBodyToJoint(joint_id, pin.Inertia(link.mass, com, tensor), pin.SE3.Identity())
        model.addFrame(pin.Frame(link.name, joint_id, pin.SE3.Identity(), pin.FrameType.BODY))
        length = link.cylinder_length
        area = math.pi * link.cylinder_diameter**2 / 4.0
        volume = link.buoyancy_kg / REFERENCE_WATER_DENSITY if link.buoyancy_kg is not None else area * length
        cylinders.append(
            WettedCylinder(
                name=link.name,
                joint_id=joint_id,
                start=np.zeros(3),
                end=link.cylinder_end,
                diameter=link.cylinder_diameter,
                displaced_volume=volume,
                cd_axial=link.cd_axial,
            )
        )
        placement = link.dh_transform()  # joint i+1 sits at DH frame i
        parent = joint_id
    model.addFrame(pin.Frame("flange", parent, placement, pin.FrameType.OP_FRAME))
    model.armature = per_joint(spec.armature, model.nv, "armature")
    limit = spec.torque_limit
    return Arm(name=spec.name, model=model, cylinders=tuple(cylinders), torque_limit=np.asarray(limit), spec=spec)


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
