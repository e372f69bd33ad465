"""The vehicle with its arm as an ordinary experiment: its settings section and its metrics.

``ExperimentConfig.vehicle`` (:class:`VehicleRun`) puts the arm on a vehicle: with
``vehicle.name`` set, :func:`hydroarm.sim.experiment.build_experiment` builds the floating
plant (:class:`~hydroarm.model.uvms_fast.FastUVMSPlant`), the whole system's controller
(:class:`~hydroarm.control.uvms_control.UVMSController`: the named arm controller on the
mounted arm + the station keeper), the arm's reach-and-return task
(:class:`~hydroarm.model.task.ReachReturn`) and the start state, and the one runner runs it.
:func:`station_keeping_metrics` reads a finished run's trajectory.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pydantic

from hydroarm.config import FrozenModel
from hydroarm.control.gp import GPConfig
from hydroarm.control.vehicle_control import VehicleControlConfig
from hydroarm.model.task import ReachReturn
from hydroarm.model.uvms import UVMS
from hydroarm.model.uvms_fast import FastUVMSConfig
from hydroarm.model.water import CurrentConfig, Water

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
        from hydroarm.model.vehicle import builtin_vehicle_name

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
    n, nq = uvms.n_arm, uvms.nq
    final = np.asarray(traj.meta["final_state"], dtype=float)
    poses = np.vstack([traj.extra.get("base_pose", np.empty((0, 7))), final[:7]])
    arm_q = np.vstack([traj.q, final[7:nq]])
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
