"""The vehicle with its arm as an ordinary experiment: its settings section and its metrics.

``ExperimentConfig.vehicle`` (:class:`VehicleRun`) puts the arm on a vehicle: with
``vehicle.name`` set, :func:`hydroarm.sim.experiment.build_experiment` builds the floating
plant (:class:`~hydroarm.model.vehicle.fast.FastUVMSPlant`), the whole system's controller
(:class:`~hydroarm.control.uvms_control.UVMSController`: the named arm controller on the
mounted arm + the station keeper), the arm's reach-and-return task
(:class:`~hydroarm.model.task.references.ReachReturn`) and the start state, and the one runner runs it.
:func:`station_keeping_metrics` reads a finished run's trajectory.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
import pydantic

from hydroarm.config import ConfigError, FrozenModel, shown
from hydroarm.control.gp import GPConfig
from hydroarm.control.vehicle_control import VehicleControlConfig
from hydroarm.model.arm.description import Arm
from hydroarm.model.task.references import ReachReturn
from hydroarm.model.vehicle.fast import FastUVMSConfig, FastUVMSPlant
from hydroarm.model.vehicle.system import UVMS
from hydroarm.model.water.morison import CurrentConfig, Water

Angles = list[float]


class VehicleRun(FrozenModel):
    """The arm on a vehicle, holding station while the arm reaches and returns.

    ``name`` None (the default): the arm on a fixed base, and nothing here is read. Otherwise
    the experiment's ``arm`` is the arm on the vehicle (``"mount"``: the one the vehicle file
    names), its controller the arm's (any registry name), and this section the rest.
    """

    name: str | None = pydantic.Field(
        None, description="a built-in vehicle (bluerov2-heavy) or a vehicle file; none: the arm on a fixed base"
    )
    current: float = pydantic.Field(
        0.2,
        ge=0.0,
        le=3.0,
        description="a uniform current along world x on a vehicle run (m/s); replaces water.current",
    )
    control: VehicleControlConfig = pydantic.Field(
        VehicleControlConfig(), description="the station keeper: pid or mpc and its gains (section)"
    )
    aware: bool = pydantic.Field(False, description="GP feed-forward of the arm's force on the vehicle (on/off)")
    gp: GPConfig = pydantic.Field(GPConfig(window=60), description="the feed-forward GP of an aware run (section)")
    home: Angles = pydantic.Field([3.0, 1.0, 1.0, 3.0], description="the arm's home angles (rad)")
    reach: Angles = pydantic.Field([3.6, 2.6, 2.4, 3.0], description="the arm's reach angles (rad)")
    task_period: float = pydantic.Field(6.0, gt=0.5, le=600.0, description="the reach-and-return cycle (s)")
    plant: FastUVMSConfig = pydantic.Field(FastUVMSConfig(), description="the floating plant's integration (section)")

    @pydantic.field_validator("name")
    @classmethod
    def _builtin_spelling(cls, value: str | None) -> str | None:
        """``bluerov2-heavy`` and ``bluerov2_heavy`` both name the built-in vehicle: kept as the first."""
        if value is None:
            return None
        from hydroarm.model.vehicle.description import builtin_vehicle_name

        return builtin_vehicle_name(value) or value

    @pydantic.model_validator(mode="after")
    def _task_fits(self) -> VehicleRun:
        if len(self.home) != len(self.reach):
            raise ValueError(
                f"vehicle.reach = {self.reach}: {len(self.reach)} angles; give one per home angle ({len(self.home)})"
            )
        return self

    def water(self, water: Water) -> Water:
        """The water of the vehicle run: ``water`` with the uniform current of ``current``."""
        return water.model_copy(update={"current": CurrentConfig(model="uniform", mean=[self.current, 0.0, 0.0])})

    def reference(self) -> ReachReturn:
        return ReachReturn(self.home, self.reach, self.task_period)


@dataclass
class VehicleParts:
    """What a vehicle run is built from: the floating system, the mounted arm the arm
    controller knows, the floating plant, the arm's reach-and-return task and the start state."""

    uvms: UVMS
    arm: Arm
    plant: FastUVMSPlant
    reference: ReachReturn
    x0: np.ndarray


def vehicle_parts(vehicle: VehicleRun, arm: str | Arm, water: Water, torque_limit=None) -> VehicleParts:
    """The parts of a vehicle run of ``vehicle`` with ``arm`` ("mount": the vehicle file's) in
    ``water`` (its current replaced by ``vehicle.current``); ``torque_limit`` overrides the arm's
    (N m, None: the arm file's). Raises :class:`ConfigError` naming the setting at fault."""
    from hydroarm.model.vehicle.system import build_uvms, mounted_arm

    try:
        uvms = build_uvms(vehicle.name, arm)
    except ConfigError as error:
        raise ConfigError(f"vehicle.name = {vehicle.name!r}: {error}") from None
    except (ValueError, FileNotFoundError, OSError) as error:
        raise ConfigError(f"vehicle.name = {vehicle.name!r} with arm = {arm!r}: {error}") from None
    if uvms.arm is None:
        raise ConfigError(f"arm = {arm!r}: a vehicle run needs an arm on the vehicle")
    if uvms.vehicle.n_thrusters == 0:
        raise ConfigError(
            f"vehicle.name = {vehicle.name!r}: a passive vehicle (thrusters = []) cannot keep station; "
            "give a vehicle with thrusters, or replay its logs (hydroarm replay)"
        )
    n = uvms.n_arm
    if len(vehicle.home) != n:
        raise ConfigError(
            f"vehicle.home = {shown(vehicle.home)}: {len(vehicle.home)} angles; the arm on the vehicle has {n} joints"
        )
    plant = FastUVMSPlant(uvms, vehicle.water(water), vehicle.plant)
    x0 = plant.initial_state(uvms.neutral(q_arm=vehicle.home))
    return VehicleParts(uvms, mounted_arm(uvms).with_torque_limit(torque_limit), plant, vehicle.reference(), x0)


def station_keeper(vehicle: VehicleRun, parts: VehicleParts, arm_controller, control_period: float):
    """The whole system's :class:`~hydroarm.control.uvms_control.UVMSController`: ``arm_controller``
    on the mounted arm + the station keeper of ``vehicle.control`` holding the start pose."""
    from hydroarm.control.uvms_control import UVMSController

    return UVMSController(
        parts.uvms, arm_controller, parts.x0[parts.uvms.layout.base_pose], vehicle=vehicle.control, gp=vehicle.gp,
        aware=vehicle.aware, control_period=control_period,
    )  # fmt: skip


def source_name(name: str | None) -> str | None:
    """A built-in name as is; a file as its absolute path (the saved run can be read elsewhere)."""
    if name is None:
        return None
    path = Path(name)
    return str(path.resolve()) if path.is_file() else name


def end_effector(uvms: UVMS, data: pin.Data, q: np.ndarray) -> np.ndarray:
    """World position (3,) m of the arm's last joint frame at the system configuration q."""
    pin.forwardKinematics(uvms.model, data, q)
    return data.oMi[uvms.model.njoints - 1].translation.copy()


def station_keeping_metrics(uvms: UVMS, traj, reference) -> dict:
    """Drift RMS and max (m), attitude RMS and max (deg), saturation time (s) and the arm's
    end-effector error RMS and max (m) of a vehicle run's :class:`~hydroarm.sim.runner.Trajectory`.

    Over the K recorded instants t_k and the end of the run (``meta["final_state"]``), against
    the start pose (``extra["base_pose"][0]``, the station-keeping target) and the end effector
    where the target pose and the joint reference put it."""
    n, layout = uvms.n_arm, uvms.layout
    final = np.asarray(traj.meta["final_state"], dtype=float)
    poses = np.vstack([traj.extra.get("base_pose", np.empty((0, 7))), final[layout.base_pose]])
    arm_q = np.vstack([traj.q, final[layout.arm_q]])
    period = float(traj.meta["control_period"])
    target = poses[0]
    drift = np.linalg.norm(poses[:, :3] - target[:3], axis=1)
    rot_ref = pin.Quaternion(target[6], *target[3:6]).toRotationMatrix()
    attitude = np.empty(poses.shape[0])
    ee_error = np.zeros(poses.shape[0])
    data = uvms.create_data()
    for k, pose in enumerate(poses):
        rot = pin.Quaternion(pose[6], *pose[3:6]).toRotationMatrix()
        attitude[k] = np.linalg.norm(pin.log3(rot_ref.T @ rot))
        if k > 0:  # the state after step k - 1, where the reference is at t_{k-1} + T
            q_ref = reference.sample(float(traj.t[k - 1]) + period)[0][:n]
            actual = end_effector(uvms, data, np.concatenate([pose, arm_q[k]]))
            wanted = end_effector(uvms, data, np.concatenate([target, q_ref]))
            ee_error[k] = np.linalg.norm(actual - wanted)
    axes = poses[:, :3] - target[:3]
    saturated = traj.extra.get("saturated", np.zeros(len(traj.t), dtype=bool))
    return {
        "drift_rms_m": float(np.sqrt(np.mean(drift**2))),
        "drift_max_m": float(np.max(drift)),
        "drift_rms_per_axis_m": np.sqrt(np.mean(axes**2, axis=0)).tolist(),
        "attitude_rms_deg": float(np.degrees(np.sqrt(np.mean(attitude**2)))),
        "attitude_max_deg": float(np.degrees(np.max(attitude))),
        "saturation_time_s": float(np.sum(saturated) * period),
        "ee_error_rms_m": float(np.sqrt(np.mean(ee_error**2))),
        "ee_error_max_m": float(np.max(ee_error)),
    }


FIXED_BASE_ONLY_SECTIONS: tuple[str, ...] = ("plant", "sensor", "actuator", "friction")
"""Sections of the fixed-base plant that a vehicle run has no place for: the floating plant
measures its true state, applies the arm's torques as commanded, has no joint friction model and
integrates by its own settings (``vehicle.plant.*``). A value away from its default is refused
(:func:`check_vehicle_settings`), never validated and then ignored."""


VEHICLE_HOMES: dict[str, str] = {
    "water.current": "vehicle.current",
    "water.quadrature_points": "vehicle.plant.drag_points",
}
"""Water settings that a vehicle run takes from its own section, fixed-base key -> its home on
a vehicle: the floating plant's current is ``vehicle.current`` (a uniform current along world
x) and its arm's Gauss points ``vehicle.plant.drag_points``. Given away from its default on a
vehicle run, the fixed-base key is refused naming its home (:func:`check_vehicle_settings`),
never validated and then replaced."""


def check_vehicle_settings(config: Any) -> None:
    """Raise :class:`ConfigError` naming the first fixed-base setting (:data:`FIXED_BASE_ONLY_SECTIONS`,
    :data:`VEHICLE_HOMES`) that a vehicle run (``vehicle.name`` set) was given away from its
    default. ``config``: an :class:`~hydroarm.sim.experiment.ExperimentConfig`."""
    for key, home in VEHICLE_HOMES.items():
        section, name = key.split(".")
        value, default = getattr(getattr(config, section), name), getattr(type(getattr(config, section))(), name)
        if value != default:
            raise ConfigError(
                f"{key} = {shown(value)}: not used on a vehicle run (vehicle.name = {config.vehicle.name!r}): "
                f"a vehicle run's is {home}. Set {home}, and leave {key} at its default ({shown(default)})"
            )
    for key, value in config.mismatch:
        default = type(config.mismatch).model_fields[key].default
        if value != default:
            raise ConfigError(
                f"mismatch.{key} = {shown(value)}: not used on a vehicle run (vehicle.name = {config.vehicle.name!r}): "
                f"the floating plant's arm is the arm file's; leave it at its default ({shown(default)}) "
                "or run the arm on a fixed base"
            )
    for section in FIXED_BASE_ONLY_SECTIONS:
        value, default = getattr(config, section), type(getattr(config, section))()
        for key in type(value).model_fields:
            if getattr(value, key) != getattr(default, key):
                raise ConfigError(
                    f"{section}.{key} = {shown(getattr(value, key))}: not used on a vehicle run "
                    f"(vehicle.name = {config.vehicle.name!r}): the floating plant measures its true state, "
                    "applies the arm's torques as commanded and has no joint friction model; its integration "
                    f"is vehicle.plant.*. Leave {section}.{key} at its default ({shown(getattr(default, key))}) "
                    "or run the arm on a fixed base"
                )
