"""Calibrate a vehicle + arm from its logs: least squares on the replayed attitude error.

The parameters (:data:`PARAMETERS`) are changes to the vehicle file: offsets of its centre of
buoyancy and of gravity (m, start 0), and scales of its buoyancy, damping and added mass (start
1). The residuals are the simulated minus the IMU's roll and pitch (deg) on the replay grid of
every training trial, each trial weighted by 1/sqrt(its samples) (so every trial counts alike
and the cost is the sum of the trials' mean squared errors). ``scipy.optimize.least_squares``
(trust-region reflective, bounds; forward differences with steps of ``diff_step`` times
max(1, |x|), which work at zero) fits them. The uncertainty of each parameter is the formal
standard error ``sqrt(diag(s^2 (J^T J)^-1))``, s^2 the residual variance: it treats the samples
as independent, which the quasi-static attitude's are not, so it is a lower bound.

``arm_buoyancy_scale`` scales every displaced volume of the mounted arm (a URDF arm): its
calibrated hydrodynamics file is written beside the vehicle file, which mounts it.

The calibrated vehicle file (TOML, what ``--vehicle`` reads) is the input file with the fitted
changes applied.
"""

from __future__ import annotations

import dataclasses
import os
import shlex
import time as clock
import warnings
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from hydroarm.config import ConfigError
from hydroarm.model.vehicle.description import VehicleSpec
from hydroarm.sim.files import atomic_write
from hydroarm.sim.logs import joint_motion
from hydroarm.sim.trials import load_trial
from hydroarm.studies.replay import ReplayConfig, build_system, measured, simulate

PARAMETERS: dict[str, tuple[str, float, float, float]] = {
    # name: (what, start, lower, upper)
    "cb_x": ("offset of the centre of buoyancy along x (m)", 0.0, -0.05, 0.05),
    "cb_y": ("offset of the centre of buoyancy along y (m)", 0.0, -0.05, 0.05),
    "cb_z": ("offset of the centre of buoyancy along z (m)", 0.0, -0.05, 0.05),
    "cg_x": ("offset of the centre of gravity along x (m)", 0.0, -0.05, 0.05),
    "cg_y": ("offset of the centre of gravity along y (m)", 0.0, -0.05, 0.05),
    "cg_z": ("offset of the centre of gravity along z (m)", 0.0, -0.05, 0.05),
    "buoyancy_scale": ("scale of the hull's displaced volume (-)", 1.0, 0.8, 1.2),
    "rotational_damping_scale": ("scale of the K M N damping, linear and quadratic (-)", 1.0, 0.0, 20.0),
    "rotational_linear_damping_scale": ("scale of the K M N linear damping (-)", 1.0, 0.0, 20.0),
    "rotational_quadratic_damping_scale": ("scale of the K M N quadratic damping (-)", 1.0, 0.0, 20.0),
    "translational_damping_scale": ("scale of the X Y Z damping, linear and quadratic (-)", 1.0, 0.0, 20.0),
    "added_mass_scale": ("scale of the added mass (-)", 1.0, 0.0, 10.0),
    "rotational_added_inertia": ("added inertia on K M N, added to the file's diagonal (kg m^2)", 0.0, 0.0, 1.0),
    "arm_buoyancy_scale": ("scale of every arm link's displaced volume (-)", 1.0, 0.0, 2.0),
    "joint_time_offset": ("delay of the arm's log behind the IMU's clock (s; a replay setting)", 0.0, -0.5, 0.5),
    "imu_roll_deg": ("the IMU's mounting roll in the body frame (deg; a replay setting)", 0.0, -10.0, 10.0),
    "imu_pitch_deg": ("the IMU's mounting pitch in the body frame (deg; a replay setting)", 0.0, -10.0, 10.0),
    "imu_yaw_deg": ("the IMU's mounting yaw in the body frame (deg; a replay setting)", 0.0, -10.0, 10.0),
    "trim": ("fraction of each log's initial restoring moment cancelled (-; a replay setting)", 0.0, 0.0, 1.0),
}
"""The calibratable parameters of a vehicle file: what, start value, bounds."""

SCALAR_REPLAY_SETTINGS = ("joint_time_offset", "trim")
REPLAY_SETTINGS = (*SCALAR_REPLAY_SETTINGS, "imu_roll_deg", "imu_pitch_deg", "imu_yaw_deg")
"""The parameters that are replay settings (:class:`~hydroarm.studies.replay.ReplayConfig`), not
vehicle-file numbers: the calibrated file's header and JSON give them, ``--set`` passes them."""

SCALES = {"cb_": 0.01, "cg_": 0.01, "joint_time_offset": 0.1, "rotational_added_inertia": 0.1, "imu_": 1.0}
"""The typical size of a parameter's change (least_squares' x_scale; 1 for the scales)."""


def replay_config(config: ReplayConfig, values: dict[str, float]) -> ReplayConfig:
    """``config`` with the fitted replay settings among ``values`` (:data:`REPLAY_SETTINGS`)."""
    update: dict[str, Any] = {k: float(v) for k, v in values.items() if k in SCALAR_REPLAY_SETTINGS}
    mounting = list(config.imu_mounting_rpy_deg)
    for i, axis in enumerate(("roll", "pitch", "yaw")):
        if f"imu_{axis}_deg" in values:
            mounting[i] = float(values[f"imu_{axis}_deg"])
            update["imu_mounting_rpy_deg"] = tuple(mounting)
    return config.model_copy(update=update) if update else config


def check_parameters(names: list[str]) -> list[str]:
    """The parameter names (``vehicle.`` prefix optional), checked; ConfigError naming the bad one."""
    out = []
    for raw in names:
        name = raw.strip().removeprefix("vehicle.")
        if name not in PARAMETERS:
            raise ConfigError(f"--params {raw!r}: unknown parameter; allowed: {', '.join(PARAMETERS)}")
        if name in out:
            raise ConfigError(f"--params {raw!r}: given twice")
        out.append(name)
    if not out:
        raise ConfigError(f"--params: give at least one of {', '.join(PARAMETERS)}")
    return out


def fitted_replay_settings(config: ReplayConfig, values: dict[str, float]) -> dict[str, float | list[float]]:
    """The replay settings among the fitted ``values`` (:data:`REPLAY_SETTINGS`) as they stand on
    ``config``, the replay settings the calibration ran with: what the calibrated file's
    ``[replay]`` table holds ({} if none was fitted)."""
    fitted = replay_config(config, values)
    out: dict[str, float | list[float]] = {k: float(getattr(fitted, k)) for k in SCALAR_REPLAY_SETTINGS if k in values}
    if any(k.startswith("imu_") for k in values):
        out["imu_mounting_rpy_deg"] = [float(v) for v in fitted.imu_mounting_rpy_deg]
    return out


def replay_settings_hint(settings: dict[str, float | list[float]]) -> str:
    """``settings`` (:func:`fitted_replay_settings`) as ``--set`` options, each quoted for a POSIX
    shell (zsh globs an unquoted ``[...]``); '' if none."""

    def text(value: float | list[float]) -> str:
        return "[" + ",".join(f"{v:.6g}" for v in value) + "]" if isinstance(value, list) else f"{value:.6g}"

    return " ".join(f"--set {shlex.quote(f'{key}={text(value)}')}" for key, value in settings.items())


def apply_parameters(spec: VehicleSpec, values: dict[str, float]) -> VehicleSpec:
    """The vehicle file with the parameters' values applied (module docstring)."""
    data = spec.model_dump(by_alias=True)
    for name, value in values.items():
        if name.startswith("arm_") or name in REPLAY_SETTINGS:
            continue  # the arm's (apply_arm_parameters) or the replay's (replay_config)
        if name[:3] in ("cb_", "cg_"):
            data[name[:2]]["xyz".index(name[3])] += float(value)
        elif name == "buoyancy_scale":
            data["displaced_volume"] *= float(value)
        elif name in ("rotational_damping_scale", "translational_damping_scale"):
            part = slice(3, 6) if name.startswith("rotational") else slice(0, 3)
            for key in ("linear_damping", "quadratic_damping"):
                row = list(data[key])
                row[part] = [float(value) * x for x in row[part]]
                data[key] = row
        elif name.startswith("rotational_") and name.endswith("_damping_scale"):
            key = "linear_damping" if "linear" in name else "quadratic_damping"
            row = list(data[key])
            row[3:6] = [float(value) * x for x in row[3:6]]
            data[key] = row
        elif name == "rotational_added_inertia":
            added = np.asarray(data["added_mass"], dtype=float)
            added = np.diag(added) if added.ndim == 1 else added
            added[3:6, 3:6] += float(value) * np.eye(3)
            data["added_mass"] = added.tolist()
        elif name == "added_mass_scale":
            added = np.asarray(data["added_mass"], dtype=float) * float(value)
            data["added_mass"] = added.tolist()
        else:  # pragma: no cover - names are checked
            raise ConfigError(f"unknown parameter {name!r}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return VehicleSpec.model_validate(data)


def apply_arm_parameters(arm, values: dict[str, float]):
    """The arm (an :class:`~hydroarm.model.arm.description.Arm`) with ``arm_buoyancy_scale`` applied."""
    scale = values.get("arm_buoyancy_scale")
    if scale is None:
        return arm
    cylinders = tuple(dataclasses.replace(c, displaced_volume=c.displaced_volume * float(scale)) for c in arm.cylinders)
    return dataclasses.replace(arm, cylinders=cylinders)


def write_calibrated_arm(path: Path, arm_source: str, arm, scale: float) -> None:
    """The mounted URDF arm's hydrodynamics file with every displaced volume times ``scale``."""
    from hydroarm.model.arm.loading import builtin_arm_path, is_urdf_source
    from hydroarm.model.arm.urdf_import import load_hydro_spec

    if not is_urdf_source(arm_source):
        raise ConfigError(f"arm_buoyancy_scale: the mounted arm {arm_source!r} is not a URDF arm with a hydro file")
    source = builtin_arm_path(arm_source) if not Path(arm_source).exists() else Path(arm_source)
    hydro = load_hydro_spec(source)
    data = hydro.model_dump(exclude_none=True)
    urdf = (source.parent / hydro.urdf).resolve()
    data["urdf"] = os.path.relpath(urdf, path.absolute().parent)
    data["name"] = f"{hydro.name or arm.name}-calibrated"
    for link in data.get("links", []):
        own = [c for c in arm.cylinders if c.name == link["link"] or c.name.startswith(link["link"] + "_")]
        for cylinder in link.get("cylinders", []):
            if "displaced_volume" in cylinder:
                cylinder["displaced_volume"] *= scale
        if "displaced_volume" in link or not link.get("cylinders"):
            link["displaced_volume"] = float(sum(c.displaced_volume for c in own))  # already scaled
    header = f"# {arm_source} with every displaced volume times {scale:.6g} (hydroarm calibrate)\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, header + to_toml(data))


# --- the residuals, in worker processes -------------------------------------------------

_STATE: dict[str, Any] = {}
DIVERGED = 90.0
"""deg: the residual of every sample of a replay that diverged (the fit backs off from it)."""


def _init(spec: VehicleSpec, arm: Any, config: ReplayConfig) -> None:
    _STATE.update(spec=spec, config=config, logs={}, measured={}, motions={})
    _STATE["arm"] = build_system(spec, arm).arm


def _residual(task: tuple[str, dict[str, float]]) -> np.ndarray:
    path, values = task
    arm = _STATE["arm"]
    names = tuple(arm.model.names[1:])
    if path not in _STATE["logs"]:
        _STATE["logs"][path] = load_trial(path, names)
        _STATE["motions"][path] = joint_motion(_STATE["logs"][path], _STATE["config"].cleaning)
    log = _STATE["logs"][path]
    uvms = build_system(apply_parameters(_STATE["spec"], values), apply_arm_parameters(arm, values))
    try:
        time, rpy = simulate(log, uvms, replay_config(_STATE["config"], values), _STATE["motions"][path])
    except np.linalg.LinAlgError:  # a diverging vehicle: as bad as a residual gets, not a crash
        time, rpy = None, None
    if rpy is None or not np.all(np.isfinite(rpy)):
        n = _STATE["measured"][path].shape[0] if path in _STATE["measured"] else 2
        return np.full(2 * n, DIVERGED / np.sqrt(n))
    if path not in _STATE["measured"]:
        _STATE["measured"][path] = measured(log, time, _STATE["config"])[0]
    imu = _STATE["measured"][path]
    error = np.degrees(rpy[:, :2] - imu[:, :2])
    return error.ravel() / np.sqrt(error.shape[0])


@dataclass
class Calibration:
    """A fit: ``values`` and ``uncertainty`` (1 sigma) per parameter, ``cost`` (sum of the
    training trials' mean squared roll and pitch errors, deg^2), ``seconds`` the fit's wall time."""

    names: list[str]
    values: dict[str, float]
    uncertainty: dict[str, float]
    cost: float
    initial_cost: float
    evaluations: int
    seconds: float
    status: str
    correlation: list[list[float]] = dataclasses.field(default_factory=list)


def calibrate(
    paths: list[Path],
    spec: VehicleSpec,
    arm: Any,
    names: list[str],
    config: ReplayConfig | None = None,
    workers: int = 2,
    diff_step: float = 1e-3,
    max_evaluations: int = 30,
    tolerance: float = 1e-4,
) -> Calibration:
    """Fit ``names`` on the logs ``paths`` (module docstring)."""
    config = config or ReplayConfig()
    names = check_parameters(names)
    start = np.array([PARAMETERS[n][1] for n in names])
    lower = np.array([PARAMETERS[n][2] for n in names])
    upper = np.array([PARAMETERS[n][3] for n in names])
    keys = [str(p) for p in paths]
    began = clock.perf_counter()
    pool = ProcessPoolExecutor(workers, initializer=_init, initargs=(spec, arm, config)) if workers > 1 else None
    if pool is None:
        _init(spec, arm, config)
    count = [0]

    def residuals(x: np.ndarray) -> np.ndarray:
        count[0] += 1
        values = dict(zip(names, (float(v) for v in x), strict=True))
        tasks = [(key, values) for key in keys]
        parts = list(pool.map(_residual, tasks)) if pool is not None else [_residual(t) for t in tasks]
        return np.concatenate(parts)

    try:
        initial = residuals(start)
        fit = least_squares(
            residuals, start, bounds=(lower, upper), method="trf", diff_step=diff_step, max_nfev=max_evaluations,
            ftol=tolerance, xtol=tolerance, gtol=tolerance,
            x_scale=np.array([next((v for k, v in SCALES.items() if n.startswith(k)), 1.0) for n in names]),
        )  # fmt: skip
    finally:
        if pool is not None:
            pool.shutdown()
    m, p = fit.fun.size, len(names)
    jtj = fit.jac.T @ fit.jac
    variance = 2.0 * fit.cost / max(m - p, 1)
    try:
        covariance = np.linalg.inv(jtj) * variance
        sigma = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
        with np.errstate(invalid="ignore", divide="ignore"):
            correlation = covariance / np.outer(sigma, sigma)
    except np.linalg.LinAlgError:
        sigma = np.full(p, np.nan)
        correlation = np.full((p, p), np.nan)
    return Calibration(
        names=names,
        values=dict(zip(names, (float(v) for v in fit.x), strict=True)),
        uncertainty=dict(zip(names, (float(s) for s in sigma), strict=True)),
        cost=float(2.0 * fit.cost),
        initial_cost=float(initial @ initial),
        evaluations=int(count[0]),
        seconds=clock.perf_counter() - began,
        status=str(fit.message),
        correlation=[[float(c) for c in row] for row in correlation],
    )


def write_calibrated_vehicle(
    path: Path,
    spec: VehicleSpec,
    calibration: Calibration,
    sources: list[str],
    arm=None,
    config: ReplayConfig | None = None,
) -> None:
    """The calibrated vehicle file (TOML) with a header saying what was fitted on what, and the
    fitted replay settings in its ``[replay]`` table (on ``config``, the replay settings the
    calibration ran with; default: the defaults), so that ``hydroarm replay --vehicle <path>``
    alone replays what was calibrated; with ``arm_buoyancy_scale``, the calibrated arm file
    ``<stem>.arm.hydro.toml`` beside it (``arm`` the mounted :class:`~hydroarm.model.arm.description.Arm`)."""
    calibrated = apply_parameters(spec, calibration.values)
    data = calibrated.model_dump(by_alias=True, exclude_none=True)
    data["name"] = f"{spec.name}-calibrated"
    replay = {**spec.replay, **fitted_replay_settings(config or ReplayConfig(), calibration.values)}
    data.pop("replay", None)
    if replay:
        data["replay"] = replay
    if "arm_buoyancy_scale" in calibration.values:
        arm_path = path.with_name(path.stem + ".arm.hydro.toml")
        scale = calibration.values["arm_buoyancy_scale"]
        write_calibrated_arm(arm_path, spec.mount.arm, apply_arm_parameters(arm, calibration.values), scale)
        data["mount"]["arm"] = str(arm_path.absolute())
    arm = Path(data["mount"]["arm"])
    if arm.is_absolute() and arm.is_file():  # an arm file: relative to the calibrated file, as it was
        data["mount"]["arm"] = os.path.relpath(arm, path.absolute().parent)
    lines = [f"# {spec.name} calibrated by hydroarm calibrate on {len(sources)} logs: {', '.join(sources)}"]
    for name in calibration.names:
        lines.append(
            f"# {name} = {calibration.values[name]:.6g} +- {calibration.uncertainty[name]:.2g} ({PARAMETERS[name][0]})"
        )
    lines.append(f"# cost (sum of the trials' mean squared roll and pitch errors): {calibration.cost:.4g} deg^2")
    if replay:
        lines.append("# the fitted replay settings: the [replay] table (hydroarm replay applies them)")
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, "\n".join(lines) + "\n" + to_toml(data))


def _value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    return repr(float(value)) if isinstance(value, float) else repr(value)


def to_toml(data: dict[str, Any]) -> str:
    """A vehicle file's dict as TOML: scalars and lists, then tables, then arrays of tables."""
    plain = {k: v for k, v in data.items() if not isinstance(v, dict) and not _tables(v)}
    lines = [f"{k} = {_value(v)}" for k, v in plain.items()]
    for key, value in data.items():
        if isinstance(value, dict):
            lines += ["", f"[{key}]"] + [f"{k} = {_value(v)}" for k, v in value.items() if v is not None]
    for key, value in data.items():
        if _tables(value):
            for row in value:
                lines += ["", f"[[{key}]]"]
                lines += [f"{k} = {_value(v)}" for k, v in row.items() if v is not None and not _tables(v)]
                for sub, rows in row.items():
                    if _tables(rows):
                        for inner in rows:
                            lines += ["", f"[[{key}.{sub}]]"] + [f"{k} = {_value(v)}" for k, v in inner.items()]
    return "\n".join(lines) + "\n"


def _tables(value: Any) -> bool:
    return isinstance(value, list) and bool(value) and all(isinstance(v, dict) for v in value)
