"""The plan of a sweep: every run it asks for, and the id that names a run's result.

:func:`plan_sweep` expands a :class:`~hydroarm.studies.sweep.schema.SweepConfig` into rows
(parameter point x seed x controller), validates every row's settings and loads every arm
before any run starts. A row's run id (:func:`run_id`) is a hash of everything that
determines the run, so rows that differ only in settings their controller does not read
share one run, and a finished run is found again by the next call (the resume cache).
:func:`~hydroarm.sim.mismatch.perturbed_arm` (what the experiment builds its plant on) is the true
plant's arm under a :class:`Mismatch`.
"""

from __future__ import annotations

import hashlib
import itertools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hydroarm.config import ConfigError, dotted_keys, unknown_key_message
from hydroarm.control.registry import controller_sections, settings_read_by
from hydroarm.model.arm.description import Arm
from hydroarm.model.arm.loading import BUILTIN_ARMS, load_arm
from hydroarm.sim.experiment import ExperimentConfig, check_settings_for_arm, with_overrides
from hydroarm.studies.outputs import slug
from hydroarm.studies.sweep.schema import (
    MAX_RUNS,
    MISMATCH_PREFIX,
    Mismatch,
    Range,
    SweepConfig,
    check_sweep,
    resolve_path,
)

FORMAT = 2
"""Version of the run-file layout; a run file of another format is recomputed.
2: fault counts, ``stopped`` and the error envelope."""


@dataclass(frozen=True)
class RunTask:
    """One closed-loop run, as sent to a worker: everything is plain data except the arm,
    which the executor sends once per arm (``arm_key``); ``label``: what progress shows."""

    id: str
    controller: str
    seed: int
    settings: dict  # ExperimentConfig as JSON (arm: the path the driver loaded)
    mismatch: dict
    arm_key: str
    save_trajectory: bool = False
    label: str = ""


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
    source: str = "sweep"  # the sweep file (or "sweep"), as messages name it


def _resolve_arm(value: str, folder: Path | None) -> str:
    """A built-in name as is; a file relative to the sweep file's folder (else to the cwd)."""
    if value in BUILTIN_ARMS:
        return value
    return str(resolve_path(value, folder).resolve()) if resolve_path(value, folder).exists() else value


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
    if np.any(model.armature != 0.0):  # only then: digests of arms made before armature stay as they were
        content["armature"] = model.armature.tolist()
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()[:16]


def run_id(config: ExperimentConfig, controller: str, seed: int, mismatch: Mismatch, arm_key: str) -> str:
    """The run's id (its file name in ``runs/``): the controller and the seed, readable
    (:func:`~hydroarm.studies.outputs.slug`), then a hash of the arm's content, the settings
    ``controller`` reads, the mismatch, the controller and the seed:
    ``gp-mpc__seed0__3f2a9c0d1e4b5a67``."""
    settings = config.canonical()
    settings.pop("mismatch", None)  # hashed beside the settings, as before it joined them: the same ids
    settings["arm"] = arm_key
    read = settings_read_by(controller)
    for section in controller_sections():
        if section not in read:
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
    return f"{slug(controller)}__seed{seed}__{hashlib.sha256(text.encode()).hexdigest()[:16]}"


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


def value_label(value: Any) -> str:
    """A value as a table cell or a group's name: floats to 4 significant digits."""
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, str):
        return value
    return json.dumps(value)


def _task_label(controller: str, seed: int, point: dict[str, Any]) -> str:
    shown = ", ".join(f"{k}={value_label(v)}" for k, v in point.items())
    return f"{controller} seed {seed}" + (f" {shown}" if shown else "")


def plan_sweep(config: SweepConfig, folder: Path | None = None, source: str = "sweep") -> Plan:
    """Validate every run's settings and load every arm before any run starts: the settings'
    types, then what only the arm can tell (:func:`~hydroarm.sim.experiment.check_settings_for_arm`
    for each point, arm and controller). Raises :class:`ConfigError` naming ``source``."""
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
        experiment, mismatch = _point_settings(config, point, source)
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
                        identifier, controller, seed, settings, mismatch.model_dump(), key, config.save_trajectories,
                        _task_label(controller, seed, point),
                    )  # fmt: skip
    _check_for_arms(rows, tasks, arms, source)
    return Plan(config, rows, tasks, arms, keys, source)


def _point_settings(config: SweepConfig, point: dict[str, Any], source: str) -> tuple[ExperimentConfig, Mismatch]:
    """A parameter point's experiment settings (the base with the sweep's ``[mismatch]`` and the
    point's overrides, ``mismatch.*`` among them: the settings' ``mismatch`` section) and its plant
    mismatch; :class:`ConfigError` naming the key."""
    where = ", ".join(f"{k} = {value_label(v)}" for k, v in point.items()) or "base"
    try:
        base = _base_with_mismatch(config, source)
        experiment = with_overrides(base, dict(point)) if point else base
    except ConfigError as error:
        message = str(error).removeprefix("settings: ")
        if message.startswith("unknown setting"):
            bad = message.split("'")[1] if "'" in message else message
            mismatch_keys = [MISMATCH_PREFIX + f for f in Mismatch.model_fields]
            text = unknown_key_message(bad, dotted_keys(ExperimentConfig), None, moved=ExperimentConfig.moved_settings)
            raise ConfigError(
                f"{source}: parameters.{bad}: {text.replace('unknown key', 'unknown setting', 1)} "
                f"(a dotted key of the experiment settings, which `hydroarm settings` lists, "
                f"or {' / '.join(mismatch_keys)})"
            ) from None
        lines = [line.removeprefix("settings: ") for line in message.splitlines()]
        raise ConfigError("\n".join(f"{source}: parameters ({where}): {line}" for line in lines)) from None
    return experiment, experiment.mismatch


def _base_with_mismatch(config: SweepConfig, source: str) -> ExperimentConfig:
    """The sweep's base settings with its ``[mismatch]`` (the settings' ``mismatch`` section: the
    one home; a sweep gives it at the top level or in ``[base.mismatch]``, not both)."""
    if config.mismatch.is_identity:
        return config.base
    if not config.base.mismatch.is_identity:
        raise ConfigError(f"{source}: mismatch: given both as [mismatch] and [base.mismatch]: give it once")
    return with_overrides(config.base, {"mismatch": config.mismatch.model_dump()})


def _check_for_arms(rows: list[PlanRow], tasks: dict[str, RunTask], arms: dict[str, Arm], source: str) -> None:
    """What only the arm can tell (:func:`~hydroarm.sim.experiment.check_settings_for_arm`), once
    per distinct settings, arm and controller of the plan's rows."""
    checked: set[tuple[int, str, str]] = set()
    for row in rows:
        arm_key = tasks[row.id].arm_key
        if (id(row.config), arm_key, row.controller) in checked:
            continue
        checked.add((id(row.config), arm_key, row.controller))
        where = ", ".join(f"{key} = {value!r}" for key, value in row.params.items())
        what = f"{source}: the runs with {where}" if where else f"{source}: base"
        check_settings_for_arm(row.config, arms[arm_key], what, controllers=(row.controller,))
