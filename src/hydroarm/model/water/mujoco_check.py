"""MuJoCo as an independent check of the water model's drag (optional: ``hydroarm[mujoco]``).

MuJoCo's ellipsoid fluid model (``fluidshape="ellipsoid"``, MuJoCo docs,
*Computation > Fluid forces*) approximates each geom by an ellipsoid with
semi-axes ``(r1, r2, r3)``; for a ``cylinder`` geom of radius r and half-length
h these are ``(r, r, h)`` (``mju_geomSemiAxes``). Its quadratic ("blunt") drag
on a geom whose centre moves at ``u`` relative to the fluid (the ``wind``) is,
in the geom frame (MuJoCo's ``mj_viscousForces``; checked numerically),

    F = -C_blunt rho A_proj(u) |u| u,
    A_proj(u) = pi sqrt((a^2 u1^2 + b^2 u2^2 + c^2 u3^2) / (a u1^2 + b u2^2 + c u3^2)),
    a = (r2 r3)^2, b = (r3 r1)^2, c = (r1 r2)^2.

For the cylinder (axis = geom z, u = u_n + u_a e) that is

    A_proj(u) = pi r sqrt((h^4 |u_n|^2 + r^4 u_a^2) / (h^2 |u_n|^2 + r^2 u_a^2)),

``pi r h`` for normal flow and ``pi r^2`` (the end face) for axial flow.
With purely normal flow (u_a = 0) this is ``-C_blunt rho pi r h |u_n| u_n``,
and Morison's normal drag on the same segment (length 2h, diameter 2r) is
``-1/2 rho C_d (2r)(2h) |u_n| u_n = -2 rho C_d r h |u_n| u_n``: they agree for

    C_blunt = 2 C_d / pi       (fluidcoef = "2*C_d/pi 0 0 0 0")

with the slender, angular, Kutta and Magnus coefficients zero and
``viscosity = 0``. The mapping is exact per segment; what remains differs:

1. *Lumping.* MuJoCo evaluates the drag at each geom's centre (no angular
   drag), hydroarm integrates along the cylinder. So each wetted cylinder is
   split into ``segments`` geoms. For a link spinning about its end the lumped
   torque is ``1 - 1/(2 N^2)`` of the integral (:func:`lumped_drag_ratio`).
2. *End faces.* With axial flow (u_a != 0) MuJoCo's ellipsoid has a frontal
   area ``pi r^2`` per segment and also scales the normal force; Morison's
   normal-only drag has neither. N segments give N end faces, so this grows
   with N: it is measured (:func:`drag_decomposition`), not hidden.
3. *Virtual mass.* MuJoCo always adds its ellipsoid's potential-flow
   virtual-mass forces, which are quadratic in the velocity (gyroscopic:
   even under ``(v, wind) -> (-v, -wind)``), while drag is odd. So the drag is
   the odd part ``(f(v, w) - f(-v, -w)) / 2``; the even part is returned
   separately. MuJoCo has no acceleration-proportional added mass and no
   buoyancy in this model: those are checked against closed forms instead
   (``docs/validation.md``).

A body whose geoms all lack ``fluidshape="ellipsoid"`` falls back to MuJoCo's
inertia-box drag, so every moving body gets at least a tiny zero-coefficient
ellipsoid geom. Gravity is off; forces are read from ``data.qfrc_fluid`` after
``mj_forward``. :func:`ellipsoid_drag` replays MuJoCo's blunt-drag formula
above in NumPy/Pinocchio (with or without the end-face part), which lets the
differences be split into lumping and end faces exactly.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from hydroarm.config import ConfigError
from hydroarm.model.arm.description import Arm, revolute_axes
from hydroarm.model.water.morison import Water, WaterModel, current_velocity

TINY_MASS = 1e-6  # kg: given to massless moving bodies (MuJoCo skips fluid forces on them)


def lumped_drag_ratio(segments: int) -> float:
    """Lumped / integrated drag torque of a cylinder spinning about one end, N segments:
    ``sum_k ((k - 1/2)/N)^3 / N`` over ``int_0^1 s^3 ds`` = ``1 - 1/(2 N^2)``."""
    return 1.0 - 1.0 / (2.0 * segments**2)


def blunt_coefficient(cd: float) -> float:
    """MuJoCo's blunt-drag coefficient equivalent to Morison's normal drag C_d: ``2 C_d / pi``."""
    return 2.0 * cd / math.pi


def _fmt(values) -> str:
    return " ".join(f"{float(v):.17g}" for v in np.atleast_1d(values))


def _quat(rotation: np.ndarray) -> np.ndarray:
    """MuJoCo quaternion (w, x, y, z) of a rotation matrix."""
    coeffs = pin.Quaternion(np.asarray(rotation, dtype=float)).coeffs()  # (x, y, z, w)
    return np.array([coeffs[3], coeffs[0], coeffs[1], coeffs[2]])


def _z_to(axis: np.ndarray) -> np.ndarray:
    """A rotation whose z column is the unit vector ``axis``."""
    z = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _cd(cylinder, water: Water) -> float:
    if water.drag_model != "constant":
        raise ConfigError(
            "water.drag_model = 'reynolds': only the fixed-base plant (UnderwaterPlant) has it; "
            "use water.drag_model = 'constant' here"
        )
    return cylinder.coefficients(water)[0]


def arm_to_mjcf(
    arm: Arm,
    water: Water | None = None,
    segments: int = 16,
    blunt: Sequence[bool] | None = None,
) -> str:
    """MJCF of ``arm`` for MuJoCo's ellipsoid fluid model (see the module docstring).

    One body per Pinocchio joint (named like the joint) with a hinge, the
    joint's inertia, and every wetted cylinder split into ``segments`` cylinder
    geoms with ``fluidshape="ellipsoid"`` and ``fluidcoef="2*C_d/pi 0 0 0 0"``.
    ``blunt[c]`` False zeroes cylinder c's coefficient (its geoms stay
    ellipsoids). ``density`` = ``water.rho``, ``viscosity`` 0, gravity off,
    ``wind`` 0 (set ``model.opt.wind`` before evaluating).
    """
    water = Water() if water is None else water
    if segments < 1:
        raise ValueError(f"segments must be >= 1, got {segments}")
    cylinders = arm.cylinders
    keep = [True] * len(cylinders) if blunt is None else list(blunt)
    if len(keep) != len(cylinders):
        raise ValueError(f"blunt has {len(keep)} values for {len(cylinders)} cylinders")
    children: dict[int, list[int]] = {}
    for joint_id in range(1, arm.model.njoints):
        children.setdefault(int(arm.model.parents[joint_id]), []).append(joint_id)
    coefficients = [blunt_coefficient(_cd(cylinder, water)) if on else 0.0 for cylinder, on in zip(cylinders, keep)]
    out = [
        f'<mujoco model="{arm.name}_fluid">',
        '  <compiler angle="radian" inertiafromgeom="false" balanceinertia="true" autolimits="true"/>',
        f'  <option density="{water.rho:.17g}" viscosity="0" wind="0 0 0" gravity="0 0 0" integrator="Euler">',
        '    <flag contact="disable"/>',
        "  </option>",
        "  <worldbody>",
    ]
    out += _geoms(arm, coefficients, segments, 0, "    ")
    for child in children.get(0, []):
        out += _body(arm, revolute_axes(arm), children, coefficients, segments, child, "    ")
    out += ["  </worldbody>", "</mujoco>"]
    return "\n".join(out) + "\n"


def _geoms(arm: Arm, coefficients: list[float], segments: int, joint_id: int, indent: str) -> list[str]:
    """The MJCF geoms of the wetted cylinders that joint ``joint_id`` carries, ``segments`` each,
    with the fluid coefficient ``coefficients[c]`` of cylinder c."""
    lines = []
    for cylinder, coefficient in zip(arm.cylinders, coefficients):
        if cylinder.joint_id != joint_id:
            continue
        half = cylinder.length / (2.0 * segments)
        quat = _quat(_z_to(cylinder.axis))
        for k in range(segments):
            centre = cylinder.start + (k + 0.5) / segments * (cylinder.end - cylinder.start)
            lines.append(
                f'{indent}<geom name="{cylinder.name}_{k}" type="cylinder" '
                f'size="{_fmt([cylinder.diameter / 2.0, half])}" pos="{_fmt(centre)}" quat="{_fmt(quat)}" '
                f'fluidshape="ellipsoid" fluidcoef="{coefficient:.17g} 0 0 0 0" contype="0" conaffinity="0"/>'
            )
    return lines


def _body(
    arm: Arm, axes: np.ndarray, children: dict[int, list[int]], coefficients: list[float], segments: int,
    joint_id: int, indent: str,
) -> list[str]:  # fmt: skip
    """The MJCF body of joint ``joint_id`` (its hinge, inertia and geoms) and, inside it, its children's."""
    model = arm.model
    placement = model.jointPlacements[joint_id]
    inertia = model.inertias[joint_id]
    mass = float(inertia.mass)
    tensor = np.asarray(inertia.inertia, dtype=float)
    lever = np.asarray(inertia.lever, dtype=float)
    if mass < TINY_MASS:
        mass, tensor, lever = TINY_MASS, TINY_MASS * 1e-4 * np.eye(3), np.zeros(3)
    full = [tensor[0, 0], tensor[1, 1], tensor[2, 2], tensor[0, 1], tensor[0, 2], tensor[1, 2]]
    name = model.names[joint_id]
    lines = [
        f'{indent}<body name="{name}" pos="{_fmt(placement.translation)}" quat="{_fmt(_quat(placement.rotation))}">',
        f'{indent}  <joint name="{name}" type="hinge" axis="{_fmt(axes[joint_id])}" limited="false" damping="0" '
        f'armature="{float(model.armature[model.joints[joint_id].idx_v]):.17g}"/>',
        f'{indent}  <inertial pos="{_fmt(lever)}" mass="{mass:.17g}" fullinertia="{_fmt(full)}"/>',
    ]
    wet = _geoms(arm, coefficients, segments, joint_id, indent + "  ")
    if not wet:  # keep MuJoCo off its inertia-box model for this body
        wet = [
            f'{indent}  <geom name="{name}_dry" type="sphere" size="1e-4" fluidshape="ellipsoid" '
            'fluidcoef="0 0 0 0 0" contype="0" conaffinity="0"/>'
        ]
    lines += wet
    for child in children.get(joint_id, []):
        lines += _body(arm, axes, children, coefficients, segments, child, indent + "  ")
    lines.append(f"{indent}</body>")
    return lines


@dataclass(frozen=True)
class FluidSplit:
    """MuJoCo's fluid generalised force (N m, (n,) each, hydroarm's joint order) split by parity:
    ``drag`` = (f(v, w) - f(-v, -w)) / 2, ``even`` = (f(v, w) + f(-v, -w)) / 2 (virtual mass)."""

    drag: np.ndarray
    even: np.ndarray


class MujocoWater:
    """MuJoCo's ellipsoid fluid forces on an arm (see :func:`arm_to_mjcf`)."""

    def __init__(self, arm: Arm, water: Water | None = None, segments: int = 16, blunt: Sequence[bool] | None = None):
        import mujoco

        self._mujoco = mujoco
        self.arm = arm
        self.water = Water() if water is None else water
        self.segments = segments
        self.xml = arm_to_mjcf(arm, self.water, segments, blunt)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        n = arm.n_joints
        if self.model.nv != n:
            raise RuntimeError(f"MJCF has {self.model.nv} dofs, the arm {n}")
        # dof[i] = MuJoCo dof of hydroarm velocity index i
        self.dof = np.empty(n, dtype=int)
        for joint_id in range(1, arm.model.njoints):
            mj_joint = self.model.joint(arm.model.names[joint_id]).id
            self.dof[arm.model.joints[joint_id].idx_v] = self.model.jnt_dofadr[mj_joint]
        self.qpos = np.array([self.model.jnt_qposadr[self.model.dof_jntid[d]] for d in self.dof])

    def wind(self, t: float = 0.0) -> np.ndarray:
        """The water velocity MuJoCo sees (m/s): the ``uniform`` current at time t, else 0."""
        return current_velocity(self.water.current, t)

    def qfrc_fluid(self, q: np.ndarray, v: np.ndarray, wind: np.ndarray) -> np.ndarray:
        """Raw ``data.qfrc_fluid`` at (q, v) in a uniform ``wind`` (m/s), hydroarm's joint order."""
        mujoco, data = self._mujoco, self.data
        data.qpos[:] = 0.0
        data.qvel[:] = 0.0
        data.qpos[self.qpos] = q
        data.qvel[self.dof] = v
        self.model.opt.wind[:] = wind
        mujoco.mj_forward(self.model, data)
        return data.qfrc_fluid[self.dof].copy()

    def split(self, q: np.ndarray, v: np.ndarray, t: float = 0.0) -> FluidSplit:
        """Drag (odd) and virtual-mass (even) parts at (q, v) and time t."""
        q, v = np.asarray(q, dtype=float), np.asarray(v, dtype=float)
        wind = self.wind(t)
        forward = self.qfrc_fluid(q, v, wind)
        backward = self.qfrc_fluid(q, -v, -wind)
        return FluidSplit(drag=0.5 * (forward - backward), even=0.5 * (forward + backward))

    def drag(self, q: np.ndarray, v: np.ndarray, t: float = 0.0) -> np.ndarray:
        """MuJoCo's drag generalised force (N m), shape (n,)."""
        return self.split(q, v, t).drag


def hydroarm_drag(arm: Arm, water: Water, q: np.ndarray, v: np.ndarray, t: float = 0.0) -> np.ndarray:
    """hydroarm's Morison drag generalised force (N m), shape (n,), for comparison."""
    drag_only = water.model_copy(update={"added_mass": False, "buoyancy": False})
    n = arm.n_joints
    return WaterModel(arm, drag_only).torques(np.asarray(q, float), np.asarray(v, float), np.zeros(n), t).drag


def only_cylinder(arm: Arm, index: int) -> Arm:
    """The same arm with C_d = 0 on every cylinder but ``index`` (for per-link hydroarm drag)."""
    cylinders = tuple(c if k == index else dataclasses.replace(c, cd=0.0) for k, c in enumerate(arm.cylinders))
    return Arm(
        name=arm.name,
        model=arm.model,
        cylinders=cylinders,
        torque_limit=arm.torque_limit,
        spec=arm.spec,
        position_limit=arm.position_limit,
    )


def ellipsoid_drag(
    arm: Arm,
    water: Water,
    q: np.ndarray,
    v: np.ndarray,
    t: float = 0.0,
    segments: int = 16,
    end_faces: bool = True,
    cylinders: Sequence[int] | None = None,
) -> np.ndarray:
    """MuJoCo's blunt drag on the segmented cylinders, replayed with Pinocchio (N m), shape (n,).

    Per segment (centre p, half-length h = L/(2N), radius r, relative velocity
    u = u_n + u_a e): ``F = -C_blunt rho A_proj(u) |u| u`` with
    ``A_proj = pi r sqrt((h^4 |u_n|^2 + r^4 u_a^2) / (h^2 |u_n|^2 + r^2 u_a^2))``
    with ``end_faces`` (MuJoCo's); ``F = -C_blunt rho pi r h |u_n| u_n``
    (Morison's normal drag lumped at the segment centre) without. Generalised force sum J_p^T F.
    ``cylinders``: the indices to include (default all).
    """
    model, data = arm.model, arm.create_data()
    q, v = np.asarray(q, dtype=float), np.asarray(v, dtype=float)
    pin.forwardKinematics(model, data, q, v)
    pin.computeJointJacobians(model, data, q)
    wind = current_velocity(water.current, t)
    tau = np.zeros(arm.n_joints)
    chosen = range(len(arm.cylinders)) if cylinders is None else cylinders
    for index in chosen:
        cylinder = arm.cylinders[index]
        joint = cylinder.joint_id
        if joint == 0:
            continue
        placement = data.oMi[joint]
        rotation = placement.rotation
        twist = data.v[joint]  # local frame of the joint
        jac = pin.getJointJacobian(model, data, joint, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        axis = rotation @ cylinder.axis
        radius = cylinder.diameter / 2.0
        half = cylinder.length / (2.0 * segments)
        coefficient = blunt_coefficient(_cd(cylinder, water)) * water.rho * math.pi * radius  # x A_proj / (pi r)
        for k in range(segments):
            local = cylinder.start + (k + 0.5) / segments * (cylinder.end - cylinder.start)
            velocity = rotation @ (twist.linear + np.cross(twist.angular, local)) - wind
            along = float(velocity @ axis)
            normal = velocity - along * axis
            speed_n = float(np.linalg.norm(normal))
            if end_faces:
                denominator = half**2 * speed_n**2 + radius**2 * along**2
                if denominator <= 0.0:
                    continue
                ratio = (half**4 * speed_n**2 + radius**4 * along**2) / denominator
                force = -coefficient * math.sqrt(ratio) * math.sqrt(speed_n**2 + along**2) * velocity
            else:
                force = -coefficient * half * speed_n * normal
            offset = rotation @ local
            jac_point = jac[:3] - pin.skew(offset) @ jac[3:]
            tau += jac_point.T @ force
    return tau


def axial_flow_fraction(arm: Arm, q: np.ndarray, v: np.ndarray, wind: np.ndarray | None = None, points: int = 9):
    """Per cylinder, the largest |u . e| / |u| over ``points`` points along it (0 = flow normal
    to the axis everywhere; cylinders at rest in still water give 0). Shape (n_cylinders,)."""
    model, data = arm.model, arm.create_data()
    pin.forwardKinematics(model, data, np.asarray(q, float), np.asarray(v, float))
    wind = np.zeros(3) if wind is None else np.asarray(wind, dtype=float)
    out = np.zeros(len(arm.cylinders))
    for index, cylinder in enumerate(arm.cylinders):
        rotation = data.oMi[cylinder.joint_id].rotation
        twist = data.v[cylinder.joint_id]
        axis = rotation @ cylinder.axis
        for s in np.linspace(0.0, 1.0, points):
            local = cylinder.start + s * (cylinder.end - cylinder.start)
            u = rotation @ (twist.linear + np.cross(twist.angular, local)) - wind
            speed = np.linalg.norm(u)
            if speed > 1e-12:
                out[index] = max(out[index], abs(u @ axis) / speed)
    return out


def drag_decomposition(
    arm: Arm,
    water: Water,
    states: Sequence[tuple[np.ndarray, np.ndarray]],
    segments: int = 16,
    t: float = 0.0,
) -> list[dict]:
    """Per cylinder, how MuJoCo's drag differs from hydroarm's on general states.

    For each cylinder c alone (blunt coefficient zeroed on the others in MuJoCo,
    C_d = 0 on the others in hydroarm), over the ``states`` (q, v):
    ``mujoco_vs_hydroarm`` = ||tau_mj - tau_h|| / ||tau_h||, ``end_face`` =
    ||tau_mj - tau_lumped|| / ||tau_h|| and ``lumping`` = ||tau_lumped - tau_h|| / ||tau_h||
    (tau_lumped: Morison drag lumped at the segment centres, :func:`ellipsoid_drag`
    without end faces), each an RMS over the states; ``share`` = ||tau_h,c|| /
    ||tau_h,all||, the link's part of the arm's drag; ``end_face_of_total`` =
    ||tau_mj - tau_lumped|| / ||tau_h,all||, the end faces against the whole
    arm's drag; ``replay_error``: the
    largest |tau_mj - :func:`ellipsoid_drag`| (N m), the check that the formula
    above is MuJoCo's.
    """
    rows = []
    total = [hydroarm_drag(arm, water, q, v, t) for q, v in states]
    for index, cylinder in enumerate(arm.cylinders):
        if cylinder.joint_id == 0:
            continue
        keep = [k == index for k in range(len(arm.cylinders))]
        simulator = MujocoWater(arm, water, segments, blunt=keep)
        alone = only_cylinder(arm, index)
        sums = dict(diff=0.0, face=0.0, lump=0.0, ref=0.0, all=0.0)
        replay = 0.0
        for (q, v), tau_all in zip(states, total, strict=True):
            mj = simulator.drag(q, v, t)
            ref = hydroarm_drag(alone, water, q, v, t)
            lumped = ellipsoid_drag(arm, water, q, v, t, segments, end_faces=False, cylinders=[index])
            full = ellipsoid_drag(arm, water, q, v, t, segments, end_faces=True, cylinders=[index])
            replay = max(replay, float(np.max(np.abs(mj - full))))
            sums["diff"] += float(np.sum((mj - ref) ** 2))
            sums["face"] += float(np.sum((mj - lumped) ** 2))
            sums["lump"] += float(np.sum((lumped - ref) ** 2))
            sums["ref"] += float(np.sum(ref**2))
            sums["all"] += float(np.sum(tau_all**2))
        scale = math.sqrt(sums["ref"]) if sums["ref"] > 0.0 else math.nan
        rows.append(
            {
                "cylinder": cylinder.name,
                "joint": arm.model.names[cylinder.joint_id],
                "segments": segments,
                "mujoco_vs_hydroarm": math.sqrt(sums["diff"]) / scale,
                "end_face": math.sqrt(sums["face"]) / scale,
                "lumping": math.sqrt(sums["lump"]) / scale,
                "share": math.sqrt(sums["ref"] / sums["all"]) if sums["all"] > 0.0 else math.nan,
                "end_face_of_total": math.sqrt(sums["face"] / sums["all"]) if sums["all"] > 0.0 else math.nan,
                "replay_error": replay,
            }
        )
    return rows
