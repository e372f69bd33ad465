"""The hydrodynamics file of a URDF arm, as validated data (format: :mod:`hydroarm.model.arm.urdf_import`)."""

from __future__ import annotations

from typing import Annotated, Literal, Self

import numpy as np
import pydantic

from hydroarm.config import FrozenModel, field_error
from hydroarm.model.arm.description import TorqueLimit

Coordinate = Annotated[float, pydantic.Field(ge=-100.0, le=100.0)]
Vector3 = Annotated[list[Coordinate], pydantic.Field(min_length=3, max_length=3)]
Coefficient = Annotated[float, pydantic.Field(ge=0.0, le=10.0)]
Volume = Annotated[float, pydantic.Field(ge=0.0, le=1e3)]
Armature = Annotated[float, pydantic.Field(ge=0.0, le=1e4)]

HYDRO_SUFFIXES = (".hydro.toml", ".hydro.yaml", ".hydro.yml")
REVOLUTE_JOINTS = ("JointModelRX", "JointModelRY", "JointModelRZ", "JointModelRevoluteUnaligned")


class CylinderSpec(FrozenModel):
    """One explicit wetted cylinder in a URDF link's frame.

    Give ``start`` and ``end`` (m), or ``length`` (m), ``axis`` (a direction,
    normalised here) and ``offset`` (the centre, m; default the link origin).
    ``cd``/``cm``/``cd_axial`` override the link's coefficients; ``displaced_volume`` (m^3)
    its share of the link's. Ranges: 0 < diameter <= 10 m, 1e-6 <= length <= 100 m,
    coordinates within +-100 m, 0 <= displaced_volume <= 1000 m^3, coefficients in [0, 10].
    """

    diameter: float = pydantic.Field(gt=0.0, le=10.0, description="m")
    start: Vector3 | None = None
    end: Vector3 | None = None
    length: float | None = pydantic.Field(None, ge=1e-6, le=100.0, description="m")
    axis: Vector3 | None = None
    offset: Vector3 | None = None
    cd: Coefficient | None = None
    cm: Coefficient | None = None
    cd_axial: Coefficient | None = pydantic.Field(
        None, description="axial drag coefficient C_a on the end area (-); default: the link's"
    )
    displaced_volume: Volume | None = pydantic.Field(
        None, description="m^3; default: its share of the link's displaced_volume, or its own volume"
    )

    @pydantic.model_validator(mode="after")
    def _check(self) -> Self:
        ends = self.start is not None or self.end is not None
        polar = self.length is not None or self.axis is not None or self.offset is not None
        if ends and polar:
            name = "start" if self.start is not None else "end"
            raise field_error(name, getattr(self, name), "give either start/end or length/axis/offset, not both")
        if ends:
            if self.start is None or self.end is None:
                missing = "start" if self.start is None else "end"
                raise field_error(missing, None, "start and end go together: give both (m)")
            if np.linalg.norm(np.subtract(self.end, self.start)) <= 1e-9:
                raise field_error("end", self.end, "start and end coincide: the cylinder has no length")
        else:
            if self.length is None or self.axis is None:
                missing = "length" if self.length is None else "axis"
                raise field_error(
                    missing, None, "missing geometry: give start and end, or length and axis (and offset)"
                )
            if np.linalg.norm(self.axis) <= 1e-9:
                raise field_error("axis", self.axis, "must be a non-zero direction")
        return self

    def endpoints(self) -> tuple[np.ndarray, np.ndarray]:
        """(start, end) in the link frame (m), shape (3,) each."""
        if self.start is not None and self.end is not None:
            return np.asarray(self.start, dtype=float), np.asarray(self.end, dtype=float)
        axis = np.asarray(self.axis, dtype=float)
        axis = axis / np.linalg.norm(axis)
        centre = np.zeros(3) if self.offset is None else np.asarray(self.offset, dtype=float)
        half = 0.5 * float(self.length) * axis
        return centre - half, centre + half


class LinkHydroSpec(FrozenModel):
    """The wetted cylinders of one URDF link and their coefficients."""

    link: str = pydantic.Field(min_length=1, description="URDF link name")
    collision: bool | list[Annotated[int, pydantic.Field(ge=0)]] = pydantic.Field(
        False, description="use the link's URDF <collision> cylinders: all (true) or these indices"
    )
    cylinders: list[CylinderSpec] = pydantic.Field(default_factory=list, max_length=64)
    cd: Coefficient | None = None
    cm: Coefficient | None = None
    cd_axial: Coefficient = pydantic.Field(
        0.0, description="axial drag coefficient C_a of the link's cylinders on their end area; 0 = none (-)"
    )
    displaced_volume: Volume | None = pydantic.Field(
        None, description="m^3 for the whole link; default: the cylinders' volume"
    )
    buoyancy_center: Vector3 | None = pydantic.Field(
        None,
        description="m, link frame: the link's whole displaced_volume acts here as one point, independent "
        "of its wetted cylinders (which then keep their drag and added mass only); default: each cylinder's midpoint",
    )

    @pydantic.model_validator(mode="after")
    def _check(self) -> Self:
        if self.buoyancy_center is not None and self.displaced_volume is None:
            raise field_error(
                "displaced_volume", None, "a buoyancy_center needs the link's displaced_volume (m^3) beside it"
            )
        if self.collision is False or self.collision == []:
            if not self.cylinders and self.buoyancy_center is None:
                raise field_error("collision", self.collision, "no cylinders: set collision = true or give cylinders")
        return self


class HydroSpec(FrozenModel):
    """A whole hydrodynamics file (see the module docstring)."""

    name: str | None = None
    description: str = ""
    source: str = ""
    urdf: str | None = pydantic.Field(None, description="URDF path, relative to this file")
    gravity: float = pydantic.Field(9.81, gt=0.0, le=100.0, description="m/s^2 along -z of the root")
    torque_limit: list[TorqueLimit] | TorqueLimit | None = pydantic.Field(
        None, description="N m, one value or one per moving joint; default: the URDF efforts"
    )
    armature: list[Armature] | Armature = pydantic.Field(
        0.0, description="reflected rotor inertia (kg m^2), one value or one per moving joint; 0 = none"
    )
    fixed_joints: dict[str, Annotated[float, pydantic.Field(ge=-100.0, le=100.0)]] = pydantic.Field(
        default_factory=dict, description="joint name -> locked position (rad or m)"
    )
    joint_offsets: dict[str, Annotated[float, pydantic.Field(ge=-10.0, le=10.0)]] = pydantic.Field(
        default_factory=dict,
        description="joint name -> zero offset o (rad): the URDF's angle is sign * (q - o), q the arm's (the "
        "encoder's) angle",
    )
    joint_signs: dict[str, Literal[1, -1]] = pydantic.Field(
        default_factory=dict, description="joint name -> sign (+1 or -1) of the arm's angle against the URDF's"
    )
    all_collision_cylinders: bool = False
    links: list[LinkHydroSpec] = pydantic.Field(default_factory=list, max_length=64)

    @pydantic.model_validator(mode="after")
    def _check(self) -> Self:
        names = [link.link for link in self.links]
        for index, name in enumerate(names):
            if name in names[:index]:
                raise field_error(f"links.{index}.link", name, f"listed twice (links.{names.index(name)} too)")
        return self
