"""Bring your own arm: a URDF plus a small hydrodynamics file -> an :class:`~hydroarm.model.arm.description.Arm`.

The URDF gives the dry rigid body (Pinocchio's own URDF parser builds the
model: links attached by fixed joints are merged into their parent joint's
body, as Pinocchio always does). The hydrodynamics file (TOML or YAML) says
which parts of which links the water acts on::

    name = "myarm"                      # default: the URDF's robot name
    urdf = "myarm.urdf"                 # relative to this file (when loading the file itself)
    gravity = 9.81                      # m/s^2 along -z of the URDF root link
    torque_limit = [20.0, 20.0, 10.0]   # N m, optional: default the URDF <limit effort>
    armature = 0.0                      # kg m^2, reflected rotor inertia: one value or one per joint
    fixed_joints = { gripper = 0.0 }    # lock joints (e.g. a prismatic jaw) at a position
    all_collision_cylinders = false     # true: every <collision> cylinder of every link is wet
    joint_offsets = { wrist = 2.879 }   # rad: the URDF angle is sign * (q - offset), q the encoder's
    joint_signs = { elbow = -1 }        # +1 (default) or -1

    [[links]]
    link = "upper_arm"                  # a URDF link name
    collision = true                    # its URDF <collision><cylinder>s (or a list of indices)
    cd = 1.0                            # Morison drag coefficient (default: Water.cd)
    cm = 2.0                            # added-mass coefficient (default: Water.cm)
    displaced_volume = 1.2e-3           # m^3 for the whole link (default: the cylinders' volume)
    buoyancy_center = [0.1, 0.0, 0.0]   # optional (m, link frame): the volume acts here, as a point

    [[links]]
    link = "forearm"
    [[links.cylinders]]                 # explicit cylinders, in the link frame (m)
    diameter = 0.06
    length = 0.3
    axis = [1.0, 0.0, 0.0]              # direction of the cylinder's axis
    offset = [0.15, 0.0, 0.0]           # centre of the cylinder (as a URDF <origin xyz>)
    # or: start = [0, 0, 0] and end = [0.3, 0, 0]

Only revolute (and continuous) joints may move: the water kernel handles
revolute joints only, so any other joint (a prismatic jaw) must be listed in
``fixed_joints``. A continuous joint becomes a revolute joint with no position
limit (``position_limit`` = +-inf). A link's ``displaced_volume`` is split
over its cylinders in proportion to their volumes; with a ``buoyancy_center`` it acts at that
point instead (a buoyancy-only element: no drag, no added mass) and the cylinders carry none.

A joint's zero offset o and sign s make the arm's angle q the encoder's: the URDF's angle is
s (q - o). They are applied to the URDF before Pinocchio reads it, exactly: the joint's origin
becomes origin * R(axis, -s o), its axis s * axis, and its limits s * limit + o.

Every wetted cylinder ends up as a :class:`~hydroarm.model.arm.description.WettedCylinder` in
the body frame of the Pinocchio joint that carries the link: a URDF link hung
on a fixed joint is placed with Pinocchio's frame placement
(``model.frames[fid].placement`` in joint ``parentJoint``). Cylinders on links
fixed to the base (joint 0) exert no joint torque but are kept (drawn by
:mod:`hydroarm.studies.animate`, written to MJCF).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from hydroarm.config import ConfigError, not_a_file, read_mapping, shown, validate
from hydroarm.model.arm.description import Arm, WettedCylinder, coefficient
from hydroarm.model.arm.hydro_spec import HYDRO_SUFFIXES, REVOLUTE_JOINTS, HydroSpec, LinkHydroSpec

POINT_LENGTH = 1e-6
"""m: length and diameter of a buoyancy-only element (no drag, no added mass: C_d = C_m = 0)."""

__all__ = ["HydroSpec", "LinkHydroSpec", "arm_from_urdf", "hydro_spec_of", "load_hydro_spec", "load_urdf_arm"]

# --- URDF reading ---------------------------------------------------------------


def _floats(text: str | None, count: int, default: float = 0.0) -> np.ndarray:
    if text is None or not text.strip():
        return np.full(count, default)
    try:
        values = np.asarray([float(x) for x in text.split()], dtype=float)
    except ValueError:
        values = np.zeros(0)
    if values.shape != (count,) or not np.all(np.isfinite(values)):
        raise ConfigError(f"URDF: expected {count} finite numbers, got {text!r}")
    return values


def _origin(element: ET.Element | None) -> pin.SE3:
    if element is None:
        return pin.SE3.Identity()
    xyz = _floats(element.get("xyz"), 3)
    rpy = _floats(element.get("rpy"), 3)
    return pin.SE3(pin.rpy.rpyToMatrix(*rpy), xyz)


def urdf_collision_cylinders(root: ET.Element) -> dict[str, list[tuple[int, pin.SE3, float, float] | None]]:
    """Per link, every ``<collision>`` in order: ``(index, origin, radius, length)`` for a
    cylinder, ``None`` for another shape. Origins are in the link frame."""
    out: dict[str, list] = {}
    for link in root.findall("link"):
        rows = []
        for index, collision in enumerate(link.findall("collision")):
            cylinder = collision.find("geometry/cylinder")
            if cylinder is None:
                rows.append(None)
                continue
            radius, length = (_floats(cylinder.get(name), 1, math.nan)[0] for name in ("radius", "length"))
            rows.append((index, _origin(collision.find("origin")), radius, length))
        out[link.get("name")] = rows
    return out


def _apply_offset(joint: ET.Element, offset: float, sign: int) -> None:
    """Re-zero and re-sign a revolute joint in place (module docstring)."""
    axis_element = joint.find("axis")
    axis = _floats(axis_element.get("xyz") if axis_element is not None else None, 3, 0.0)
    if axis_element is None:
        axis = np.array([1.0, 0.0, 0.0])
        axis_element = ET.SubElement(joint, "axis")
    unit = axis / np.linalg.norm(axis)
    origin = _origin(joint.find("origin")) * pin.SE3(pin.exp3(-sign * offset * unit), np.zeros(3))
    element = joint.find("origin")
    if element is None:
        element = ET.SubElement(joint, "origin")
    element.set("xyz", " ".join(repr(float(x)) for x in origin.translation))
    element.set("rpy", " ".join(repr(float(x)) for x in pin.rpy.matrixToRpy(origin.rotation)))
    axis_element.set("xyz", " ".join(repr(float(x)) for x in sign * axis))
    limit = joint.find("limit")
    if limit is not None and limit.get("lower") is not None and limit.get("upper") is not None:
        bounds = sorted(sign * float(limit.get(key)) + offset for key in ("lower", "upper"))
        limit.set("lower", repr(bounds[0]))
        limit.set("upper", repr(bounds[1]))


def _prepare_urdf(
    root: ET.Element,
    fixed: dict[str, float],
    source: str,
    offsets: dict[str, float] | None = None,
    signs: dict[str, int] | None = None,
) -> tuple[str, set[str]]:
    """Rewrite continuous joints as revolute (placeholder limits); apply the joints' zero
    offsets and signs; check joint types.

    Returns the URDF text for Pinocchio and the names of the continuous joints.
    """
    joints = {joint.get("name"): joint for joint in root.findall("joint")}
    offsets, signs = offsets or {}, signs or {}
    for field, names in (("joint_offsets", offsets), ("joint_signs", signs)):
        for name in names:
            if name not in joints or joints[name].get("type") not in ("revolute", "continuous"):
                movable = [n for n, j in joints.items() if j.get("type") in ("revolute", "continuous")]
                raise ConfigError(
                    f"{source}: {field}.{name}: no revolute joint {name!r} in the URDF: "
                    f"give one of {', '.join(movable)}"
                )
    for name in fixed:
        if name not in joints:
            raise ConfigError(
                f"{source}: fixed_joints.{name}: no joint {name!r} in the URDF: give one of {', '.join(joints)}"
            )
    continuous = set()
    for name, joint in joints.items():
        kind = joint.get("type")
        if kind == "continuous":
            continuous.add(name)
            joint.set("type", "revolute")
            limit = joint.find("limit")
            if limit is None:
                limit = ET.SubElement(joint, "limit", effort="0", velocity="0")
            limit.set("lower", repr(-math.pi))
            limit.set("upper", repr(math.pi))
        if kind in ("revolute", "continuous") and (name in offsets or name in signs):
            _apply_offset(joint, offsets.get(name, 0.0), signs.get(name, 1))
        if kind in ("revolute", "fixed", "continuous"):
            continue
        elif name not in fixed:
            raise ConfigError(
                f"{source}: joint '{name}' is {kind}: the water model supports revolute joints only; "
                f"lock it with fixed_joints = {{ {name} = 0.0 }} in the hydrodynamics file"
            )
    return ET.tostring(root, encoding="unicode"), continuous


# --- building the arm -----------------------------------------------------------


def arm_from_urdf(urdf_xml: str, hydro: HydroSpec | dict | None = None, source: str = "<hydro>") -> Arm:
    """Build an :class:`Arm` from URDF text and a hydrodynamics spec (see the module docstring).

    ``hydro`` None means every URDF collision cylinder is wet with the water's
    default coefficients. ``source`` names the hydrodynamics file in errors.
    """
    if hydro is None:
        hydro = HydroSpec(all_collision_cylinders=True)
    elif not isinstance(hydro, HydroSpec):
        hydro = validate(HydroSpec, hydro, source)
    try:
        root = ET.fromstring(urdf_xml)
    except ET.ParseError as error:
        raise ConfigError(f"URDF: cannot parse: {error}") from None
    if root.tag != "robot":
        raise ConfigError(f"URDF: the root element is <{root.tag}>, not <robot>")
    collisions = urdf_collision_cylinders(root)
    prepared, continuous = _prepare_urdf(root, hydro.fixed_joints, source, hydro.joint_offsets, hydro.joint_signs)
    try:
        model = pin.buildModelFromXML(prepared)
    except (RuntimeError, ValueError) as error:
        raise ConfigError(f"URDF: Pinocchio cannot build a model: {error}") from None
    if hydro.fixed_joints:
        q_lock = pin.neutral(model)
        locked = []
        for name, value in hydro.fixed_joints.items():
            if not model.existJointName(name):
                continue  # a fixed joint in the URDF already
            joint_id = model.getJointId(name)
            if model.joints[joint_id].nq != 1:
                raise ConfigError(f"{source}: fixed_joints.{name}: only 1-DOF joints can be locked")
            q_lock[model.joints[joint_id].idx_q] = value
            locked.append(joint_id)
        if locked:
            model = pin.buildReducedModel(model, sorted(locked), q_lock)
    model.name = hydro.name or root.get("name") or "urdf_arm"
    model.gravity = pin.Motion(np.array([0.0, 0.0, -hydro.gravity]), np.zeros(3))
    if model.nv == 0:
        raise ConfigError(f"URDF '{model.name}': no moving joint")
    for joint_id in range(1, model.njoints):
        kind = model.joints[joint_id].shortname()
        if kind not in REVOLUTE_JOINTS:
            raise ConfigError(
                f"URDF: joint '{model.names[joint_id]}' ({kind}) is not revolute: lock it with fixed_joints"
            )
    cylinders = _wetted_cylinders(model, hydro, collisions, source)
    torque_limit = _torque_limit(model, hydro, source)
    armature = np.atleast_1d(np.asarray(hydro.armature, dtype=float))
    if armature.size not in (1, model.nv):
        raise ConfigError(
            f"{source}: armature has {armature.size} values for {model.nv} joints: "
            f"{shown(hydro.armature)}; give one value or a list of {model.nv}"
        )
    model.armature = np.broadcast_to(armature, (model.nv,)).copy()
    lower = np.asarray(model.lowerPositionLimit, dtype=float).copy()
    upper = np.asarray(model.upperPositionLimit, dtype=float).copy()
    for joint_id in range(1, model.njoints):
        if model.names[joint_id] in continuous:
            index = model.joints[joint_id].idx_v
            lower[index], upper[index] = -math.inf, math.inf
    return Arm(
        name=model.name,
        model=model,
        cylinders=tuple(cylinders),
        torque_limit=torque_limit,
        spec=None,
        position_limit=np.column_stack([lower, upper]),
    )


def _torque_limit(model: pin.Model, hydro: HydroSpec, source: str) -> np.ndarray:
    """The hydrodynamics file's ``torque_limit`` (one value or one per joint), else the URDF efforts."""
    if hydro.torque_limit is not None:
        limit = np.atleast_1d(np.asarray(hydro.torque_limit, dtype=float))
        if limit.size == 1:
            limit = np.full(model.nv, limit[0])
        if limit.shape != (model.nv,):
            raise ConfigError(
                f"{source}: torque_limit has {limit.size} values for {model.nv} joints: "
                f"{shown(hydro.torque_limit)}; give one value or a list of {model.nv}"
            )
        return limit
    effort = np.asarray(model.effortLimit, dtype=float).copy()
    if np.any(~np.isfinite(effort)) or np.any(effort <= 0.0):
        raise ConfigError(
            f"{source}: the URDF gives no usable <limit effort> for every joint ({effort.tolist()}): "
            "set torque_limit in the hydrodynamics file"
        )
    return effort


def _link_frame(model: pin.Model, link: str) -> pin.Frame | None:
    if not model.existBodyName(link):
        return None
    return model.frames[model.getBodyId(link)]


def _wetted_cylinders(model: pin.Model, hydro: HydroSpec, collisions: dict, source: str) -> list[WettedCylinder]:
    entries = list(enumerate(hydro.links))
    listed = {spec.link for spec in hydro.links}
    if hydro.all_collision_cylinders:
        extra = [
            LinkHydroSpec(link=name, collision=True)
            for name, rows in collisions.items()
            if name not in listed and any(row is not None for row in rows)
        ]
        entries += [(None, spec) for spec in extra]
    out = []
    for index, spec in entries:
        where = f"{source}: links.{index}" if index is not None else f"{source}: link {spec.link}"
        if spec.link not in collisions:
            known = ", ".join(collisions)
            raise ConfigError(f"{where}.link = {spec.link!r}: no such link in the URDF (links: {known})")
        frame = _link_frame(model, spec.link)
        if frame is None:
            raise ConfigError(f"{where}.link = {spec.link!r}: Pinocchio has no body frame for this link")
        pieces = []  # (start, end, diameter, cd, cm, own displaced volume or None, cd_axial) in the link frame
        if spec.collision is not False:
            rows = collisions[spec.link]
            wanted = [row[0] for row in rows if row is not None] if spec.collision is True else list(spec.collision)
            if spec.collision is True and not wanted:
                raise ConfigError(f"{where}.collision: link '{spec.link}' has no <collision> cylinder")
            for k in wanted:
                if k >= len(rows) or rows[k] is None:
                    raise ConfigError(
                        f"{where}.collision: <collision> {k} of link '{spec.link}' is not a cylinder "
                        f"({len(rows)} collision elements)"
                    )
                _, origin, radius, length = rows[k]
                if not (math.isfinite(radius) and math.isfinite(length) and radius > 0.0 and length > 1e-9):
                    raise ConfigError(
                        f"{where}.collision: <collision> {k} of link '{spec.link}' is a cylinder of radius "
                        f"{radius!r} and length {length!r}: both must be finite and > 0"
                    )
                axis = origin.rotation[:, 2]
                half = 0.5 * length * axis
                pieces.append(
                    (origin.translation - half, origin.translation + half, 2.0 * radius, None, None, None, None)
                )
        for cylinder in spec.cylinders:
            start, end = cylinder.endpoints()
            pieces.append((start, end, cylinder.diameter, cylinder.cd, cylinder.cm, cylinder.displaced_volume,
                           cylinder.cd_axial))  # fmt: skip
        point = spec.buoyancy_center is not None
        volumes = np.zeros(len(pieces)) if point else _split_volumes(pieces, spec.displaced_volume, where)
        placement = frame.placement
        if point:
            centre = np.asarray(spec.buoyancy_center, dtype=float)
            out.append(
                WettedCylinder(
                    name=f"{spec.link}_buoyancy",
                    joint_id=int(frame.parentJoint),
                    start=placement.act(centre - [POINT_LENGTH / 2, 0.0, 0.0]),
                    end=placement.act(centre + [POINT_LENGTH / 2, 0.0, 0.0]),
                    diameter=POINT_LENGTH,
                    displaced_volume=float(spec.displaced_volume),
                    cd=0.0,
                    cm=0.0,
                )
            )
        for k, ((start, end, diameter, cd, cm, _, cd_axial), volume) in enumerate(zip(pieces, volumes, strict=True)):
            out.append(
                WettedCylinder(
                    name=spec.link if len(pieces) == 1 else f"{spec.link}_{k}",
                    joint_id=int(frame.parentJoint),
                    start=placement.act(np.asarray(start, dtype=float)),
                    end=placement.act(np.asarray(end, dtype=float)),
                    diameter=float(diameter),
                    displaced_volume=float(volume),
                    cd=coefficient(cd, spec.cd),
                    cm=coefficient(cm, spec.cm),
                    cd_axial=coefficient(cd_axial, spec.cd_axial),
                )
            )
    return out


def _split_volumes(pieces: list, link_volume: float | None, where: str) -> np.ndarray:
    """Displaced volume per cylinder: its own if given; the rest share ``link_volume``
    (what is left of it) in proportion to their geometric volumes, or keep those."""
    geometric = np.asarray([math.pi / 4.0 * p[2] ** 2 * np.linalg.norm(p[1] - p[0]) for p in pieces])
    own = np.asarray([np.nan if p[5] is None else p[5] for p in pieces])
    free = np.isnan(own)
    volumes = np.where(free, geometric, own)
    if link_volume is not None:
        left = link_volume - own[~free].sum()
        if not free.any() or left < 0.0:
            raise ConfigError(
                f"{where}.displaced_volume = {link_volume}: does not match the cylinders' own displaced volumes"
            )
        volumes[free] = left * geometric[free] / geometric[free].sum()
    return volumes


# --- files ---------------------------------------------------------------------


def load_hydro_spec(path: str | Path) -> HydroSpec:
    """Read and validate a hydrodynamics file (TOML or YAML)."""
    return validate(HydroSpec, read_mapping(path), str(path))


def hydro_file_for(urdf_path: str | Path) -> Path | None:
    """The hydrodynamics file beside a URDF: ``<stem>.hydro.toml`` (or ``.yaml``/``.yml``)."""
    urdf_path = Path(urdf_path)
    for suffix in HYDRO_SUFFIXES:
        candidate = urdf_path.with_name(urdf_path.stem + suffix)
        if candidate.is_file():
            return candidate
    return None


def load_urdf_arm(source: str | Path, hydro: HydroSpec | dict | str | Path | None = None) -> Arm:
    """Load a URDF arm from a ``.urdf`` path or from a hydrodynamics file that names its URDF.

    For a ``.urdf``, ``hydro`` is a spec, a dict, a path, or None (then the
    ``<stem>.hydro.toml`` beside the URDF, or if there is none every collision
    cylinder wet with default coefficients).
    """
    path = Path(source)
    if not path.is_file():
        raise ConfigError(f"arm {str(source)!r}: {not_a_file(path)}")
    name = path.name.lower()
    hydro_source = str(path)
    if name.endswith(HYDRO_SUFFIXES):
        if hydro is not None:
            raise ConfigError(f"{source}: a hydrodynamics file already; do not pass hydro as well")
        spec = load_hydro_spec(path)
        if spec.urdf is None:
            raise ConfigError(f"{source}: urdf: missing (the URDF this file describes, relative to it)")
        urdf_path = (path.parent / spec.urdf).resolve()
        if not urdf_path.is_file():
            raise ConfigError(f"{source}: urdf = {spec.urdf!r}: no such file ({urdf_path})")
    else:
        urdf_path = path
        if hydro is None:
            found = hydro_file_for(path)
            spec = load_hydro_spec(found) if found is not None else None
            hydro_source = str(found) if found is not None else f"{path} (no hydrodynamics file)"
        elif isinstance(hydro, (str, Path)):
            spec = load_hydro_spec(hydro)
            hydro_source = str(hydro)
        else:
            spec = hydro if isinstance(hydro, HydroSpec) else validate(HydroSpec, hydro, "hydro")
    return arm_from_urdf(urdf_path.read_text(), spec, source=hydro_source)


def hydro_spec_of(arm: Arm, use_collision: bool = True) -> dict[str, Any]:
    """A hydrodynamics mapping for ``arm`` exported with :meth:`Arm.to_urdf`.

    One entry per link of :func:`hydroarm.model.arm.urdf_export.arm_to_urdf` (``link<i>``): its
    URDF collision cylinder (``use_collision`` and one cylinder on the link) or
    explicit cylinders, with the arm's displaced volumes and coefficient
    overrides, so that re-loading the export with it gives the same dynamics
    and water (the round-trip test). Cylinders on the base are not exported.
    """
    by_joint: dict[int, list[WettedCylinder]] = {}
    for cylinder in arm.cylinders:
        by_joint.setdefault(cylinder.joint_id, []).append(cylinder)
    links = []
    for joint_id, cylinders in sorted(by_joint.items()):
        if joint_id == 0:
            continue
        if use_collision and len(cylinders) == 1:
            (c,) = cylinders
            entry: dict[str, Any] = {
                "link": f"link{joint_id}",
                "collision": True,
                "displaced_volume": c.displaced_volume,
            }
            entry.update({key: value for key, value in (("cd", c.cd), ("cm", c.cm)) if value is not None})
            if c.cd_axial > 0.0:
                entry["cd_axial"] = c.cd_axial
        else:
            entry = {"link": f"link{joint_id}", "cylinders": []}
            for c in cylinders:
                row = {"diameter": c.diameter, "start": c.start.tolist(), "end": c.end.tolist()}
                row["displaced_volume"] = c.displaced_volume
                row.update({key: value for key, value in (("cd", c.cd), ("cm", c.cm)) if value is not None})
                if c.cd_axial > 0.0:
                    row["cd_axial"] = c.cd_axial
                entry["cylinders"].append(row)
        links.append(entry)
    spec: dict = {"name": arm.name, "gravity": arm.gravity_acceleration, "links": links}
    if np.any(arm.model.armature != 0.0):  # URDF has no armature: the hydrodynamics file carries it
        spec["armature"] = [float(x) for x in arm.model.armature]
    return spec
