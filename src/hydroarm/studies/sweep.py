"""Parameter sweeps: many closed-loop runs over a grid or a random sample of settings.

A sweep file (TOML or YAML, validated into :class:`SweepConfig`) names the
controllers, the seeds, the settings shared by every run (``[base]``, an
:class:`~hydroarm.studies.experiment.ExperimentConfig`) and the settings that vary
(``[parameters]``: dotted keys such as ``mpc.r``, ``water.current.scale``,
``plant.noise_variance``, ``arm``, ``mismatch.mass_scale``)::

    controllers = ["MPC", "GP-MPC"]
    seeds = 2                       # seeds 0 and 1; or a list [0, 4, 7]
    mode = "grid"                   # every combination; "random": `samples` draws

    [base]
    arm = "paper"
    duration = 3.0

    [parameters]
    "water.current.scale" = [0.5, 1.0, 2.0]
    "mismatch.mass_scale" = [1.0, 1.3]
    "mpc.r" = { low = 1e-4, high = 1e-1, num = 4, log = true }

:func:`run_sweep` runs every combination x seed x controller that is not
finished yet, on a local process pool (default) or a Ray cluster, and writes
into its output folder:

* ``sweep.json``: the validated sweep and its plan (one entry per row);
* ``runs/<id>.json``: one finished run (settings + metrics), written
  atomically; ``<id>`` is a hash of everything that determines the run (the
  arm's content, the settings the controller uses, the mismatch, controller,
  seed), so a re-run skips finished runs and recomputes an unreadable file;
  ``runs/<id>.npz`` the trajectory when asked for;
* ``results.csv``: one row per run with every setting and metric, rewritten
  atomically after each finished run (an interrupted sweep leaves a readable
  table);
* ``summary.md``, ``summary.json``, ``ep_boxplot.png``, ``ep_by_<key>.png``,
  ``ep_distribution.png``, ``robustness.png``: written by :func:`summarise` at
  the end, with a robustness table (per controller: runs within a tracking
  bound, ``[robustness]`` in the sweep file, runs that stopped, fault counts).

Random starts: ``initial_state.position_spread`` / ``velocity_spread`` in
``[base]`` and ``"initial_state.seed" = {low = 0, high = 1000000, integer =
true}`` in ``[parameters]`` give every sample its own start
(:class:`~hydroarm.studies.experiment.InitialState`).

Model mismatch. The controllers know the arm file (the nominal model); the
true plant is that arm plus the water. ``water.*`` and ``plant.*`` settings
exist only in the plant, so sweeping them is already mismatch;
``mismatch.mass_scale`` (every link's mass and rotational inertia about its
centre of gravity, i.e. the density, times this factor) and
``mismatch.payload_kg`` (a point mass at the flange, or at the last link's
centre of gravity for URDF arms) change the plant's rigid body only
(:func:`perturbed_arm`). The recorded ``disturbance`` of a trajectory is then
relative to the plant's own (perturbed) dry dynamics.

Executors are small and pluggable (:class:`SerialExecutor`,
:class:`LocalExecutor`, :class:`RayExecutor`): each only turns tasks into
outcomes; all result handling is here. Ray is optional (``pip install
hydroarm[ray]``) and used through its own API only (``ray.remote``,
``ray.wait``).
"""

from __future__ import annotations

import csv
import hashlib
import io
import itertools
import json
import math
import multiprocessing
import os
import signal
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, Protocol, Self

import numpy as np
import pinocchio as pin
import pydantic

from hydroarm.model.arm import Arm
from hydroarm.model.loading import BUILTIN_ARMS, load_arm
from hydroarm.config import ConfigError, FrozenModel, read_mapping, validate
from hydroarm.studies.experiment import (
    CONTROLLER_SECTIONS,
    CONTROLLER_SETTINGS,
    CONTROLLERS,
    canonical_name,
    ExperimentConfig,
    build_controller,
    start_for_arm,
    with_overrides,
)
from hydroarm.studies.runner import fault_counts, stop_reason

FORMAT = 2
"""Version of the run-file layout; a run file of another format is recomputed.
2: fault counts, ``stopped`` and the error envelope."""

MAX_RUNS = 100_000
MISMATCH_PREFIX = "mismatch."
FAULT_PREFIX = "faults."
"""Results-table columns of the fault counts: ``faults.<key>``, one per key that occurred."""

ENVELOPE_WINDOW = 0.1
"""s: a run file keeps the largest |q_r - q| over joints per window of this length (at
least one control step), so the robustness bound can be checked from any time on."""


# --- the sweep file -----------------------------------------------------------------


class Mismatch(FrozenModel):
    """How the true plant's rigid body differs from the arm file the controllers use.

    ``mass_scale``: every link's mass and rotational inertia (about its centre
    of gravity) times this factor, centres of gravity unchanged; ``payload_kg``:
    a point mass at the flange (DH arms) or at the last link's centre of gravity
    (URDF arms), in the plant only.
    """

    mass_scale: float = pydantic.Field(1.0, gt=0.0, le=100.0)
    payload_kg: float = pydantic.Field(0.0, ge=0.0, le=1000.0)

    @property
    def is_identity(self) -> bool:
        return self.mass_scale == 1.0 and self.payload_kg == 0.0


class Robustness(FrozenModel):
    """The tracking bound of the summary's robustness table.

    A run stays within the bound if it ran to the end (not diverged, not stopped
    by the runner) and from ``after`` s on |q_r - q| < ``max_error`` rad on every
    joint at every control step (true q). It is checked on the run's error
    envelope (the largest error over joints per :data:`ENVELOPE_WINDOW` s), so
    ``after`` is rounded up to a window start. A run that ends before ``after``
    is never within the bound.
    """

    max_error: float = pydantic.Field(0.5, gt=0.0, le=100.0, description="rad")
    after: float = pydantic.Field(2.0, ge=0.0, le=3600.0, description="s")


class Range(FrozenModel):
    """A range of values: ``num`` evenly spaced points (grid) or uniform draws (random).

    ``log``: evenly spaced / uniform in log space (``low`` > 0); ``integer``:
    round to integers (e.g. ``gp.window``, ``mpc.horizon``).
    """

    low: float
    high: float
    log: bool = False
    integer: bool = False
    num: int | None = pydantic.Field(None, ge=1, le=10_000, description="grid mode: how many values")

    @pydantic.model_validator(mode="after")
    def _check(self) -> Self:
        if self.high < self.low:
            raise ValueError(f"high ({self.high}) < low ({self.low}): high must be at least low")
        if self.log and self.low <= 0.0:
            raise ValueError(f"log = true needs low > 0 (low = {self.low})")
        return self

    def grid(self) -> list[float | int]:
        """The ``num`` grid values (duplicates removed after integer rounding)."""
        num = int(self.num or 1)
        values = np.geomspace(self.low, self.high, num) if self.log else np.linspace(self.low, self.high, num)
        return _unique([_as_number(x, self.integer) for x in values])

    def draw(self, rng: np.random.Generator) -> float | int:
        """One uniform draw (in log space if ``log``)."""
        if self.log:
            x = math.exp(rng.uniform(math.log(self.low), math.log(self.high)))
        else:
            x = rng.uniform(self.low, self.high)
        return _as_number(min(max(x, self.low), self.high), self.integer)


def _as_number(x: float, integer: bool) -> float | int:
    return int(round(float(x))) if integer else float(x)


def _unique(values: list) -> list:
    out: list = []
    for value in values:
        if value not in out:
            out.append(value)
    return out


class SweepConfig(FrozenModel):
    """A whole sweep file (see the module docstring and ``examples/sweep.toml``).

    ``controllers``: names (case-insensitive: smc, mpc, gp-mpc); ``seeds``: a
    count n (seeds 0..n-1) or a list; ``mode``: ``grid`` (every combination of
    the parameters' values) or ``random`` (``samples`` points drawn with
    ``sampling_seed``: a list is a uniform choice, a range a uniform draw);
    ``base``: the settings of every run; ``mismatch``: the plant's rigid-body
    mismatch of every run; ``parameters``: dotted key -> list of values or
    :class:`Range`; ``save_trajectories``: also keep ``runs/<id>.npz``;
    ``metric``: the column the summary and the plots compare (default the mean
    E_p over joints; ``Ep_steady_mean`` leaves out the first 2 s);
    ``robustness``: the tracking bound of the summary's robustness table
    (:class:`Robustness`; an analysis setting: changing it recomputes no run).
    """

    name: str = pydantic.Field("sweep", min_length=1, max_length=200)
    description: str = ""
    controllers: list[Literal["SMC", "MPC", "GP-MPC"]] = pydantic.Field(min_length=1)
    seeds: (
        Annotated[int, pydantic.Field(ge=1, le=MAX_RUNS)]
        | Annotated[list[pydantic.NonNegativeInt], pydantic.Field(min_length=1, max_length=MAX_RUNS)]
    ) = 1
    mode: Literal["grid", "random"] = "grid"
    samples: int | None = pydantic.Field(None, ge=1, le=MAX_RUNS)
    sampling_seed: int = pydantic.Field(0, ge=0)
    base: ExperimentConfig = ExperimentConfig()
    mismatch: Mismatch = Mismatch()
    parameters: dict[str, list[Any] | Range] = pydantic.Field(default_factory=dict)
    save_trajectories: bool = False
    metric: Literal[
        "Ep_mean", "Ep_steady_mean", "rms_mean", "max_error", "torque_rms_mean", "time_to_band_max", "step_ms_median"
    ] = "Ep_mean"
    robustness: Robustness = Robustness()

    @pydantic.field_validator("controllers", mode="before")
    @classmethod
    def _controller_case(cls, value: Any) -> Any:
        if isinstance(value, list):
            return [_canonical_or_same(v) for v in value]
        return value

    @pydantic.field_validator("parameters", mode="before")
    @classmethod
    def _flatten(cls, value: Any) -> Any:
        return flatten_parameters(value) if isinstance(value, dict) else value

    @property
    def seed_list(self) -> list[int]:
        return list(range(self.seeds)) if isinstance(self.seeds, int) else list(self.seeds)


def _canonical_or_same(name: Any) -> Any:
    """The registry's canonical name of a controller (any spelling); anything else unchanged,
    for the field's own validation to name."""
    try:
        return canonical_name(name)
    except ConfigError:
        return name


def flatten_parameters(parameters: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"mpc": {"r": [..]}}`` -> ``{"mpc.r": [..]}`` (TOML's unquoted dotted keys nest);
    a mapping with ``low``/``high`` is a :class:`Range`, not a level."""
    out: dict[str, Any] = {}
    for key, value in parameters.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, Mapping) and not ({"low", "high"} & set(value)):
            out.update(flatten_parameters(value, dotted + "."))
        else:
            out[dotted] = value
    return out


def validate_sweep(data: Mapping[str, Any], source: str = "sweep", folder: Path | None = None) -> SweepConfig:
    """Validate a sweep mapping; errors name the field (``parameters.mpc.r``, ``controllers.1``).

    ``base`` may be a path to an experiment settings file (relative to ``folder``).
    """
    data = dict(data)
    if isinstance(data.get("base"), str):
        try:
            data["base"] = read_mapping(_resolve(data["base"], folder))
        except ConfigError as error:
            raise ConfigError(f"{source}: base = {data['base']!r}: {error}") from None
    parameters = data.get("parameters", {})
    if isinstance(parameters, Mapping):
        parameters = flatten_parameters(parameters)
        for key, value in parameters.items():
            if isinstance(value, list) and not value:
                raise ConfigError(f"{source}: parameters.{key}: empty list: give at least one value")
            if not isinstance(value, (list, Mapping)):
                raise ConfigError(
                    f"{source}: parameters.{key} = {value!r}: give a list of values or a range "
                    "{low, high[, num][, log][, integer]}"
                )
            if isinstance(value, Mapping):
                try:
                    Range.model_validate(value)
                except pydantic.ValidationError as error:
                    problems = "; ".join(_range_problem(e) for e in error.errors())
                    raise ConfigError(f"{source}: parameters.{key}: {problems}") from None
        data["parameters"] = parameters
    config = validate(SweepConfig, data, source)
    check_sweep(config, source)
    return config


def _range_problem(error: Mapping[str, Any]) -> str:
    """One pydantic error of a :class:`Range` as ``field = value: what is allowed``."""
    where = ".".join(map(str, error["loc"]))
    if error["type"] == "extra_forbidden":
        return f"unknown key '{where}' (a range has low, high, num, log, integer)"
    message = error["msg"].removeprefix("Value error, ")
    return f"{where} = {error.get('input')!r}: {message}" if where else message


def check_sweep(config: SweepConfig, source: str = "sweep") -> None:
    """What the field types cannot say: mode/samples/range combinations, seeds, duplicates."""
    if len(set(config.controllers)) != len(config.controllers):
        raise ConfigError(f"{source}: controllers: a controller is listed twice ({config.controllers})")
    seeds = config.seed_list
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"{source}: seeds: a seed is listed twice ({seeds})")
    if config.mode == "grid" and config.samples is not None:
        raise ConfigError(f"{source}: samples: only for mode = 'random' (mode is 'grid')")
    if config.mode == "random":
        if config.samples is None:
            raise ConfigError(f"{source}: samples: missing: mode = 'random' needs the number of draws")
        if not config.parameters:
            raise ConfigError(f"{source}: parameters: mode = 'random' needs at least one parameter to draw")
    for key, value in config.parameters.items():
        if isinstance(value, list) and not value:
            raise ConfigError(f"{source}: parameters.{key}: empty list: give at least one value")
        if isinstance(value, Range):
            if config.mode == "grid" and value.num is None:
                raise ConfigError(f"{source}: parameters.{key}: a range in grid mode needs num (how many values)")
            if config.mode == "random" and value.num is not None:
                raise ConfigError(
                    f"{source}: parameters.{key}: num is for grid mode; random mode draws `samples` values"
                )


def load_sweep(path: str | Path) -> SweepConfig:
    """Read and validate a sweep file (TOML or YAML)."""
    path = Path(path)
    return validate_sweep(read_mapping(path), str(path), path.parent)


# --- the plan -----------------------------------------------------------------------


@dataclass(frozen=True)
class RunTask:
    """One closed-loop run, as sent to a worker: everything is plain data except the arm,
    which the executor sends once per arm (``arm_key``)."""

    id: str
    controller: str
    seed: int
    settings: dict  # ExperimentConfig as JSON (arm: the path the driver loaded)
    mismatch: dict
    arm_key: str
    save_trajectory: bool = False


@dataclass(frozen=True)
class PlanRow:
    """One row of the sweep's table: a point of the grid/sample, a seed, a controller."""

    index: int
    point: int
    params: dict
    controller: str
    seed: int
    config: ExperimentConfig  # ``arm`` as written in the sweep file
    mismatch: Mismatch
    id: str


@dataclass
class Plan:
    """The rows of a sweep and what running them needs."""

    config: SweepConfig
    rows: list[PlanRow]
    tasks: dict[str, RunTask]  # by run id (rows that differ only in unused settings share one)
    arms: dict[str, Arm]  # by arm digest
    keys: list[str]  # the swept parameters, in file order


def _resolve(value: str, folder: Path | None) -> Path:
    path = Path(value)
    if folder is not None and not path.is_absolute() and (folder / path).exists():
        return folder / path
    return path


def _resolve_arm(value: str, folder: Path | None) -> str:
    """A built-in name as is; a file relative to the sweep file's folder (else to the cwd)."""
    if value in BUILTIN_ARMS:
        return value
    return str(_resolve(value, folder).resolve()) if _resolve(value, folder).exists() else value


def arm_digest(arm: Arm) -> str:
    """A hash of what the simulation uses of an arm (joints, placements, inertias, limits,
    wetted cylinders): the same arm from another path has the same digest; an edited one not."""
    model = arm.model
    content = {
        "joints": [[j.shortname(), getattr(j, "axis", np.zeros(0)).tolist()] for j in model.joints],
        "parents": [int(p) for p in model.parents],
        "placements": [p.homogeneous.tolist() for p in model.jointPlacements],
        "inertias": [[i.mass, *i.lever.tolist(), *i.inertia.ravel().tolist()] for i in model.inertias],
        "gravity": model.gravity.linear.tolist(),
        "cylinders": [
            [c.name, c.joint_id, c.start.tolist(), c.end.tolist(), c.diameter, c.displaced_volume, c.cd, c.cm]
            for c in arm.cylinders
        ],
        "torque_limit": arm.torque_limit.tolist(),
        "position_limit": None if arm.position_limit is None else arm.position_limit.tolist(),
        "frames": [[f.name, int(f.parentJoint), f.placement.homogeneous.tolist()] for f in model.frames],
    }
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()[:16]


def run_id(config: ExperimentConfig, controller: str, seed: int, mismatch: Mismatch, arm_key: str) -> str:
    """The run's id: a hash of the arm's content, the settings ``controller`` reads, the
    mismatch, the controller and the seed."""
    settings = config.model_dump(mode="json")
    settings["arm"] = arm_key
    for section in CONTROLLER_SECTIONS:
        if section not in CONTROLLER_SETTINGS[controller]:
            settings.pop(section, None)
    text = json.dumps(
        {
            "format": FORMAT,
            "controller": controller,
            "seed": seed,
            "settings": settings,
            "mismatch": mismatch.model_dump(),
        },
        sort_keys=True,
    )
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def sample_points(config: SweepConfig) -> list[dict[str, Any]]:
    """The parameter points: every combination (grid) or ``samples`` draws (random)."""
    keys = list(config.parameters)
    if config.mode == "grid":
        values = [v.grid() if isinstance(v, Range) else list(v) for v in config.parameters.values()]
        return [dict(zip(keys, combo)) for combo in itertools.product(*values)]
    rng = np.random.default_rng(config.sampling_seed)
    points = []
    for _ in range(int(config.samples or 0)):
        point = {}
        for key, spec in config.parameters.items():
            point[key] = spec.draw(rng) if isinstance(spec, Range) else spec[int(rng.integers(len(spec)))]
        points.append(point)
    return points


def _label(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, str):
        return value
    return json.dumps(value)


def plan_sweep(config: SweepConfig, folder: Path | None = None, source: str = "sweep") -> Plan:
    """Validate every run's settings and load every arm before any run starts."""
    check_sweep(config, source)
    points = sample_points(config)
    size = len(points) * len(config.seed_list) * len(config.controllers)
    if size > MAX_RUNS:
        raise ConfigError(
            f"{source}: the sweep has {size} runs ({len(points)} parameter points x "
            f"{len(config.seed_list)} seeds x {len(config.controllers)} controllers); at most {MAX_RUNS}"
        )
    keys = list(config.parameters)
    arms: dict[str, Arm] = {}
    arm_keys: dict[str, str] = {}  # resolved arm source -> digest
    rows: list[PlanRow] = []
    tasks: dict[str, RunTask] = {}
    for number, point in enumerate(points):
        overrides = {k: v for k, v in point.items() if not k.startswith(MISMATCH_PREFIX)}
        mismatch_values = {
            k.removeprefix(MISMATCH_PREFIX): v for k, v in point.items() if k.startswith(MISMATCH_PREFIX)
        }
        where = ", ".join(f"{k} = {_label(v)}" for k, v in point.items()) or "base"
        try:
            experiment = with_overrides(config.base, overrides) if overrides else config.base
        except ConfigError as error:
            message = str(error).removeprefix("settings: ")
            if message.startswith("unknown setting"):
                bad = message.split("'")[1] if "'" in message else message
                raise ConfigError(
                    f"{source}: parameters.{bad}: unknown setting (a dotted key of the experiment settings, "
                    f"e.g. mpc.r or water.current.scale, or {MISMATCH_PREFIX}mass_scale / {MISMATCH_PREFIX}payload_kg)"
                ) from None
            lines = [line.removeprefix("settings: ") for line in message.splitlines()]
            raise ConfigError("\n".join(f"{source}: parameters ({where}): {line}" for line in lines)) from None
        unknown = set(mismatch_values) - set(Mismatch.model_fields)
        if unknown:
            raise ConfigError(
                f"{source}: parameters.{MISMATCH_PREFIX}{sorted(unknown)[0]}: unknown setting "
                f"(mismatch keys: {', '.join(MISMATCH_PREFIX + f for f in Mismatch.model_fields)})"
            )
        mismatch = validate(
            Mismatch, {**config.mismatch.model_dump(), **mismatch_values}, f"{source}: parameters ({where}): mismatch"
        )
        resolved = _resolve_arm(experiment.arm, folder)
        if resolved not in arm_keys:
            try:
                arm = load_arm(resolved)
            except ConfigError as error:
                text = str(error)
                raise ConfigError(
                    f"{source}: {text}" if text.startswith("arm '") else f"{source}: arm '{experiment.arm}': {text}"
                ) from None
            digest = arm_digest(arm)
            arm_keys[resolved] = digest
            arms.setdefault(digest, arm)
        key = arm_keys[resolved]
        settings = experiment.model_dump(mode="json")
        settings["arm"] = resolved
        for seed in config.seed_list:
            for controller in config.controllers:
                identifier = run_id(experiment, controller, seed, mismatch, key)
                rows.append(PlanRow(len(rows), number, dict(point), controller, seed, experiment, mismatch, identifier))
                if identifier not in tasks:
                    tasks[identifier] = RunTask(
                        identifier, controller, seed, settings, mismatch.model_dump(), key, config.save_trajectories
                    )
    return Plan(config, rows, tasks, arms, keys)


# --- one run (in a worker) -------------------------------------------------------------


def perturbed_arm(arm: Arm, mismatch: Mismatch) -> Arm:
    """The plant's arm: ``arm`` with its masses scaled and a payload added (see
    :class:`Mismatch`); ``arm`` itself if there is no mismatch. The geometry, the
    wetted cylinders and the limits are the nominal arm's."""
    if mismatch.is_identity:
        return arm
    model = arm.model.copy()
    scale = mismatch.mass_scale
    for joint in range(1, model.njoints):
        inertia = model.inertias[joint]
        model.inertias[joint] = pin.Inertia(inertia.mass * scale, inertia.lever.copy(), inertia.inertia * scale)
    if mismatch.payload_kg > 0.0:
        last = model.njoints - 1
        where = model.inertias[last].lever.copy()
        if model.existFrame("flange"):
            frame = model.frames[model.getFrameId("flange")]
            if frame.parentJoint == last:
                where = frame.placement.translation.copy()
        model.inertias[last] = model.inertias[last] + pin.Inertia(mismatch.payload_kg, where, np.zeros((3, 3)))
    return Arm(
        name=f"{arm.name} (plant: mass x{scale:g}, payload {mismatch.payload_kg:g} kg)",
        model=model,
        cylinders=arm.cylinders,
        torque_limit=arm.torque_limit,
        spec=None,
        position_limit=arm.position_limit,
    )


def _finite(value: Any) -> Any:
    """NaN/inf -> None, recursively (strict JSON)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, list):
        return [_finite(v) for v in value]
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    return value


def error_envelope(traj, window: float = ENVELOPE_WINDOW) -> dict:
    """The largest |q_r - q| over joints per window: ``{"window_s": w, "max_abs_error": [...]}``
    (rad), window i covering t in [i w, (i + 1) w); w is ``window`` rounded to whole control
    steps (at least one)."""
    period = float(traj.meta["control_period"])
    steps = max(1, int(round(window / period)))
    error = np.max(np.abs(traj.q_ref - traj.q), axis=1)  # (K,)
    peaks = [float(np.max(error[k : k + steps])) for k in range(0, len(error), steps)]
    return {"window_s": steps * period, "max_abs_error": peaks}


def steady_max_error(envelope: Mapping[str, Any] | None, after: float) -> float:
    """The largest |q_r - q| (rad) from ``after`` s on (windows starting at or after it), from
    :func:`error_envelope`'s dict; inf if an error there was not finite, NaN if no window
    starts that late."""
    if not envelope:
        return math.nan
    window = float(envelope["window_s"])
    values = [
        v if v is not None and math.isfinite(v) else math.inf
        for i, v in enumerate(envelope["max_abs_error"])
        if i * window >= after - 1e-9 * max(1.0, after)
    ]
    return float(max(values)) if values else math.nan


def assess(record: Mapping[str, Any], robustness: Robustness) -> dict:
    """A run file against the tracking bound: ``stopped`` (None if it ran to the end),
    ``steady_max_error`` (rad, NaN if it ended before ``robustness.after``) and ``within_bound``."""
    summary = record["summary"]
    stopped = summary.get("stopped")
    if stopped is None and summary.get("diverged"):
        stopped = "diverged"
    error = steady_max_error(record.get("envelope"), robustness.after)
    within = stopped is None and math.isfinite(error) and error < robustness.max_error
    return {"stopped": stopped, "steady_max_error": error, "within_bound": bool(within)}


def _scalars(metrics: dict, traj) -> dict:
    """One number per metric: means over joints (max for the error and the settling time),
    plus how the run ended and its fault count."""
    ttb = metrics["time_to_band"]
    total = traj.timings.get("total")
    return {
        "Ep_mean": float(np.mean(metrics["Ep"])),
        "Ep_steady_mean": float(np.mean(metrics["Ep_steady"])),
        "rms_mean": float(np.mean(metrics["rms"])),
        "max_error": float(np.max(metrics["max"])),
        "torque_rms_mean": float(np.mean(metrics["torque_rms"])),
        "time_to_band_max": float(np.max(ttb)) if all(math.isfinite(x) for x in ttb) else math.nan,
        "diverged": bool(metrics["diverged"]),
        "diverged_at_s": traj.meta.get("diverged_at_s"),
        "stopped": stop_reason(traj),
        "faults_total": sum(fault_counts(traj).values()),
        "step_ms_median": float(np.nanmedian(total) * 1e3)
        if total is not None and np.isfinite(total).any()
        else math.nan,
    }


def execute_run(task: RunTask, arm: Arm | None = None) -> dict:
    """Run one task: the plant gets the perturbed arm, the controller the nominal one; the
    run starts at :func:`~hydroarm.studies.experiment.start_for_arm`'s state.

    Returns ``{"record": <the run file's content>, "trajectory": <.npz bytes or None>}``;
    the driver writes both (so workers need no shared disk, e.g. on a Ray cluster).
    """
    from hydroarm import __version__
    from hydroarm.model.plant import UnderwaterPlant
    from hydroarm.studies.runner import Trajectory, run_closed_loop, tracking_metrics

    start = time.perf_counter()
    if arm is None:
        arm = _WORKER_ARMS[task.arm_key]
    config = ExperimentConfig.model_validate(task.settings)
    mismatch = Mismatch.model_validate(task.mismatch)
    plant = UnderwaterPlant(perturbed_arm(arm, mismatch), config.water, config.plant)
    reference, x0 = start_for_arm(arm, config)
    controller = build_controller(task.controller, arm, config)
    traj: Trajectory = run_closed_loop(plant, controller, reference, config.duration, task.seed, x0=x0)
    metrics = tracking_metrics(traj)
    record = {
        "format": FORMAT,
        "id": task.id,
        "controller": task.controller,
        "seed": task.seed,
        "arm_digest": task.arm_key,
        "settings": task.settings,
        "mismatch": task.mismatch,
        "metrics": metrics,
        "summary": _scalars(metrics, traj),
        "faults": fault_counts(traj),
        "error": traj.meta.get("error"),  # why the runner stopped it (a controller error), or None
        "envelope": error_envelope(traj),
        "n_joints": arm.n_joints,
        "wall_s": time.perf_counter() - start,
        "hydroarm": __version__,
    }
    blob = None
    if task.save_trajectory:
        traj.meta.update(id=task.id, settings=task.settings, mismatch=task.mismatch, arm=config.arm)
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "run.npz"
            traj.save(path)
            blob = path.read_bytes()
    return {"record": _finite(record), "trajectory": blob}


_WORKER_ARMS: dict[str, Arm] = {}


def _init_worker(arms: dict[str, Arm]) -> None:
    """Process-pool initializer: the arms arrive once per worker, not once per task.

    Workers ignore SIGINT: Ctrl-C reaches the whole process group, and only the main
    process handles it (cancels what has not started, lets running runs finish and
    save), so no worker dies mid-write or prints a traceback."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _WORKER_ARMS.clear()
    _WORKER_ARMS.update(arms)


# --- executors ---------------------------------------------------------------------------

Outcome = dict | BaseException


class Executor(Protocol):
    """Turns tasks into outcomes (the dict of :func:`execute_run`, or the exception a
    run raised), yielded as runs finish, in any order."""

    def map(self, tasks: Sequence[RunTask], arms: Mapping[str, Arm]) -> Iterator[tuple[RunTask, Outcome]]: ...


class SerialExecutor:
    """In this process, one run after the other (debugging, profiling, tiny sweeps)."""

    def map(self, tasks: Sequence[RunTask], arms: Mapping[str, Arm]) -> Iterator[tuple[RunTask, Outcome]]:
        for task in tasks:
            try:
                outcome: Outcome = execute_run(task, arms[task.arm_key])
            except Exception as error:  # noqa: BLE001 - a failed run is a result of the sweep
                outcome = error
            yield task, outcome


@dataclass
class LocalExecutor:
    """``workers`` processes of this machine (``concurrent.futures``, spawn context)."""

    workers: int = 2

    def map(self, tasks: Sequence[RunTask], arms: Mapping[str, Arm]) -> Iterator[tuple[RunTask, Outcome]]:
        if not tasks:
            return
        context = multiprocessing.get_context("spawn")
        used = {task.arm_key: arms[task.arm_key] for task in tasks}
        pool = ProcessPoolExecutor(
            max_workers=max(1, min(self.workers, len(tasks))), mp_context=context,
            initializer=_init_worker, initargs=(used,),
        )  # fmt: skip
        futures = {pool.submit(execute_run, task): task for task in tasks}
        pending = set(futures)
        try:
            while pending:
                done, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
                for future in done:
                    try:
                        outcome: Outcome = future.result()
                    except Exception as error:  # noqa: BLE001 - incl. a worker that died
                        outcome = error
                    yield futures[future], outcome
        finally:
            pool.shutdown(wait=not pending, cancel_futures=True)


@dataclass
class RayExecutor:
    """Ray tasks (``ray.remote`` + ``ray.wait``) on a cluster.

    ``address``: ``None`` or ``"local"`` starts a local Ray instance with
    ``num_cpus`` CPUs; anything else is passed to ``ray.init(address=...)``
    (``"auto"``, ``"ray://head:10001"``, ``"10.0.0.5:6379"``). If Ray is already
    initialised in this process it is used as it is. A Ray instance started here
    is shut down at the end. Every node needs hydroarm installed (same versions).
    """

    address: str | None = None
    num_cpus: int = 2

    def map(self, tasks: Sequence[RunTask], arms: Mapping[str, Arm]) -> Iterator[tuple[RunTask, Outcome]]:
        if not tasks:
            return
        ray = import_ray()
        started = False
        if not ray.is_initialized():
            os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
            if self.address in (None, "local"):
                ray.init(address="local", num_cpus=self.num_cpus, include_dashboard=False, log_to_driver=False)
            else:
                ray.init(address=self.address, log_to_driver=False)
            started = True
        pending: dict = {}
        try:
            remote = ray.remote(num_cpus=1, max_retries=0)(execute_run)
            refs = {key: ray.put(arms[key]) for key in {task.arm_key for task in tasks}}
            pending = {remote.remote(task, refs[task.arm_key]): task for task in tasks}
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                for ref in ready:
                    task = pending.pop(ref)
                    try:
                        outcome: Outcome = ray.get(ref)
                    except Exception as error:  # noqa: BLE001 - RayTaskError wraps the run's error
                        outcome = error
                    yield task, outcome
        finally:
            for ref in pending:
                ray.cancel(ref, force=True)
            if started:
                ray.shutdown()


def import_ray():
    """``import ray`` or a ConfigError saying how to install it."""
    try:
        import ray
    except ImportError:
        raise ConfigError("--ray needs Ray: pip install 'hydroarm[ray]'") from None
    return ray


def make_executor(workers: int = 2, ray_address: str | None = None) -> Executor:
    """``ray_address`` None: local processes (``workers`` of them; 0 = in this process);
    ``"local"``: a new local Ray instance with ``workers`` CPUs; else a Ray cluster's address."""
    if ray_address is not None:
        import_ray()
        return RayExecutor(address=ray_address, num_cpus=max(1, workers))
    if workers <= 0:
        return SerialExecutor()
    return LocalExecutor(workers=workers)


# --- files ---------------------------------------------------------------------------------


def _atomic_write(path: Path, data: str | bytes) -> None:
    """Write to a temporary file beside ``path``, then rename it over ``path``."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    if isinstance(data, bytes):
        tmp.write_bytes(data)
    else:
        tmp.write_text(data)
    os.replace(tmp, path)


def read_run(path: Path, identifier: str) -> dict | None:
    """A finished run file of this id and format, or None (missing, unreadable, stale)."""
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict) or record.get("id") != identifier or record.get("format") != FORMAT:
        return None
    if not isinstance(record.get("summary"), dict) or not isinstance(record.get("metrics"), dict):
        return None
    return record


def _flat(data: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, Mapping):
            out.update(_flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


SUMMARY_COLUMNS = (
    "Ep_mean", "Ep_steady_mean", "rms_mean", "max_error", "torque_rms_mean", "time_to_band_max",
    "diverged", "diverged_at_s", "stopped", "faults_total", "step_ms_median",
)  # fmt: skip

BOUND_COLUMNS = ("steady_max_error", "within_bound")
"""The run against the sweep's tracking bound (:func:`assess`): recomputed from the run
file whenever the table is written, so a changed ``[robustness]`` recomputes no run."""


PER_JOINT = ("Ep", "Ep_steady", "rms", "max", "torque_rms", "time_to_band")
"""The per-joint metrics of :func:`hydroarm.studies.runner.tracking_metrics`: columns ``Ep_1``, ``Ep_2``, ..."""


def _cell(value: Any) -> Any:
    if value is None:
        return ""
    if isinstance(value, (list, dict)):
        return json.dumps(value)
    return value


def table_columns(
    plan_keys: list[str], settings_keys: list[str], joints: int, fault_keys: Sequence[str] = ()
) -> list[str]:
    """``id, controller, seed, point, <swept keys>, <metrics>, <bound>, wall_s, faults.<key>..,
    Ep_1.., <every other setting>``."""
    per_joint = [f"{name}_{j + 1}" for name in PER_JOINT for j in range(joints)]
    rest = [k for k in settings_keys if k not in plan_keys]
    faults = [f"{FAULT_PREFIX}{key}" for key in fault_keys]
    return [
        "id", "controller", "seed", "point", *plan_keys, *SUMMARY_COLUMNS, *BOUND_COLUMNS, "wall_s",
        *faults, *per_joint, *rest,
    ]  # fmt: skip


def table_row(
    row: PlanRow, record: Mapping[str, Any], settings: Mapping[str, Any], robustness: Robustness = Robustness()
) -> dict[str, Any]:
    """One CSV row: the row's settings (as written in the sweep), the run's metrics, the run
    against the tracking bound and its fault counts (``faults.<key>``)."""
    out: dict[str, Any] = {"id": row.id, "controller": row.controller, "seed": row.seed, "point": row.point}
    out.update(settings)
    out.update({key: _cell(value) for key, value in row.params.items()})
    summary = record["summary"]
    out.update({key: _cell(summary.get(key)) for key in SUMMARY_COLUMNS})
    verdict = assess(record, robustness)
    out.update({key: _cell(_finite(verdict[key])) for key in BOUND_COLUMNS})
    out["wall_s"] = record.get("wall_s", "")
    out.update({f"{FAULT_PREFIX}{key}": value for key, value in (record.get("faults") or {}).items()})
    for key in PER_JOINT:
        for j, value in enumerate(record["metrics"].get(key, [])):
            out[f"{key}_{j + 1}"] = _cell(value)
    return out


def _row_settings(row: PlanRow) -> dict[str, Any]:
    settings = _flat(row.config.model_dump(mode="json"))
    settings.update({f"{MISMATCH_PREFIX}{k}": v for k, v in row.mismatch.model_dump().items()})
    return {key: _cell(value) for key, value in settings.items()}


class ResultsTable:
    """results.csv: one row per finished plan row, rewritten atomically on demand."""

    def __init__(self, plan: Plan, path: Path):
        self.plan, self.path = plan, path
        self.joints = max(arm.n_joints for arm in plan.arms.values())
        self.settings_keys = list(_row_settings(plan.rows[0])) if plan.rows else []
        self.rows: dict[int, dict] = {}
        self.fault_keys: set[str] = set()  # a column per fault that occurred (count > 0) in a finished run
        self.by_id: dict[str, list[PlanRow]] = {}
        for row in plan.rows:
            self.by_id.setdefault(row.id, []).append(row)

    def add(self, record: Mapping[str, Any]) -> None:
        for row in self.by_id.get(record["id"], []):
            self.rows[row.index] = table_row(row, record, _row_settings(row), self.plan.config.robustness)
            self.fault_keys.update(key for key, count in (record.get("faults") or {}).items() if count > 0)

    @property
    def columns(self) -> list[str]:
        return table_columns(self.plan.keys, self.settings_keys, self.joints, sorted(self.fault_keys))

    def write(self) -> None:
        zeros = {f"{FAULT_PREFIX}{key}": 0 for key in self.fault_keys}
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=self.columns, extrasaction="ignore", lineterminator="\n")
        writer.writeheader()
        for index in sorted(self.rows):
            writer.writerow({**zeros, **self.rows[index]})
        _atomic_write(self.path, buffer.getvalue())


def _plan_json(plan: Plan, source: str) -> dict:
    return {
        "format": FORMAT,
        "source": source,
        "sweep": plan.config.model_dump(mode="json"),
        "parameters": plan.keys,
        "rows": [
            {"id": r.id, "point": r.point, "controller": r.controller, "seed": r.seed, "params": r.params}
            for r in plan.rows
        ],
    }


# --- running ---------------------------------------------------------------------------------

ProgressHook = Callable[[int, int, str], None]
"""``on_progress(done, total, label)``: runs finished (incl. reused) of the sweep's distinct runs."""


def _task_label(task: RunTask, rows: list[PlanRow]) -> str:
    params = rows[0].params if rows else {}
    shown = ", ".join(f"{k}={_label(v)}" for k, v in params.items())
    return f"{task.controller} seed {task.seed}" + (f" {shown}" if shown else "")


def run_sweep(
    sweep: str | Path | SweepConfig,
    out_dir: str | Path,
    workers: int = 2,
    ray_address: str | None = None,
    on_progress: ProgressHook | None = None,
    executor: Executor | None = None,
    save_trajectories: bool | None = None,
) -> dict:
    """Run a sweep into ``out_dir`` (see the module docstring); return :func:`summarise`'s dict
    plus ``ran``, ``reused``, ``failed`` and ``wall_s``.

    ``sweep``: a sweep file or a :class:`SweepConfig` (relative arm paths then
    relative to the cwd). ``workers``: local processes (0 = this process), or
    the CPUs of a local Ray instance. ``ray_address``: ``None`` local processes;
    ``"local"`` a new local Ray instance; else a Ray address (``"auto"``,
    ``"ray://head:10001"``). ``executor``: any :class:`Executor` (overrides both).
    Every setting is validated and every arm loaded before the first run
    (:class:`~hydroarm.config.ConfigError` otherwise). A run that raises is
    listed in ``failed`` (and ``failed.json``) and retried by the next call;
    the others go on. KeyboardInterrupt stops the sweep; finished runs are kept.
    """
    start = time.perf_counter()
    if isinstance(sweep, SweepConfig):
        config, folder, source = sweep, None, "sweep"
    else:
        config, folder, source = load_sweep(sweep), Path(sweep).parent, str(sweep)
    if save_trajectories is not None:
        config = config.model_copy(update={"save_trajectories": save_trajectories})
    plan = plan_sweep(config, folder, source)
    out = Path(out_dir)
    run_dir = out / "runs"
    run_dir.mkdir(parents=True, exist_ok=True)
    _atomic_write(out / "sweep.json", json.dumps(_plan_json(plan, source), indent=1))
    table = ResultsTable(plan, out / "results.csv")
    todo: list[RunTask] = []
    for identifier, task in plan.tasks.items():
        record = read_run(run_dir / f"{identifier}.json", identifier)
        if record is None or (task.save_trajectory and not (run_dir / f"{identifier}.npz").is_file()):
            todo.append(task)
        else:
            table.add(record)
    total, reused = len(plan.tasks), len(plan.tasks) - len(todo)
    table.write()
    if on_progress:
        on_progress(reused, total, "reused finished runs" if reused else "starting")
    runner = executor if executor is not None else make_executor(workers, ray_address)
    failed: list[dict] = []
    done = reused
    last_write = time.perf_counter()
    many = len(plan.rows) > 2000
    outcomes = runner.map(todo, plan.arms)
    try:
        for task, outcome in outcomes:
            done += 1
            if isinstance(outcome, BaseException):
                error = f"{type(outcome).__name__}: {outcome}"
                failed.append({"id": task.id, "controller": task.controller, "seed": task.seed, "error": error[:2000]})
            else:
                if outcome.get("trajectory") is not None:
                    _atomic_write(run_dir / f"{task.id}.npz", outcome["trajectory"])
                record = outcome["record"]
                _atomic_write(run_dir / f"{task.id}.json", json.dumps(record, indent=1, allow_nan=False))
                table.add(record)
                if not many or time.perf_counter() - last_write > 2.0:
                    table.write()
                    last_write = time.perf_counter()
            if on_progress:
                on_progress(done, total, _task_label(task, table.by_id.get(task.id, [])))
    finally:
        close = getattr(outcomes, "close", None)
        if close is not None:
            close()  # stops the executor's workers now, not at garbage collection
        table.write()
        failed_path = out / "failed.json"
        if failed:
            _atomic_write(failed_path, json.dumps(failed, indent=1))
        elif failed_path.exists():
            failed_path.unlink()
    summary = summarise(out)
    summary.update(ran=len(todo) - len(failed), reused=reused, failed=failed, wall_s=time.perf_counter() - start)
    return summary


# --- summary and plots --------------------------------------------------------------------


def _stats(values: list[float]) -> dict:
    finite = np.array([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if finite.size == 0:
        return {"mean": None, "median": None, "p90": None, "min": None, "max": None}
    return {
        "mean": float(finite.mean()),
        "median": float(np.median(finite)),
        "p90": float(np.percentile(finite, 90)),
        "min": float(finite.min()),
        "max": float(finite.max()),
    }


MAX_GROUPS = 12
"""A parameter with more distinct values than this (or drawn from a range in random mode)
is plotted as a scatter, not boxes."""


def _load_rows(out: Path) -> tuple[dict, list[dict]]:
    """sweep.json and its rows joined with their run files (``record`` None if not finished)."""
    path = out / "sweep.json"
    if not path.is_file():
        raise ConfigError(f"{out}: no sweep.json (not a sweep folder)")
    plan = json.loads(path.read_text())
    records: dict[str, dict | None] = {}
    rows = []
    for row in plan["rows"]:
        identifier = row["id"]
        if identifier not in records:
            records[identifier] = read_run(out / "runs" / f"{identifier}.json", identifier)
        rows.append({**row, "record": records[identifier]})
    return plan, rows


METRICS = {
    "Ep_mean": ("mean E_p over joints", "rad$^2$"),
    "Ep_steady_mean": ("mean E_p over joints after 2 s", "rad$^2$"),
    "rms_mean": ("mean RMS error over joints", "rad"),
    "max_error": ("largest |error|", "rad"),
    "torque_rms_mean": ("mean RMS torque over joints", "N m"),
    "time_to_band_max": ("time to stay within 0.05 rad, slowest joint", "s"),
    "step_ms_median": ("median controller step", "ms"),
}
"""The columns a summary can compare (``metric`` in the sweep file): label, unit."""


def robustness_table(rows: list[dict], controllers: list[str], robustness: Robustness) -> dict:
    """Per controller, the runs against the tracking bound (:class:`Robustness`) and the faults.

    ``rows``: plan rows with their run file (``record``, None if not finished).
    Per controller: ``rows`` = ``within`` + ``outside`` (ran to the end, error
    not within the bound) + ``stopped`` (ended early; ``stopped_by`` counts the
    reasons: diverged, controller_error, ...) + ``unfinished`` (failed or not
    run yet); ``short``: runs (among ``outside``) that ended before ``after``;
    ``steady_max_error`` (rad, the largest |q_r - q| from ``after`` on) and
    ``Ep_steady`` (rad^2, mean over joints of E_p after 2 s): mean, median, p90,
    min, max over the runs that ran to the end; ``runs_with_faults`` and
    ``faults``: key -> {"runs": runs with that fault, "events": total count}.
    """
    table: dict[str, dict] = {}
    for name in controllers:
        mine = [r for r in rows if r["controller"] == name]
        done = [r["record"] for r in mine if r["record"] is not None]
        verdicts = [assess(record, robustness) for record in done]
        ran = [(record, v) for record, v in zip(done, verdicts) if v["stopped"] is None]
        within = sum(v["within_bound"] for v in verdicts)
        stopped_by: dict[str, int] = {}
        for v in verdicts:
            if v["stopped"] is not None:
                stopped_by[v["stopped"]] = stopped_by.get(v["stopped"], 0) + 1
        faults: dict[str, dict[str, int]] = {}
        for record in done:
            for key, count in (record.get("faults") or {}).items():
                if count > 0:
                    entry = faults.setdefault(key, {"runs": 0, "events": 0})
                    entry["runs"] += 1
                    entry["events"] += int(count)
        table[name] = {
            "rows": len(mine),
            "finished": len(done),
            "within": within,
            "outside": len(ran) - within,
            "stopped": sum(stopped_by.values()),
            "stopped_by": dict(sorted(stopped_by.items())),
            "unfinished": len(mine) - len(done),
            "short": sum(math.isnan(v["steady_max_error"]) for _, v in ran),
            "steady_max_error": _stats([v["steady_max_error"] for _, v in ran]),
            "Ep_steady": _stats([record["summary"].get("Ep_steady_mean") for record, _ in ran]),
            "runs_with_faults": sum(bool(any(c > 0 for c in (r.get("faults") or {}).values())) for r in done),
            "faults": dict(sorted(faults.items())),
        }
    return {"bound": robustness.model_dump(), "controllers": table}


def summarise(out_dir: str | Path, metric: str | None = None) -> dict:
    """Write ``summary.md``, ``summary.json`` and the plots of a sweep folder; return the summary.

    ``metric``: a key of :data:`METRICS` (default: the sweep file's ``metric``,
    the mean E_p over joints). Per controller: rows, finished, diverged runs and
    mean/median/p90/min/max of the metric; per swept parameter with at most
    ``MAX_GROUPS`` values that are not drawn from a range: the same per value
    and controller (the others are plotted as a scatter); ``robustness``: the
    runs against the sweep's tracking bound and the fault counts per controller
    (:func:`robustness_table`).
    """
    out = Path(out_dir)
    plan, rows = _load_rows(out)
    metric = metric or plan["sweep"].get("metric", "Ep_mean")
    if metric not in METRICS:
        raise ConfigError(f"metric '{metric}': must be one of {', '.join(METRICS)}")
    controllers = plan["sweep"]["controllers"]
    robustness = validate(Robustness, plan["sweep"].get("robustness", {}), f"{out}/sweep.json: robustness")
    finished = [r for r in rows if r["record"] is not None]

    def group(selected: list[dict]) -> dict:
        return {
            "finished": len(selected),
            "diverged": sum(bool(r["record"]["summary"]["diverged"]) for r in selected),
            **_stats([r["record"]["summary"].get(metric) for r in selected]),
        }

    per_controller = {}
    for name in controllers:
        mine = [r for r in rows if r["controller"] == name]
        per_controller[name] = {"rows": len(mine), **group([r for r in mine if r["record"] is not None])}
    by_parameter: dict[str, dict] = {}
    varying = []
    continuous = _continuous(plan, rows)
    for key in plan["parameters"]:
        labels = _unique([_label(r["params"][key]) for r in rows])
        if len(labels) < 2:
            continue
        varying.append(key)
        if key in continuous:
            by_parameter[key] = {"values": len(labels), "grouped": False}
            continue
        groups = {
            label: {
                name: group([r for r in finished if r["controller"] == name and _label(r["params"][key]) == label])
                for name in controllers
            }
            for label in labels
        }
        by_parameter[key] = {"values": len(labels), "grouped": True, "groups": groups}
    summary = {
        "name": plan["sweep"]["name"],
        "out": str(out),
        "metric": metric,
        "metric_label": f"{METRICS[metric][0]} ({METRICS[metric][1].replace('$^2$', '^2')})",
        "rows": len(rows),
        "runs": len({r["id"] for r in rows}),
        "finished_rows": len(finished),
        "controllers": per_controller,
        "parameters": plan["parameters"],
        "varying": varying,
        "by_parameter": by_parameter,
        "robustness": robustness_table(rows, controllers, robustness),
    }
    failed_path = out / "failed.json"
    summary["failed_runs"] = json.loads(failed_path.read_text()) if failed_path.is_file() else []
    summary["plots"] = _plots(out, controllers, finished, varying, continuous, metric)
    plot = _robustness_plot(out, controllers, finished, robustness)
    if plot:
        summary["plots"]["robustness"] = plot
    plot = _robustness_by_parameter_plot(out, controllers, finished, varying, robustness)
    if plot:
        summary["plots"]["robustness_by_parameter"] = plot
    _atomic_write(out / "summary.json", json.dumps(_finite(summary), indent=1))
    _atomic_write(out / "summary.md", _markdown(summary, plan))
    return summary


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.4g}"


def _markdown(summary: dict, plan: dict) -> str:
    sweep = plan["sweep"]
    seeds = sweep["seeds"] if isinstance(sweep["seeds"], list) else list(range(sweep["seeds"]))
    label = summary["metric_label"]
    lines = [f"# Sweep `{summary['name']}`", ""]
    if sweep.get("description"):
        lines += [sweep["description"], ""]
    lines += [
        f"{summary['finished_rows']} of {summary['rows']} rows finished ({summary['runs']} distinct runs: rows that "
        "differ only in another controller's settings share one run). Mode "
        f"`{sweep['mode']}`; controllers {', '.join(sweep['controllers'])}; seeds {seeds}; arm `{sweep['base']['arm']}` "
        f"unless swept; {sweep['base']['duration']:g} s per run. Every setting and metric of every run: "
        "`results.csv`; one file per run: `runs/<id>.json`.",
        "",
        f"## {label[0].upper() + label[1:]}, per controller",
        "",
        "| controller | rows | finished | mean | median | p90 | min | max | diverged |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, s in summary["controllers"].items():
        lines.append(
            f"| {name} | {s['rows']} | {s['finished']} | {_fmt(s['mean'])} | {_fmt(s['median'])} | "
            f"{_fmt(s['p90'])} | {_fmt(s['min'])} | {_fmt(s['max'])} | {s['diverged']} |"
        )
    lines += ["", "A diverged run's metrics are over the steps before it stopped.", ""]
    for name in ("ep_boxplot", "ep_distribution"):
        if name in summary["plots"]:
            lines += [f"![{name}]({summary['plots'][name]})", ""]
    lines += _robustness_markdown(
        summary["robustness"], summary["plots"].get("robustness"), summary["plots"].get("robustness_by_parameter")
    )
    for key, entry in summary["by_parameter"].items():
        lines += [f"## By `{key}`", ""]
        if not entry["grouped"]:
            lines += [f"{entry['values']} distinct values: see the scatter plot.", ""]
        else:
            names = list(summary["controllers"])
            lines += ["| " + key + " | " + " | ".join(f"{n}: median (runs)" for n in names) + " |",
                      "|---" * (len(names) + 1) + "|"]  # fmt: skip
            for value, group in entry["groups"].items():
                cells = [f"{_fmt(group[n]['median'])} ({group[n]['finished']})" for n in names]
                lines.append(f"| {value} | " + " | ".join(cells) + " |")
            lines.append("")
        plot = summary["plots"].get(f"ep_by_{_safe(key)}")
        if plot:
            lines += [f"![{label} by {key}]({plot})", ""]
    if summary["failed_runs"]:
        lines += ["## Failed runs (retried by the next call)", ""]
        lines += [f"- `{f['id']}` {f['controller']} seed {f['seed']}: {f['error']}" for f in summary["failed_runs"]]
        lines.append("")
    return "\n".join(lines)


def _robustness_markdown(robustness: dict, plot: str | None, by_parameter: str | None = None) -> list[str]:
    """The robustness section of summary.md: runs within the bound, faults, the plot."""
    bound, table = robustness["bound"], robustness["controllers"]
    after, limit = bound["after"], bound["max_error"]
    lines = [
        "## Robustness: runs within the tracking bound",
        "",
        f"Within the bound: the run ran to the end (not diverged, not stopped) and from t = {after:g} s on "
        f"|q_r - q| < {limit:g} rad on every joint at every control step (true q). rows = within + outside + "
        "stopped + not finished. The error columns are over the runs that ran to the end: the largest "
        f"|q_r - q| from {after:g} s on (rad) and the mean over joints of E_p after 2 s (rad^2).",
        "",
        "| controller | rows | within bound | outside | stopped | not finished | max error: median | p90 "
        "| E_p after 2 s: median | p90 | runs with faults |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, s in table.items():
        why = ", ".join(f"{k} {v}" for k, v in s["stopped_by"].items())
        stopped = f"{s['stopped']} ({why})" if why else "0"
        lines.append(
            f"| {name} | {s['rows']} | {s['within']} | {s['outside']} | {stopped} | {s['unfinished']} | "
            f"{_fmt(s['steady_max_error']['median'])} | {_fmt(s['steady_max_error']['p90'])} | "
            f"{_fmt(s['Ep_steady']['median'])} | {_fmt(s['Ep_steady']['p90'])} | {s['runs_with_faults']} |"
        )
    lines.append("")
    short = sum(s["short"] for s in table.values())
    if short:
        lines += [f"{short} runs ended before {after:g} s: they cannot be within the bound (`[robustness] after`).", ""]
    keys = sorted({key for s in table.values() for key in s["faults"]})
    if keys:
        lines += [
            "Faults the runner counted (runs with the fault / events over those runs):",
            "",
            "| fault | " + " | ".join(table) + " |",
            "|---" * (len(table) + 1) + "|",
        ]
        for key in keys:
            cells = [
                f"{s['faults'][key]['runs']} / {s['faults'][key]['events']}" if key in s["faults"] else "0"
                for s in table.values()
            ]
            lines.append(f"| {key} | " + " | ".join(cells) + " |")
        lines.append("")
    else:
        lines += ["No fault was counted in any finished run.", ""]
    if plot:
        lines += [f"![fraction of runs within a bound]({plot})", ""]
    if by_parameter:
        lines += [f"![the largest error after {after:g} s by parameter]({by_parameter})", ""]
    return lines


def _safe(key: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in key)


COLOURS = {"SMC": "tab:green", "MPC": "tab:blue", "GP-MPC": "tab:red"}


def _plots(
    out: Path, controllers: list[str], finished: list[dict], varying: list[str], continuous: set[str], metric: str
) -> dict[str, str]:
    """ep_boxplot.png, ep_distribution.png and ep_by_<key>.png; returns name -> file."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    label = f"{METRICS[metric][0]} ({METRICS[metric][1]})"

    def values(rows: list[dict]) -> list[float]:
        got = (r["record"]["summary"].get(metric) for r in rows)
        return [v for v in got if v is not None and math.isfinite(v)]

    def wide(data: list[float]) -> bool:
        return bool(data) and min(data) > 0.0 and max(data) / min(data) > 20.0

    def scale(ax, data: list[float]) -> None:
        if wide(data):
            ax.set_yscale("log")

    plots: dict[str, str] = {}
    per = {name: values([r for r in finished if r["controller"] == name]) for name in controllers}
    everything = [v for vs in per.values() for v in vs]
    if not everything:
        return plots
    names = [n for n in controllers if per[n]]
    single = varying[0] if len(varying) == 1 and varying[0] not in continuous else None
    fig, axes = plt.subplots(1, 2 if single else 1, figsize=(11 if single else 6, 4.2), squeeze=False)
    ax = axes[0, 0]
    box = ax.boxplot([per[n] for n in names], tick_labels=names, patch_artist=True, medianprops={"color": "black"})
    for patch, name in zip(box["boxes"], names):
        patch.set_facecolor(COLOURS.get(name, "lightgrey"))
        patch.set_alpha(0.5)
    scale(ax, everything)
    ax.set_ylabel(label)
    ax.set_title("per controller")
    ax.grid(True, axis="y", alpha=0.3)
    if single:
        _grouped_boxes(axes[0, 1], single, controllers, finished, values, label)
        scale(axes[0, 1], everything)
    fig.tight_layout()
    fig.savefig(out / "ep_boxplot.png", dpi=110)
    plt.close(fig)
    plots["ep_boxplot"] = "ep_boxplot.png"

    fig, ax = plt.subplots(figsize=(6, 4.2))
    for name in names:
        data = np.sort(per[name])
        fraction = np.arange(0, data.size + 1) / data.size
        ax.step(np.r_[data[0], data], fraction, where="post", label=name, color=COLOURS.get(name))
    if wide(everything):
        ax.set_xscale("log")
    ax.set_xlabel(label)
    ax.set_ylabel("fraction of runs <= x")
    ax.set_title("distribution per controller")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "ep_distribution.png", dpi=110)
    plt.close(fig)
    plots["ep_distribution"] = "ep_distribution.png"

    for key in varying:
        fig, ax = plt.subplots(figsize=(8, 4.2))
        if key in continuous:
            for name in names:
                mine = [r for r in finished if r["controller"] == name]
                xs = [r["params"][key] for r in mine]
                ys = [r["record"]["summary"].get(metric) for r in mine]
                ys = [math.nan if y is None else y for y in ys]
                ax.scatter(xs, ys, s=14, alpha=0.7, label=name, color=COLOURS.get(name))
            numeric = [r["params"][key] for r in finished if isinstance(r["params"][key], (int, float))]
            if numeric and min(numeric) > 0 and max(numeric) / min(numeric) > 50:
                ax.set_xscale("log")
            ax.set_xlabel(key)
            ax.set_ylabel(label)
            ax.legend()
            ax.grid(True, alpha=0.3)
        else:
            _grouped_boxes(ax, key, controllers, finished, values, label)
        scale(ax, everything)
        ax.set_title(f"by {key}")
        fig.tight_layout()
        name = f"ep_by_{_safe(key)}"
        fig.savefig(out / f"{name}.png", dpi=110)
        plt.close(fig)
        plots[name] = f"{name}.png"
    return plots


def _robustness_plot(out: Path, controllers: list[str], finished: list[dict], robustness: Robustness) -> str | None:
    """robustness.png: per controller, the fraction of finished runs that ran to the end with
    the largest |q_r - q| from ``after`` on below x (a run that stopped never counts), and the
    sweep's bound; returns the file name (None if no run finished)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curves = {}
    for name in controllers:
        verdicts = [assess(r["record"], robustness) for r in finished if r["controller"] == name]
        errors = [v["steady_max_error"] for v in verdicts if v["stopped"] is None]
        curves[name] = (np.sort([e for e in errors if math.isfinite(e)]), len(verdicts))
    values = np.concatenate([c[0] for c in curves.values()]) if curves else np.zeros(0)
    if values.size == 0:
        return None
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    low, high = min(values.min(), robustness.max_error), max(values.max(), robustness.max_error)
    for name, (errors, count) in curves.items():
        if count == 0:
            continue
        xs = np.r_[low, errors, high]
        fraction = np.r_[0.0, np.arange(1, errors.size + 1), errors.size] / count
        ax.step(xs, fraction, where="post", label=f"{name} ({count} runs)", color=COLOURS.get(name))
    bound = f"bound {robustness.max_error:g} rad"
    ax.axvline(robustness.max_error, color="black", linestyle="--", linewidth=1, label=bound)
    if low > 0.0 and high / low > 20.0:
        ax.set_xscale("log")
    ax.set_ylim(0.0, 1.02)
    ax.set_xlabel(f"largest |q_r - q| over joints from t = {robustness.after:g} s on (rad)")
    ax.set_ylabel("fraction of runs within x")
    ax.set_title("runs within a tracking bound (stopped runs never are)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "robustness.png", dpi=110)
    plt.close(fig)
    return "robustness.png"


def _robustness_by_parameter_plot(
    out: Path, controllers: list[str], finished: list[dict], varying: list[str], robustness: Robustness
) -> str | None:
    """robustness_by_parameter.png: one panel per swept parameter, the largest |q_r - q| from
    ``after`` on of every finished run against the parameter's value (runs that stopped as
    crosses above the rest), and the bound; returns the file name (None if nothing to plot)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not varying or not finished:
        return None
    points = [(row, assess(row["record"], robustness)) for row in finished]
    errors = [v["steady_max_error"] for _, v in points if v["stopped"] is None and math.isfinite(v["steady_max_error"])]
    top = max([*errors, robustness.max_error]) * 1.25  # where runs that stopped are drawn
    columns = min(3, len(varying))
    rows_count = math.ceil(len(varying) / columns)
    fig, axes = plt.subplots(rows_count, columns, figsize=(4.2 * columns, 3.3 * rows_count), squeeze=False)
    for ax, key in zip(axes.ravel(), varying):
        values = [row["params"][key] for row, _ in points]
        numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
        labels = [] if numeric else _unique([_label(v) for v in values])
        for c, name in enumerate(controllers):
            mine = [(row, v) for row, v in points if row["controller"] == name]
            xs = [row["params"][key] if numeric else labels.index(_label(row["params"][key])) for row, _ in mine]
            ran = [(x, v["steady_max_error"]) for x, (_, v) in zip(xs, mine) if v["stopped"] is None]
            stopped = [x for x, (_, v) in zip(xs, mine) if v["stopped"] is not None]
            colour = COLOURS.get(name)
            ax.scatter([x for x, _ in ran], [y for _, y in ran], s=10, alpha=0.6, color=colour, label=name)
            if stopped:
                ax.scatter(stopped, [top * (1.0 + 0.04 * c)] * len(stopped), s=18, marker="x", color=colour)
        if not numeric:
            ax.set_xticks(range(len(labels)), [_short(label) for label in labels], rotation=20)
        ax.axhline(robustness.max_error, color="black", linestyle="--", linewidth=1)
        ax.set_xlabel(key)
        ax.set_ylabel(f"max |q_r - q| after {robustness.after:g} s (rad)", fontsize=8)
        ax.grid(True, alpha=0.3)
    for ax in axes.ravel()[len(varying) :]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(
        f"largest error after {robustness.after:g} s per run; dashed: bound {robustness.max_error:g} rad; "
        "crosses at the top: runs that stopped (one row per controller)",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(out / "robustness_by_parameter.png", dpi=110)
    plt.close(fig)
    return "robustness_by_parameter.png"


def _continuous(plan: dict, rows: list[dict]) -> set[str]:
    """Parameters shown as a scatter, not boxes: drawn from a range, or more than
    ``MAX_GROUPS`` distinct values."""
    sweep = plan["sweep"]
    out = set()
    for key in plan["parameters"]:
        drawn = sweep["mode"] == "random" and isinstance(sweep["parameters"].get(key), dict)
        if drawn or len(_unique([_label(r["params"][key]) for r in rows])) > MAX_GROUPS:
            out.add(key)
    return out


def _grouped_boxes(ax, key: str, controllers: list[str], finished: list[dict], values, label: str) -> None:
    """Boxes of the metric per value of ``key``, one colour per controller."""
    labels = _unique([_label(r["params"][key]) for r in finished])
    width = 0.8 / max(1, len(controllers))
    for c, name in enumerate(controllers):
        data, positions = [], []
        for g, value in enumerate(labels):
            group = values([r for r in finished if r["controller"] == name and _label(r["params"][key]) == value])
            if group:
                data.append(group)
                positions.append(g + (c - (len(controllers) - 1) / 2) * width)
        if not data:
            continue
        box = ax.boxplot(
            data,
            positions=positions,
            widths=width * 0.9,
            patch_artist=True,
            medianprops={"color": "black"},
            manage_ticks=False,
        )
        for patch in box["boxes"]:
            patch.set_facecolor(COLOURS.get(name, "lightgrey"))
            patch.set_alpha(0.5)
        ax.plot([], [], color=COLOURS.get(name, "grey"), linewidth=8, alpha=0.5, label=name)
    ax.set_xticks(range(len(labels)), [_short(value) for value in labels], rotation=20 if len(labels) > 4 else 0)
    ax.set_xlabel(key)
    ax.set_ylabel(label)
    ax.set_title(f"by {key}")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=8)


def _short(label: str) -> str:
    """File arms by their file name; long labels cut."""
    if "/" in label or "\\" in label:
        label = Path(label).name
    return label if len(label) <= 24 else label[:21] + "..."
