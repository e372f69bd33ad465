"""URDF export of an arm's dry rigid body (links, revolute joints, inertials, cylinders).

The URDF is the exchange format our users' tools read (Pinocchio, MuJoCo,
ROS, Drake). Each moving link carries its inertial (at the CoG, tensor in the
link frame) and its wetted cylinders as visual and collision geometry. Numbers
are written with 17 significant digits so the round trip is exact to ~1e-15.
"""

from __future__ import annotations

from xml.sax.saxutils import quoteattr

import numpy as np
import pinocchio as pin

from hydroarm.model.arm.description import Arm, revolute_axes


def _fmt(values: np.ndarray) -> str:
    return " ".join(f"{float(v):.17g}" for v in np.atleast_1d(values))


def _origin(placement: pin.SE3) -> str:
    rpy = pin.rpy.matrixToRpy(placement.rotation)
    return f'<origin xyz="{_fmt(placement.translation)}" rpy="{_fmt(rpy)}"/>'


def _axis_to_z_rotation(axis: np.ndarray) -> np.ndarray:
    """A rotation whose z column is ``axis`` (URDF cylinders lie along local z)."""
    z = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z])


def arm_to_urdf(arm: Arm) -> str:
    """URDF text of ``arm``'s dry rigid body; see the module docstring.

    Joint axes come from the Pinocchio joint types; position limits from
    ``arm.position_limit`` when known, else +-2 pi (URDF revolute joints need
    limits, and a ``continuous`` joint would give Pinocchio a 2-number
    configuration per joint).
    """
    axes = revolute_axes(arm)
    model = arm.model
    lines = ['<?xml version="1.0"?>', f"<robot name={quoteattr(arm.name)}>", '  <link name="base_link"/>']
    if np.any(model.armature != 0.0):  # URDF has no reflected rotor inertia: say so where it is lost
        lines.append(
            f"  <!-- armature (kg m^2, per joint) = {_fmt(model.armature)}: URDF cannot carry it; "
            "give it as armature in the hydrodynamics file (hydro_spec_of writes it there) -->"
        )
    cylinders_by_joint: dict[int, list] = {}
    for cylinder in arm.cylinders:
        cylinders_by_joint.setdefault(cylinder.joint_id, []).append(cylinder)
    for joint_id in range(1, model.njoints):
        link_name = f"link{joint_id}"
        inertia = model.inertias[joint_id]
        tensor = inertia.inertia
        lines.append(f'  <link name="{link_name}">')
        lines.append("    <inertial>")
        lines.append(f'      <origin xyz="{_fmt(inertia.lever)}" rpy="0 0 0"/>')
        lines.append(f'      <mass value="{inertia.mass:.17g}"/>')
        lines.append(
            f'      <inertia ixx="{tensor[0, 0]:.17g}" ixy="{tensor[0, 1]:.17g}" ixz="{tensor[0, 2]:.17g}" '
            f'iyy="{tensor[1, 1]:.17g}" iyz="{tensor[1, 2]:.17g}" izz="{tensor[2, 2]:.17g}"/>'
        )
        lines.append("    </inertial>")
        for cylinder in cylinders_by_joint.get(joint_id, []):
            middle = 0.5 * (cylinder.start + cylinder.end)
            placement = pin.SE3(_axis_to_z_rotation(cylinder.end - cylinder.start), middle)
            geometry = (
                f'<geometry><cylinder radius="{cylinder.diameter / 2:.17g}" '
                f'length="{cylinder.length:.17g}"/></geometry>'
            )
            for tag in ("visual", "collision"):
                lines.append(f"    <{tag} name={quoteattr(cylinder.name + '_' + tag)}>")
                lines.append(f"      {_origin(placement)}")
                lines.append(f"      {geometry}")
                lines.append(f"    </{tag}>")
        lines.append("  </link>")
        parent_id = model.parents[joint_id]
        parent_name = "base_link" if parent_id == 0 else f"link{parent_id}"
        index = model.joints[joint_id].idx_v
        effort = arm.torque_limit[index]
        bounds = None if arm.position_limit is None else np.asarray(arm.position_limit)[index]
        if bounds is None or not np.all(np.isfinite(bounds)):
            bounds = np.array([-2.0 * np.pi, 2.0 * np.pi])
        lines.append(f'  <joint name="{model.names[joint_id]}" type="revolute">')
        lines.append(f'    <parent link="{parent_name}"/>')
        lines.append(f'    <child link="{link_name}"/>')
        lines.append(f"    {_origin(model.jointPlacements[joint_id])}")
        lines.append(f'    <axis xyz="{_fmt(axes[joint_id])}"/>')
        lines.append(
            f'    <limit lower="{bounds[0]:.17g}" upper="{bounds[1]:.17g}" effort="{effort:.17g}" velocity="10"/>'
        )
        lines.append("  </joint>")
    if model.existFrame("flange"):
        frame = model.frames[model.getFrameId("flange")]
        lines.append('  <link name="flange"/>')
        lines.append('  <joint name="flange_joint" type="fixed">')
        lines.append(f'    <parent link="link{frame.parentJoint}"/>')
        lines.append('    <child link="flange"/>')
        lines.append(f"    {_origin(frame.placement)}")
        lines.append("  </joint>")
    lines.append("</robot>")
    return "\n".join(lines) + "\n"
