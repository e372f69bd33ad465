"""The vehicle under the arm: a validated vehicle file -> Fossen's 6-DOF rigid body, water and thrusters.

A vehicle file (TOML or YAML, see ``hydroarm/vehicles/bluerov2_heavy.toml``) gives, in the
vehicle's body frame (x forward, y left, z up; origin = the body reference point, which the
built-in vehicle puts at its centre of gravity):

* ``mass`` (kg), ``inertia`` about the CG (kg m^2; 3 principal values or a 3 x 3 tensor),
  ``cg`` and ``cb`` (m), ``displaced_volume`` (m^3; buoyancy = rho g V at ``cb``);
* ``added_mass`` M_A (6 diagonal values or a 6 x 6 symmetric PSD matrix, order
  [X Y Z K M N], kg and kg m^2, about the body origin), with its Coriolis term C_A(nu_r);
* ``linear_damping`` and ``quadratic_damping`` (6 values each, >= 0): the damping force
  ``-(d_l + d_q |nu_r|) nu_r`` per DOF on the velocity relative to the current;
* ``thrusters``: positions and unit axes -> the 6 x n allocation matrix ``B`` (or an explicit
  ``allocation`` matrix of that shape), per-thruster limits ``[-max_reverse, max_forward]`` (N),
  and an optional first-order thrust lag ``thrust_time_constant`` (s, 0 = none);
* ``hull``: the frame's bounding box (length x width x height, centred on the body origin);
* ``replay``: the replay settings a calibration fitted together with this file (``hydroarm
  calibrate`` writes them, ``hydroarm replay`` applies them under any ``--set``);
* ``mount``: where the arm sits (``arm``, ``position``, ``rpy_deg``); a mount outside the hull
  box is allowed with a warning (a real arm often sits on a bracket ahead of the frame);
* ``[[ballast]]`` and ``[[float]]``: extra point loads as tested (weights, foam blocks, a DVL),
  each a ``mass`` (kg, dry) and/or a ``volume`` (m^3, displaced) at a ``position`` (m). They are
  lumped exactly into the rigid body (mass, CG and inertia of the point masses added) and the
  buoyancy (volumes added, the centre of buoyancy their volume-weighted centroid); a ballast
  needs a mass > 0, a float a volume > 0. A weight known only by its weight in water is a
  ballast with ``mass`` = its water weight / g and no volume (the same force and moment);
* ``thrusters`` may be empty: a passive vehicle (the allocation matrix is 6 x 0).

Validation names the field and its allowed range (:class:`~hydroarm.config.ConfigError`).
The equations and their sources are in ``docs/vehicle.md``; the forces are in
:func:`vehicle_generalised_force` (compiled).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Annotated, Self

import numba
import numpy as np
import pinocchio as pin
import pydantic

from hydroarm.config import ConfigError, FrozenModel, field_error, load_model

BUILTIN_VEHICLES = ("bluerov2-heavy",)
"""The built-in vehicles' names (``bluerov2_heavy``, with an underscore, names the same one)."""
MAX_LENGTH = 100.0
"""m: bound on every coordinate in a vehicle file."""

Coordinate = Annotated[float, pydantic.Field(ge=-MAX_LENGTH, le=MAX_LENGTH)]
Vector3 = Annotated[list[Coordinate], pydantic.Field(min_length=3, max_length=3)]
Entry = Annotated[float, pydantic.Field(ge=-1e6, le=1e6)]
NonNegative = Annotated[float, pydantic.Field(ge=0.0, le=1e6)]
Six = Annotated[list[NonNegative], pydantic.Field(min_length=6, max_length=6)]
Row = Annotated[list[Entry], pydantic.Field(min_length=1, max_length=64)]


class ThrusterSpec(FrozenModel):
    """One thruster: ``position`` (m) and thrust ``axis`` (a direction, normalised here) in the
    body frame; thrust limits ``max_forward`` and ``max_reverse`` (N, > 0): the force along
    ``axis`` lies in ``[-max_reverse, max_forward]``."""

    name: str = pydantic.Field(min_length=1)
    position: Vector3
    axis: Vector3
    max_forward: float = pydantic.Field(gt=0.0, le=1e6, description="N")
    max_reverse: float = pydantic.Field(gt=0.0, le=1e6, description="N")

    @pydantic.model_validator(mode="after")
    def _check(self) -> Self:
        if float(np.linalg.norm(self.axis)) <= 1e-9:
            raise field_error("axis", self.axis, "has zero length: give the thrust direction (any length > 0)")
        return self


class PointLoadSpec(FrozenModel):
    """An extra point load on the vehicle: ``mass`` (kg, >= 0) and ``volume`` (m^3, >= 0,
    displaced) at ``position`` (m, body frame)."""

    name: str = ""
    mass: float = pydantic.Field(0.0, ge=0.0, le=1e4, description="dry mass (kg)")
    volume: float = pydantic.Field(0.0, ge=0.0, le=10.0, description="displaced volume (m^3)")
    position: Vector3


class HullSpec(FrozenModel):
    """The frame's bounding box, centred on the body origin: 0 < length, width, height <= 100 m."""

    length: float = pydantic.Field(gt=0.0, le=MAX_LENGTH, description="along x (m)")
    width: float = pydantic.Field(gt=0.0, le=MAX_LENGTH, description="along y (m)")
    height: float = pydantic.Field(gt=0.0, le=MAX_LENGTH, description="along z (m)")

    @property
    def half_extents(self) -> np.ndarray:
        return 0.5 * np.array([self.length, self.width, self.height])


class MountSpec(FrozenModel):
    """Where the arm's base frame sits in the vehicle's body frame: ``position`` (m, inside the
    hull box) and ``rpy_deg`` (roll, pitch, yaw in degrees, URDF convention R = Rz Ry Rx);
    ``arm``: a built-in arm name or an arm file (``hydroarm.model.arm.loading.load_arm``)."""

    arm: str = "alpha5"
    position: Vector3
    rpy_deg: Annotated[list[Annotated[float, pydantic.Field(ge=-360.0, le=360.0)]], pydantic.Field(
        min_length=3, max_length=3
    )] = [0.0, 0.0, 0.0]  # fmt: skip

    def placement(self) -> pin.SE3:
        """The arm base frame's placement in the vehicle body frame."""
        return pin.SE3(pin.rpy.rpyToMatrix(*np.radians(self.rpy_deg)), np.asarray(self.position, dtype=float))


class VehicleSpec(FrozenModel):
    """A whole vehicle file (see the module docstring for every field and its units)."""

    model_config = pydantic.ConfigDict(populate_by_name=True)

    name: str = pydantic.Field(min_length=1)
    description: str = ""
    source: str = ""
    mass: float = pydantic.Field(gt=0.0, le=1e5, description="dry mass (kg)")
    inertia: list[Entry] | list[list[Entry]] = pydantic.Field(
        description="about the CG (kg m^2): 3 principal values or a 3 x 3 tensor"
    )
    cg: Vector3 = pydantic.Field(description="centre of gravity in the body frame (m)")
    cb: Vector3 = pydantic.Field(description="centre of buoyancy in the body frame (m)")
    displaced_volume: float = pydantic.Field(ge=0.0, le=1e3, description="m^3")
    added_mass: list[Entry] | list[list[Entry]] = pydantic.Field(
        description="[X Y Z K M N]: 6 diagonal values >= 0, or a 6 x 6 symmetric PSD matrix (kg, kg m, kg m^2)"
    )
    linear_damping: Six = pydantic.Field(description="d_l per DOF (N s/m, N m s/rad)")
    quadratic_damping: Six = pydantic.Field(description="d_q per DOF (N s^2/m^2, N m s^2/rad^2)")
    thrust_time_constant: float = pydantic.Field(0.0, ge=0.0, le=10.0, description="first-order thrust lag (s)")
    hull: HullSpec
    thrusters: list[ThrusterSpec] = pydantic.Field(default_factory=list, max_length=32)
    ballast: list[PointLoadSpec] = pydantic.Field(default_factory=list, max_length=64)
    floats: list[PointLoadSpec] = pydantic.Field(
        default_factory=list, max_length=64, alias="float", description="foam blocks and other floats"
    )
    allocation: list[Row] | None = pydantic.Field(
        None, description="explicit 6 x n_thrusters allocation matrix (default: from positions and axes)"
    )
    mount: MountSpec
    replay: dict[str, float | list[float]] = pydantic.Field(
        default_factory=dict,
        description="the settings of `hydroarm replay` that a calibration fitted with this file "
        "(joint_time_offset, trim, imu_mounting_rpy_deg); replay applies them, a --set wins",
    )

    @pydantic.model_validator(mode="after")
    def _check(self) -> Self:
        _check_square("inertia", self.inertia, 3, "principal values (kg m^2)")
        _check_square("added_mass", self.added_mass, 6, "diagonal values [X Y Z K M N] (kg, kg m^2)")
        if not isinstance(self.added_mass[0], list) and min(self.added_mass) < 0.0:
            raise field_error("added_mass", self.added_mass, "diagonal values must be >= 0")
        if isinstance(self.inertia[0], list):
            tensor = np.asarray(self.inertia, dtype=float)
            if not np.allclose(tensor, tensor.T, rtol=0.0, atol=1e-12):
                raise field_error("inertia", self.inertia, "must be symmetric")
        else:
            tensor = np.diag(self.inertia)
        eig = np.linalg.eigvalsh(tensor)
        if eig[0] <= 0.0:
            raise field_error("inertia", self.inertia, f"must be positive definite (eigenvalues {eig.tolist()})")
        if eig[2] > eig[0] + eig[1] + 1e-12:
            raise field_error("inertia", self.inertia, "violates the triangle inequality: not a rigid body")
        if isinstance(self.added_mass[0], list):
            matrix = np.asarray(self.added_mass, dtype=float)
            if not np.allclose(matrix, matrix.T, rtol=0.0, atol=1e-9):
                raise field_error("added_mass", self.added_mass, "the 6 x 6 matrix must be symmetric")
            if np.linalg.eigvalsh(matrix)[0] < -1e-9:
                raise field_error("added_mass", self.added_mass, "the 6 x 6 matrix must be positive semidefinite")
        n = len(self.thrusters)
        if self.allocation is not None:
            shape = (len(self.allocation), {len(row) for row in self.allocation})
            if shape[0] != 6 or shape[1] != {n}:
                raise field_error(
                    "allocation",
                    self.allocation,
                    f"must be 6 rows (X Y Z K M N) of {n} columns (one per thruster), "
                    f"got {shape[0]} rows of {sorted(shape[1])} columns",
                )
        half = self.hull.half_extents
        for axis, (value, limit, size) in enumerate(
            zip(self.mount.position, half.tolist(), ("length", "width", "height"))
        ):
            if abs(value) > limit + 1e-12:
                warnings.warn(
                    f"vehicle {self.name!r}: mount.position {'xyz'[axis]} = {value!r} m is outside the hull's "
                    f"frame range [{-limit!r}, {limit!r}] m (+-hull.{size}/2): the arm sits off the frame",
                    stacklevel=2,
                )
        for index, load in enumerate(self.ballast):
            if load.mass <= 0.0:
                raise field_error(f"ballast.{index}.mass", load.mass, "a ballast needs a mass > 0 (kg)")
        for index, load in enumerate(self.floats):
            if load.volume <= 0.0:
                raise field_error(f"float.{index}.volume", load.volume, "a float needs a volume > 0 (m^3)")
        names = [t.name for t in self.thrusters]
        for index, name in enumerate(names):
            if name in names[:index]:
                raise field_error(f"thrusters.{index}.name", name, "thruster names must differ")
        return self


def _check_square(name: str, value: list, n: int, what: str) -> None:
    """``value`` must be n numbers or n rows of n numbers."""
    rows = all(isinstance(row, list) for row in value)
    if rows and len(value) == n and all(len(row) == n for row in value):
        return
    if not rows and len(value) == n and not any(isinstance(x, list) for x in value):
        return
    raise field_error(name, value, f"give {n} {what} or {n} rows of {n} numbers")


@dataclass(frozen=True)
class Vehicle:
    """A vehicle's constants as arrays (built by :func:`build_vehicle`), body frame, SI units.

    ``inertia`` (3, 3) about ``cg``; ``added_mass`` (6, 6) about the body origin;
    ``allocation`` (6, n_thr): body wrench = ``allocation @ thrust``; ``thrust_min`` /
    ``thrust_max`` (n_thr,) in N; ``mount`` the arm base's placement in the body frame.
    """

    name: str
    mass: float
    inertia: np.ndarray
    cg: np.ndarray
    cb: np.ndarray
    displaced_volume: float
    added_mass: np.ndarray
    linear_damping: np.ndarray
    quadratic_damping: np.ndarray
    allocation: np.ndarray
    thrust_min: np.ndarray
    thrust_max: np.ndarray
    thrust_time_constant: float
    hull: np.ndarray
    mount: pin.SE3
    mount_arm: str
    spec: VehicleSpec | None = None

    @property
    def n_thrusters(self) -> int:
        return int(self.allocation.shape[1])

    def rigid_inertia(self) -> pin.Inertia:
        """The dry rigid body as a Pinocchio inertia about the body origin."""
        return pin.Inertia(self.mass, self.cg, self.inertia)

    def clip_thrust(self, command: np.ndarray) -> np.ndarray:
        """Per-thruster saturation: ``command`` (N) clipped to ``[thrust_min, thrust_max]``."""
        return np.clip(command, self.thrust_min, self.thrust_max)


def allocation_matrix(positions: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """6 x n allocation matrix of thrusters at ``positions`` (n, 3) along ``axes`` (n, 3):
    column i = [e_i, r_i x e_i] with e_i the unit axis (force and moment about the origin)."""
    positions = np.asarray(positions, dtype=float).reshape(-1, 3)
    units = np.asarray(axes, dtype=float).reshape(-1, 3)
    units = units / np.linalg.norm(units, axis=1, keepdims=True)
    return np.vstack([units.T, np.cross(positions, units).T])


def build_vehicle(spec: VehicleSpec) -> Vehicle:
    """Arrays of a :class:`VehicleSpec`."""
    inertia = np.asarray(spec.inertia, dtype=float)
    inertia = inertia if inertia.ndim == 2 else np.diag(inertia)
    added = np.asarray(spec.added_mass, dtype=float)
    added = added if added.ndim == 2 else np.diag(added)
    positions = np.asarray([t.position for t in spec.thrusters], dtype=float).reshape(-1, 3)
    axes = np.asarray([t.axis for t in spec.thrusters], dtype=float).reshape(-1, 3)
    if spec.allocation is not None:
        allocation = np.asarray(spec.allocation, dtype=float)
    elif positions.shape[0]:
        allocation = allocation_matrix(positions, axes)
    else:
        allocation = np.zeros((6, 0))
    mass, cg, inertia, volume, cb = lump_point_loads(spec, inertia)
    return Vehicle(
        name=spec.name,
        mass=mass,
        inertia=inertia,
        cg=cg,
        cb=cb,
        displaced_volume=volume,
        added_mass=0.5 * (added + added.T),
        linear_damping=np.asarray(spec.linear_damping, dtype=float),
        quadratic_damping=np.asarray(spec.quadratic_damping, dtype=float),
        allocation=np.ascontiguousarray(allocation, dtype=float),
        thrust_min=-np.asarray([t.max_reverse for t in spec.thrusters], dtype=float),
        thrust_max=np.asarray([t.max_forward for t in spec.thrusters], dtype=float),
        thrust_time_constant=spec.thrust_time_constant,
        hull=spec.hull.half_extents * 2.0,
        mount=spec.mount.placement(),
        mount_arm=spec.mount.arm,
        spec=spec,
    )


def lump_point_loads(spec: VehicleSpec, inertia: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, float, np.ndarray]:
    """``(mass, cg, inertia about cg, displaced volume, cb)`` of the hull with its ballast and
    floats (every load's mass a point mass, its volume a point volume); without loads the
    file's own numbers, unchanged."""
    loads = [*spec.ballast, *spec.floats]
    cg = np.asarray(spec.cg, dtype=float)
    cb = np.asarray(spec.cb, dtype=float)
    if not loads:
        return spec.mass, cg, inertia, spec.displaced_volume, cb
    body = pin.Inertia(spec.mass, cg, inertia)
    volume = spec.displaced_volume
    moment = volume * cb
    for load in loads:
        position = np.asarray(load.position, dtype=float)
        if load.mass > 0.0:
            body = body + pin.Inertia(load.mass, position, np.zeros((3, 3)))
        volume += load.volume
        moment = moment + load.volume * position
    lumped_cb = moment / volume if volume > 0.0 else cb
    return float(body.mass), np.array(body.lever), np.array(body.inertia), float(volume), lumped_cb


def builtin_vehicle_name(source: str | Path) -> str | None:
    """The built-in vehicle ``source`` names, in its one spelling (``bluerov2-heavy``; ``_`` and
    ``-`` and the case alike), or None if it names none."""
    if not isinstance(source, str):
        return None
    key = source.strip().lower().replace("_", "-")
    return key if key in BUILTIN_VEHICLES else None


def builtin_vehicle_path(name: str) -> Path:
    """The file of the built-in vehicle ``name`` (either spelling)."""
    canonical = builtin_vehicle_name(name) or name
    return Path(str(resources.files("hydroarm") / "vehicles" / f"{canonical.replace('-', '_')}.toml"))


def load_vehicle_spec(source: str | Path = "bluerov2-heavy") -> VehicleSpec:
    """Read and validate a vehicle file, or a built-in vehicle by name (either spelling)."""
    if builtin_vehicle_name(source) is not None:
        return load_model(VehicleSpec, builtin_vehicle_path(source))
    path = Path(source)
    if not str(source) or not path.is_file():
        raise ConfigError(
            f"vehicle {str(source)!r}: neither a built-in vehicle ({', '.join(BUILTIN_VEHICLES)}) nor an existing file"
        )
    spec = load_model(VehicleSpec, path)
    beside = path.parent / spec.mount.arm
    if not Path(spec.mount.arm).is_absolute() and beside.is_file():  # an arm file next to the vehicle file
        spec = spec.model_copy(update={"mount": spec.mount.model_copy(update={"arm": str(beside.resolve())})})
    return spec


def load_vehicle(source: str | Path = "bluerov2-heavy") -> Vehicle:
    """Load a vehicle: ``"bluerov2-heavy"`` (or ``"bluerov2_heavy"``) or a vehicle file (TOML/YAML)."""
    return build_vehicle(load_vehicle_spec(source))


# --- the forces on the root (compiled) ----------------------------------------------------


def body_rotation(pose: np.ndarray) -> np.ndarray:
    """R (3, 3), body to world, of a pose ``[p (3), quaternion x y z w (4)]`` (its first 7
    entries are read): Pinocchio's quaternion (normalised by it). The controllers' way to the
    pose algebra (they do not import Pinocchio)."""
    return pin.Quaternion(pose[6], *pose[3:6]).toRotationMatrix()


def rotation_log(rotation: np.ndarray) -> np.ndarray:
    """The rotation vector (3,) rad of ``rotation`` (3, 3): SO(3)'s logarithm (Pinocchio's ``log3``)."""
    return pin.log3(rotation)


@numba.njit(cache=True)
def quaternion_matrix(x, y, z, w):  # pragma: no cover - compiled
    """Rotation matrix of the unit quaternion (x, y, z, w) (Pinocchio's order)."""
    out = np.empty((3, 3))
    out[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    out[0, 1] = 2.0 * (x * y - z * w)
    out[0, 2] = 2.0 * (x * z + y * w)
    out[1, 0] = 2.0 * (x * y + z * w)
    out[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    out[1, 2] = 2.0 * (y * z - x * w)
    out[2, 0] = 2.0 * (x * z - y * w)
    out[2, 1] = 2.0 * (y * z + x * w)
    out[2, 2] = 1.0 - 2.0 * (x * x + y * y)
    return out


@numba.njit(cache=True)
def _cross(a, b):  # pragma: no cover - compiled
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


@numba.njit(cache=True)
def vehicle_generalised_force(
    nu, rot, water_velocity, added_mass, linear_damping, quadratic_damping, buoyancy, cb,
    use_added_mass, use_drag, use_buoyancy,
):  # fmt: skip  # pragma: no cover - compiled
    """Water and buoyancy wrench on the vehicle body (6,), body frame, at the body origin,
    without the ``-M_A nu'`` part (that one is in the mass matrix that is solved).

    ``nu`` = [u v w p q r] body velocity; ``rot`` body-to-world rotation; ``water_velocity``
    the current in the world frame (constant in time over the evaluation). With
    ``nu_c = [R^T V_c, 0]`` and ``nu_r = nu - nu_c``:

    * added mass: ``-M_A nu_r' - C_A(nu_r) nu_r`` where ``nu_r' = nu' - nu_c'`` and
      ``nu_c' = [-omega x R^T V_c, 0]``; ``C_A(nu_r) nu_r = nu_r x* (M_A nu_r)`` (Fossen's C_A);
      returned: ``M_A nu_c' - C_A(nu_r) nu_r``;
    * damping: ``-(d_l + d_q |nu_r|) nu_r`` per DOF;
    * buoyancy: ``B = buoyancy`` (N) up in the world, at ``cb``: ``[R^T B e_z, cb x R^T B e_z]``.

    The weight is not here: Pinocchio's gravity acts on the rigid body.
    """
    out = np.zeros(6)
    current = np.empty(3)
    for i in range(3):
        current[i] = rot[0, i] * water_velocity[0] + rot[1, i] * water_velocity[1] + rot[2, i] * water_velocity[2]
    rel = nu.copy()
    for i in range(3):
        rel[i] -= current[i]
    omega = nu[3:]
    if use_added_mass:
        momentum = added_mass @ rel
        lin = momentum[:3]
        ang = momentum[3:]
        a = _cross(omega, lin)  # linear part of nu_r x* p uses nu_r's angular part = omega
        b = _cross(omega, ang) + _cross(rel[:3], lin)
        drift = -_cross(omega, current)  # nu_c' (linear part)
        for i in range(6):
            out[i] += added_mass[i, 0] * drift[0] + added_mass[i, 1] * drift[1] + added_mass[i, 2] * drift[2]
        for i in range(3):
            out[i] -= a[i]
            out[3 + i] -= b[i]
    if use_drag:
        for i in range(6):
            out[i] -= (linear_damping[i] + quadratic_damping[i] * abs(rel[i])) * rel[i]
    if use_buoyancy and buoyancy != 0.0:
        force = np.array([rot[2, 0] * buoyancy, rot[2, 1] * buoyancy, rot[2, 2] * buoyancy])
        moment = _cross(cb, force)
        for i in range(3):
            out[i] += force[i]
            out[3 + i] += moment[i]
    return out
