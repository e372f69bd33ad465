"""One closed-loop run of the vehicle-manipulator system: station keeping while the arm works.

:class:`UVMSRunConfig` (validated settings) -> :func:`run_uvms` -> :class:`UVMSRun` (arrays and
metrics). The arm runs a reach-and-return cycle (:class:`ReachReturn`) while the vehicle holds
its start pose in a uniform current; the plant is :class:`~hydroarm.model.uvms_fast.FastUVMSPlant`.

:func:`uvms_trajectory` turns a run into a :class:`~hydroarm.studies.runner.Trajectory` (the
arm's rows, the vehicle's pose in ``extra["base_pose"]``, the vehicle in ``meta["vehicle"]``)
that ``hydroarm animate`` draws with the vehicle's hull.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np
import pinocchio as pin
import pydantic

from hydroarm.config import ConfigError, FrozenModel
from hydroarm.control.gp import GPConfig
from hydroarm.control.registry import CONTROLLERS, canonical_name, controller_spec
from hydroarm.control.uvms_control import UVMSController
from hydroarm.control.vehicle_control import VehicleControlConfig
from hydroarm.model.uvms import UVMS, build_uvms
from hydroarm.model.uvms_fast import FastUVMSConfig, FastUVMSPlant
from hydroarm.model.vehicle import load_vehicle
from hydroarm.model.water import CurrentConfig, Water
from hydroarm.studies.experiment import ExperimentConfig
from hydroarm.studies.runner import Trajectory

Angles = list[float]


class ReachReturn:
    """Joint reference: from ``home`` to ``reach`` and back every ``period`` s (cosine blends,
    continuous acceleration at the ends of each leg), after ``start`` s at home."""

    def __init__(self, home, reach, period: float = 6.0, start: float = 1.0):
        self.home, self.reach = np.asarray(home, float), np.asarray(reach, float)
        self.period, self.start = period, start

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        tau = max(0.0, t - self.start) % self.period
        w = 2.0 * math.pi / self.period
        s = 0.5 * (1.0 - math.cos(w * tau))
        ds, dds = 0.5 * w * math.sin(w * tau), 0.5 * w * w * math.cos(w * tau)
        if t < self.start:
            ds = dds = 0.0
        delta = self.reach - self.home
        return self.home + s * delta, ds * delta, dds * delta


class UVMSRunConfig(FrozenModel):
    """Settings of one UVMS run."""

    settings_hint: ClassVar[str] = (
        "a vehicle run's settings are vehicle, arm, current, duration, control_period, vehicle_controller, aware, "
        "arm_controller, home, reach, task_period, gp_window and plant.*; "
        "its arm controller runs with its default gains"
    )

    vehicle: str = pydantic.Field("bluerov2_heavy", description="built-in vehicle or vehicle file")
    arm: str = pydantic.Field("mount", description="the arm: 'mount' (the vehicle file's), a built-in or a file")
    current: float = pydantic.Field(0.2, ge=0.0, le=3.0, description="current speed along world x (m/s)")
    duration: float = pydantic.Field(20.0, gt=0.0, le=3600.0, description="simulated time (s)")
    control_period: float = pydantic.Field(0.01, ge=1e-3, le=0.1, description="s")
    vehicle_controller: str = pydantic.Field("pid", pattern="^(pid|mpc)$", description="pid or mpc")
    aware: bool = pydantic.Field(False, description="GP feed-forward of the arm's force on the vehicle")
    arm_controller: str = pydantic.Field("SMC", description="registry name of the arm controller")
    home: Angles = pydantic.Field([3.0, 1.0, 1.0, 3.0], description="arm home angles (rad)")
    reach: Angles = pydantic.Field([3.6, 2.6, 2.4, 3.0], description="arm reach angles (rad)")
    task_period: float = pydantic.Field(6.0, gt=0.5, le=600.0, description="reach-and-return cycle (s)")
    gp_window: int = pydantic.Field(60, ge=5, le=500, description="GP window (samples)")
    plant: FastUVMSConfig = pydantic.Field(FastUVMSConfig(), description="plant path settings")

    @pydantic.model_validator(mode="after")
    def _at_least_one_step(self) -> UVMSRunConfig:
        if self.control_period > self.duration:
            raise ValueError(
                f"control_period = {self.control_period!r}: must be <= duration = {self.duration!r} (s); "
                "a run needs at least one control step"
            )
        return self

    @pydantic.field_validator("arm_controller")
    @classmethod
    def _known_controller(cls, value: str) -> str:
        try:
            return canonical_name(value)
        except ConfigError:
            allowed = ", ".join(name.lower() for name in CONTROLLERS)
            raise ValueError(f"must be one of {allowed}") from None


@dataclass
class UVMSRun:
    """Time series (``t`` (K,), ``x`` (K+1, n_state), ``u`` (K, n_u), ``d_hat`` (K, 6), ``saturated``
    (K,), ``ee_error`` (K+1,) m) and ``metrics``."""

    config: UVMSRunConfig
    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    d_hat: np.ndarray
    saturated: np.ndarray
    ee_error: np.ndarray
    metrics: dict = field(default_factory=dict)


def arm_sections(name: str) -> dict:
    """The default config sections the arm controller ``name`` reads (``ExperimentConfig``'s)."""
    defaults = ExperimentConfig()
    return {key: getattr(defaults, key) for key in (*controller_spec(name).sections, "estimator")}


def end_effector(uvms: UVMS, data: pin.Data, q: np.ndarray) -> np.ndarray:
    """World position of the arm's last joint frame (m)."""
    pin.forwardKinematics(uvms.model, data, q)
    return data.oMi[uvms.model.njoints - 1].translation.copy()


def run_uvms(config: UVMSRunConfig, progress=None) -> UVMSRun:
    """Simulate ``config``; ``progress(k, total)`` per control step (optional)."""
    uvms = build_uvms(config.vehicle, config.arm)
    water = Water(current=CurrentConfig(model="uniform", mean=[config.current, 0.0, 0.0]))
    plant = FastUVMSPlant(uvms, water, config.plant)
    reference = ReachReturn(config.home, config.reach, config.task_period)
    controller = UVMSController(
        uvms,
        arm_controller=config.arm_controller,
        vehicle=VehicleControlConfig(kind=config.vehicle_controller),
        gp=GPConfig(window=config.gp_window),
        aware=config.aware,
        control_period=config.control_period,
        arm_sections=arm_sections(config.arm_controller),
    )
    x = plant.initial_state(uvms.neutral(q_arm=config.home))
    target = x[:7].copy()
    steps = int(round(config.duration / config.control_period))
    nq = uvms.nq
    xs, us = np.empty((steps + 1, x.shape[0])), np.empty((steps, plant.n_arm + plant.n_thr))
    d_hat, saturated = np.zeros((steps, 6)), np.zeros(steps, dtype=bool)
    ee_error = np.zeros(steps + 1)
    data = uvms.create_data()
    xs[0] = x
    for k in range(steps):
        t = k * config.control_period
        out = controller.compute(t, x, reference, target)
        x_next, _ = plant.step(t, x, out.u, config.control_period)
        if not np.all(np.isfinite(x_next)):
            raise FloatingPointError(f"the plant state blew up at t = {t:.2f} s")
        controller.observe(t, x, out.u, x_next)
        xs[k + 1], us[k], d_hat[k], saturated[k] = x_next, out.u, out.d_hat, out.saturated
        x = x_next
        q_ref = np.concatenate([target, reference.sample(t + config.control_period)[0]])
        ee_error[k + 1] = np.linalg.norm(end_effector(uvms, data, x[:nq]) - end_effector(uvms, data, q_ref))
        if progress is not None:
            progress(k + 1, steps)
    times = np.arange(steps) * config.control_period
    run = UVMSRun(config, times, xs, us, d_hat, saturated, ee_error)
    run.metrics = uvms_metrics(run, target)
    return run


def uvms_metrics(run: UVMSRun, target: np.ndarray) -> dict:
    """Drift RMS and max (m), attitude RMS (deg), saturation time (s), end-effector error (m)."""
    x = run.x
    drift = np.linalg.norm(x[:, :3] - target[:3], axis=1)
    attitude = np.empty(x.shape[0])
    rot_ref = pin.Quaternion(target[6], *target[3:6]).toRotationMatrix()
    for k in range(x.shape[0]):
        rot = pin.Quaternion(x[k, 6], *x[k, 3:6]).toRotationMatrix()
        attitude[k] = np.linalg.norm(pin.log3(rot_ref.T @ rot))
    axes = x[:, :3] - target[:3]
    return {
        "drift_rms_m": float(np.sqrt(np.mean(drift**2))),
        "drift_max_m": float(np.max(drift)),
        "drift_rms_per_axis_m": np.sqrt(np.mean(axes**2, axis=0)).tolist(),
        "attitude_rms_deg": float(np.degrees(np.sqrt(np.mean(attitude**2)))),
        "attitude_max_deg": float(np.degrees(np.max(attitude))),
        "saturation_time_s": float(np.sum(run.saturated) * run.config.control_period),
        "ee_error_rms_m": float(np.sqrt(np.mean(run.ee_error**2))),
        "ee_error_max_m": float(np.max(run.ee_error)),
    }


def _source(name: str) -> str:
    """A built-in name as is; a file as its absolute path (the saved run can be read elsewhere)."""
    path = Path(name)
    return str(path.resolve()) if path.is_file() else name


def uvms_trajectory(run: UVMSRun) -> Trajectory:
    """``run`` as a :class:`Trajectory` at the control instants t_k (K rows): ``x`` the arm's
    [q, v], ``u`` the arm's torques, ``q_ref``/``v_ref`` the reach-and-return reference; ``extra``:
    ``base_pose`` (K, 7: position, quaternion x y z w), ``base_velocity`` (K, 6: body twist),
    ``thrust_command`` (K, n_thr) N, ``vehicle_disturbance_estimate`` (K, 6), ``saturated`` (K,);
    ``meta``: ``vehicle`` and ``arm`` (built-in names or absolute file paths), ``target_pose``
    (the station-keeping target), the run's settings (``uvms``) and metrics. The arm's true
    disturbance is not separated on the floating system: NaN."""
    config = run.config
    n, steps = len(config.home), run.t.shape[0]
    nq = 7 + n
    states = run.x[:steps]
    reference = ReachReturn(config.home, config.reach, config.task_period)
    q_ref, v_ref = np.empty((steps, n)), np.empty((steps, n))
    for k, t in enumerate(run.t):
        q_ref[k], v_ref[k] = reference.sample(float(t))[:2]
    arm_state = np.hstack([states[:, 7:nq], states[:, nq + 6 : nq + 6 + n]])
    unknown = np.full((steps, n), np.nan)
    arm = load_vehicle(config.vehicle).mount_arm if config.arm == "mount" else config.arm
    label = f"{config.arm_controller} arm, {config.vehicle_controller.upper()} vehicle"
    meta = {
        "controller": label + (" + GP feed-forward" if config.aware else ""),
        "vehicle": _source(config.vehicle),
        "arm": _source(arm),
        "target_pose": run.x[0, :7].tolist(),
        "duration": config.duration,
        "control_period": config.control_period,
        "steps": steps,
        "diverged": False,
        "stopped": None,
        "error": None,
        "faults": {},
        "uvms": config.model_dump(mode="json"),
        "metrics": run.metrics,
    }
    extra = {
        "base_pose": states[:, :7].copy(),
        "base_velocity": states[:, nq : nq + 6].copy(),
        "thrust_command": run.u[:, n:].copy(),
        "vehicle_disturbance_estimate": run.d_hat.copy(),
        "saturated": run.saturated.copy(),
    }
    return Trajectory(
        t=run.t.copy(), x=arm_state, y=arm_state.copy(), u=run.u[:, :n].copy(), q_ref=q_ref, v_ref=v_ref,
        disturbance=unknown, disturbance_estimate=unknown.copy(), disturbance_var=unknown.copy(),
        terminal_violation=np.zeros(steps), status=np.full(steps, "", dtype=str),
        events=np.full(steps, "", dtype=str), meta=meta, extra=extra,
    )  # fmt: skip
