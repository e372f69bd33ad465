"""Replay a real vehicle + arm from its logs: the vehicle's response to the logged arm motion.

For each trial: the joints' logged motion is cleaned and smoothed
(:func:`hydroarm.sim.logs.joint_motion`); the vehicle starts from the IMU's attitude and rates
at the first common instant; the prescribed-motion plant
(:class:`hydroarm.model.vehicle.prescribed.PrescribedUVMSPlant`) integrates the vehicle only; the
simulated roll and pitch are compared with the IMU's and the motion capture's (RMSE and the
peak-excursion error, the largest departure from the initial value, simulated minus measured).

Outputs (:func:`write_replay`): ``DIR/<trial>/attitude.csv`` (time_s, simulated roll, pitch,
yaw, the IMU's and the motion capture's, rad, on the output grid), ``DIR/<trial>/attitude.png``
and ``DIR/summary.json`` (per trial and means, in degrees).
"""

from __future__ import annotations

import math
import warnings
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import pinocchio as pin
import pydantic

from hydroarm.config import ConfigError, FrozenModel
from hydroarm.model.arm.loading import load_arm
from hydroarm.model.dynamics.integrator import inner_step_setting, inner_steps
from hydroarm.model.vehicle.description import VehicleSpec, build_vehicle, load_vehicle_spec
from hydroarm.model.vehicle.plant import UVMSPlantConfig
from hydroarm.model.vehicle.prescribed import PrescribedUVMSPlant
from hydroarm.model.vehicle.system import build_uvms
from hydroarm.model.water.morison import Water, density_setting
from hydroarm.sim.files import atomic_write
from hydroarm.sim.logs import CleaningConfig, TrialLog, clean_attitude, joint_motion, roll_pitch_yaw
from hydroarm.sim.trials import load_trial

AXES = ("roll", "pitch")


class ReplayConfig(FrozenModel):
    """How a replay runs (the physics is the vehicle and arm files')."""

    water_density: float = density_setting(997.0, "the tank's fresh water: the replay's water.rho")
    inner_step: float = inner_step_setting(0.05, "the replayed vehicle")
    output_period: float = pydantic.Field(0.05, ge=1e-3, le=1.0, description="s: the attitude.csv grid")
    rate_window: float = pydantic.Field(
        0.25, ge=0.0, le=5.0, description="s: the initial body rates are the IMU's mean over this window"
    )
    joint_time_offset: float = pydantic.Field(
        0.0,
        ge=-1.0,
        le=1.0,
        description="s: the arm log runs this far behind the IMU clock (joints at t = the log at t - offset)",
    )
    imu_mounting_rpy_deg: Annotated[
        tuple[pydantic.StrictFloat, pydantic.StrictFloat, pydantic.StrictFloat], pydantic.Strict(False)
    ] = pydantic.Field(
        (0.0, 0.0, 0.0),
        description="deg: the IMU's frame in the body frame (roll, pitch, yaw; each within +-15)",
    )
    trim: float = pydantic.Field(
        0.0,
        ge=0.0,
        le=1.0,
        description="fraction of the initial restoring moment cancelled by a constant one (a per-log trim)",
    )
    trim_window: float = pydantic.Field(
        3.0,
        ge=0.0,
        le=10.0,
        description="s: the trim's rest attitude: the IMU's mean over this first window (cut where the arm moves)",
    )
    cleaning: CleaningConfig = pydantic.Field(CleaningConfig(), description="the logs' cleaning (section)")

    @pydantic.field_validator("imu_mounting_rpy_deg")
    @classmethod
    def _small_mounting(cls, value: tuple[float, float, float]) -> tuple[float, float, float]:
        if any(not math.isfinite(v) or abs(v) > 15.0 for v in value):
            raise ValueError(f"each angle must be within +-15 deg, got {list(value)}")
        return value

    def imu_mounting(self) -> np.ndarray:
        """R (3, 3): the IMU's frame in the body frame (the IMU reads R_body R)."""
        return pin.rpy.rpyToMatrix(*np.radians(self.imu_mounting_rpy_deg))


NOT_ON_REPLAY: dict[str, str] = {
    "sensor": "the arm's joints follow the logged angles, which the real encoders already measured: "
    "no controller reads a simulated sensor",
    "actuator": "no torque is commanded: the log prescribes the joints' motion, so no drive sits "
    "between a command and the arm",
    "friction": "the log prescribes the joints' motion: joint friction, a torque between two links, changes "
    "only the motor torque that motion takes, never the force on the vehicle",
    "plant": "the replay's plant is the vehicle file's under the logged joint motion; its integration "
    "step is the replay setting inner_step",
}
"""The experiment's real-loop sections that cannot apply to a replay, and why: given to
``hydroarm replay`` they are refused (:func:`check_replay_key`), never ignored."""


def check_replay_key(key: str, where: str = "--set") -> None:
    """:class:`ConfigError` naming ``key`` (a dotted setting) if it belongs to a section of
    :data:`NOT_ON_REPLAY`, with why it cannot apply and the settings a replay takes."""
    section = key.strip().split(".", 1)[0]
    if section in NOT_ON_REPLAY:
        raise ConfigError(
            f"{where} {key.strip()}: not used by a replay: {NOT_ON_REPLAY[section]}. A replay's settings: "
            f"{', '.join(ReplayConfig.model_fields)} (hydroarm settings, section replay)"
        )


@dataclass
class ReplayResult:
    """One trial replayed: ``time`` (k,) s; ``simulated``, ``imu``, ``mocap`` (k, 3) roll pitch
    yaw (rad; mocap NaN where absent); ``metrics`` in degrees."""

    name: str
    time: np.ndarray
    simulated: np.ndarray
    imu: np.ndarray
    mocap: np.ndarray
    metrics: dict[str, Any]


def load_vehicle_quietly(source: str | Path) -> VehicleSpec:
    """A vehicle file, its off-hull mount warning silenced (it is known for the tested vehicles)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return load_vehicle_spec(source)


def build_system(vehicle: VehicleSpec, arm: Any = "mount"):
    """The floating system of a vehicle spec and an arm (an Arm, a name/file, or ``"mount"``)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        built = build_vehicle(vehicle)
    if isinstance(arm, str):
        arm = load_arm(built.mount_arm if arm == "mount" else arm)
    return build_uvms(built, arm)


def _interp_angles(t: np.ndarray, time: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Angles (k, 3) at times t, unwrapped before interpolating."""
    unwrapped = np.unwrap(angles, axis=0)
    return np.column_stack([np.interp(t, time, unwrapped[:, i]) for i in range(angles.shape[1])])


def simulate(log: TrialLog, uvms, config: ReplayConfig, motion=None) -> tuple[np.ndarray, np.ndarray]:
    """``(time (k,), simulated roll pitch yaw (k, 3))`` of one log on one system (``motion``: the
    log's cleaned joint motion, if already made). The attitude is the IMU frame's (the body's
    times ``config.imu_mounting()``: the body's with the default identity mounting); the vehicle
    starts from the IMU's attitude and mean rates brought into the body frame."""
    names = tuple(uvms.arm.model.names[1:])
    motion = motion if motion is not None else joint_motion(log.select_joints(names), config.cleaning)
    if config.joint_time_offset:
        motion = motion.delayed(config.joint_time_offset)
    t0 = max(float(log.joint_time[0]), float(log.imu_time[0]))
    t1 = min(float(log.joint_time[-1]), float(log.imu_time[-1]))
    first = int(np.searchsorted(log.imu_time, t0))
    quaternion = log.imu_quaternion[min(first, log.imu_time.size - 1)]
    mounting = config.imu_mounting()
    x_, y_, z_, w_ = quaternion / np.linalg.norm(quaternion)
    body = pin.Quaternion(pin.Quaternion(w_, x_, y_, z_).toRotationMatrix() @ mounting.T)
    pose = np.concatenate([np.zeros(3), body.coeffs()])
    twist = np.zeros(6)
    if log.imu_angular_velocity is not None and config.rate_window > 0.0:
        window = (log.imu_time >= t0) & (log.imu_time <= t0 + config.rate_window)
        if window.any():
            twist[3:] = mounting @ log.imu_angular_velocity[window].mean(axis=0)
    water = Water(rho=config.water_density, current={"model": "none"})
    steps = int(math.floor((t1 - t0) / config.output_period + 1e-9))
    time = t0 + config.output_period * np.arange(steps + 1)
    inner, h = inner_steps(config.output_period, config.inner_step)
    grid = motion.tabulate(t0, 0.5 * h, 2 * inner * steps + 1)  # every RK4 stage time
    plant = PrescribedUVMSPlant(uvms, grid, water, UVMSPlantConfig(inner_step=config.inner_step))
    x = plant.initial_state(t0, pose, twist)
    trim = None
    if config.trim:  # the per-log trim: a constant body moment against the restoring moment at rest
        still = x.copy()
        still[3:7] = _rest_attitude(log, motion, t0, mounting, config.trim_window)
        still[plant.nq :] = 0.0
        trim = np.zeros(6)
        trim[3:6] = -config.trim * plant.free_force(t0, still)[3:6]
    rpy = np.empty((time.size, 3))
    for k in range(time.size):
        rpy[k] = pin.rpy.matrixToRpy(pin.Quaternion(x[3:7]).normalized().toRotationMatrix() @ mounting)
        if k < steps:
            x, _ = plant.step(float(time[k]), x, trim, config.output_period)
    return time, rpy


def _rest_attitude(log: TrialLog, motion, t0: float, mounting: np.ndarray, window: float) -> np.ndarray:
    """The body's quaternion (x y z w) at rest before the arm moves: the IMU's mean roll and pitch
    over ``[t0, t0 + window]``, cut where a joint first moves faster than 0.02 rad/s (the first
    sample's yaw; the first sample alone with a zero window or an arm moving from the start)."""
    grid = t0 + np.arange(0.0, window + 1e-9, 0.02)
    _, rates, _ = motion.sample(grid)
    moving = np.flatnonzero(np.abs(rates).max(axis=1) > 0.02)
    end = grid[moving[0]] if moving.size else t0 + window
    inside = (log.imu_time >= t0) & (log.imu_time <= end)
    first = min(int(np.searchsorted(log.imu_time, t0)), log.imu_time.size - 1)
    inside[first] = True
    rotations = []
    for x_, y_, z_, w_ in log.imu_quaternion[inside]:
        rotations.append(pin.Quaternion(w_, x_, y_, z_).normalized().toRotationMatrix() @ mounting.T)
    rpy = np.array([pin.rpy.matrixToRpy(r) for r in rotations])
    roll, pitch = rpy[:, 0].mean(), rpy[:, 1].mean()
    return pin.Quaternion(pin.rpy.rpyToMatrix(roll, pitch, rpy[0, 2])).coeffs()


def measured(log: TrialLog, time: np.ndarray, config: ReplayConfig) -> tuple[np.ndarray, np.ndarray]:
    """``(imu, mocap)`` roll pitch yaw (k, 3) at ``time`` (mocap NaN without motion capture)."""
    imu_t, imu_rpy = clean_attitude(log.imu_time, roll_pitch_yaw(log.imu_quaternion), config.cleaning)
    imu = _interp_angles(time, imu_t, imu_rpy)
    mocap = np.full_like(imu, np.nan)
    if log.mocap_time is not None and log.mocap_time.size > 5:
        mocap_t, mocap_rpy = clean_attitude(log.mocap_time, roll_pitch_yaw(log.mocap_quaternion), config.cleaning)
        mocap = _interp_angles(time, mocap_t, mocap_rpy)
        outside = (time < mocap_t[0]) | (time > mocap_t[-1])
        mocap[outside] = np.nan
    return imu, mocap


def attitude_metrics(simulated: np.ndarray, imu: np.ndarray, mocap: np.ndarray) -> dict[str, Any]:
    """Per axis (roll, pitch), in degrees: RMSE and peak-excursion error of the simulation against
    the IMU and the motion capture, the hold baseline (the initial value held) against the IMU,
    and the IMU-mocap disagreement (the measurement floor)."""
    out: dict[str, Any] = {}
    for i, axis in enumerate(AXES):
        sim = np.degrees(simulated[:, i])
        for name, reference in (("imu", imu), ("mocap", mocap)):
            ref = np.degrees(reference[:, i])
            ok = np.isfinite(ref)
            if ok.sum() < 2:
                out[f"{axis}_rmse_{name}_deg"] = None
                out[f"{axis}_peak_error_{name}_deg"] = None
                continue
            out[f"{axis}_rmse_{name}_deg"] = float(np.sqrt(np.mean((sim[ok] - ref[ok]) ** 2)))
            excursion_sim = float(np.max(np.abs(sim[ok] - sim[0])))
            excursion_ref = float(np.max(np.abs(ref[ok] - ref[ok][0])))
            out[f"{axis}_peak_error_{name}_deg"] = excursion_sim - excursion_ref
        ref = np.degrees(imu[:, i])
        out[f"{axis}_rmse_hold_deg"] = float(np.sqrt(np.mean((ref - ref[0]) ** 2)))
        both = np.isfinite(mocap[:, i])
        out[f"{axis}_imu_vs_mocap_deg"] = (
            float(np.sqrt(np.mean((np.degrees(mocap[both, i]) - ref[both]) ** 2))) if both.sum() > 1 else None
        )
    return out


def replay_log(log: TrialLog, uvms, config: ReplayConfig) -> ReplayResult:
    time, rpy = simulate(log, uvms, config)
    imu, mocap = measured(log, time, config)
    return ReplayResult(log.name, time, rpy, imu, mocap, attitude_metrics(rpy, imu, mocap))


# --- many trials, in parallel ----------------------------------------------------------

_WORKER: dict[str, Any] = {}


def _init(vehicle: VehicleSpec, arm: Any, config: ReplayConfig) -> None:
    _WORKER["uvms"] = build_system(vehicle, arm)
    _WORKER["config"] = config


def _replay_path(path: str) -> ReplayResult:
    uvms = _WORKER["uvms"]
    log = load_trial(path, tuple(uvms.arm.model.names[1:]))
    return replay_log(log, uvms, _WORKER["config"])


def replay_many(
    paths: list[Path], vehicle: VehicleSpec, arm: Any, config: ReplayConfig, workers: int = 2, progress=None
) -> list[ReplayResult]:
    """Replay every log of ``paths`` (in their order); ``workers`` processes (0 or 1: this one);
    ``progress(done, total, name)`` after each trial. Bad logs raise LogError before any run."""
    uvms = build_system(vehicle, arm)
    names = tuple(uvms.arm.model.names[1:])
    for path in paths:  # read and check every log first: one clear message, nothing half done
        load_trial(path, names)
    results: list[ReplayResult] = []
    if workers <= 1 or len(paths) == 1:
        _init(vehicle, arm, config)
        for path in paths:
            results.append(_replay_path(str(path)))
            if progress:
                progress(len(results), len(paths), results[-1].name)
        return results
    with ProcessPoolExecutor(workers, initializer=_init, initargs=(vehicle, arm, config)) as pool:
        for result in pool.map(_replay_path, [str(p) for p in paths]):
            results.append(result)
            if progress:
                progress(len(results), len(paths), result.name)
    return results


def summary(results: list[ReplayResult]) -> dict[str, Any]:
    """Per-trial metrics and their means over the trials (degrees)."""
    trials = {r.name: r.metrics for r in results}
    keys = sorted({k for r in results for k in r.metrics})
    means = {}
    for key in keys:
        values = [r.metrics[key] for r in results if r.metrics.get(key) is not None]
        means[key] = float(np.mean(values)) if values else None
        if "peak_error" in key and values:
            means[key.replace("peak_error", "peak_abs_error")] = float(np.mean(np.abs(values)))
    return {"trials": trials, "mean": means, "n_trials": len(results)}


def write_trial(out: Path, result: ReplayResult, figures: bool = True) -> None:
    """``out/<trial>/attitude.csv`` (and ``attitude.png``)."""
    folder = out / result.name
    folder.mkdir(parents=True, exist_ok=True)
    header = "time_s,sim_roll,sim_pitch,sim_yaw,imu_roll,imu_pitch,imu_yaw,mocap_roll,mocap_pitch,mocap_yaw"
    table = np.column_stack([result.time, result.simulated, result.imu, result.mocap])
    lines = [header] + [",".join("" if not np.isfinite(v) else repr(float(v)) for v in row) for row in table]
    atomic_write(folder / "attitude.csv", "\n".join(lines) + "\n")
    if figures:
        plot_trial(folder / "attitude.png", result)


def plot_trial(path: Path, result: ReplayResult) -> None:
    from matplotlib.figure import Figure

    figure = Figure(figsize=(8, 4.5), layout="constrained")
    axes = figure.subplots(2, 1, sharex=True)
    for i, (ax, axis) in enumerate(zip(axes, AXES, strict=True)):
        ax.plot(result.time, np.degrees(result.imu[:, i]), color="k", lw=1.2, label="IMU")
        ax.plot(result.time, np.degrees(result.mocap[:, i]), color="0.6", lw=1.0, label="mocap")
        ax.plot(result.time, np.degrees(result.simulated[:, i]), color="C0", lw=1.4, ls="--", label="hydroarm")
        rmse = result.metrics[f"{axis}_rmse_imu_deg"]
        ax.set_ylabel(f"{axis} (deg)")
        ax.set_title(f"{result.name}: {axis} RMSE vs IMU {rmse:.2f} deg", fontsize=9)
    axes[0].legend(fontsize=8, ncols=3)
    axes[-1].set_xlabel("time (s)")
    figure.savefig(path, dpi=110)
