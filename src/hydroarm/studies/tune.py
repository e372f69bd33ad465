"""Tuning a controller's gains on the dry arm: one procedure for every controller on every arm.

The paper's premise is that the controllers are "tuned once on land". For controller C on
arm A, every point of C's grid (:func:`tuning_grid`, the registry's) runs A's own task
(:func:`~hydroarm.model.task.references.task_for_arm`) on A without water (no drag, added mass,
buoyancy or current: the nominal model is then exact, as on land), once clean and once with
measurement noise of variance ``NOISE_VARIANCE`` (seed 0). A point's score is the mean of the
two runs' mean E_p over joints; a diverged or failed run scores infinity. The best point is
written as a settings file: a TOML file holding C's section with the tuned keys, which
``hydroarm run``, ``reproduce`` and ``sweep`` read with ``--config`` (the keys of other
controllers already in the file are kept). Every scored point goes to ``<file>.json``.

Runs go through :mod:`hydroarm.studies.executor`: finished runs are kept in
``<file>.runs/`` and a repeated call reuses them.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hydroarm.config import ConfigError
from hydroarm.control.registry import canonical_name, controller_spec
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, settings_from_record, with_overrides
from hydroarm.sim.files import atomic_write
from hydroarm.sim.runner import tracking_metrics
from hydroarm.sim.settings_schema import SCHEMA, migrate, schema_of
from hydroarm.studies.executor import RunCache, make_executor, run_tasks

NOISE_VARIANCE = 1e-3
"""Measurement-noise variance of the noisy tuning run (the paper's Table 2)."""

DRY = {"water.drag": False, "water.added_mass": False, "water.buoyancy": False, "water.current.model": "none"}
"""The overrides that take the water away ("on land")."""


NDOB_GAINS = [0.05, 0.1, 0.3, 1.0]
"""With ``observer.kind = "ndob"`` in the settings, the NDOB's gain L joins the grid of every
controller that runs over an observer (a TDE has no gain: the controller's grid alone; on the
dry arm's noisy run the observer's noise amplification is what the score sees)."""


def tuning_grid(base: ExperimentConfig, controller: str) -> dict[str, list[Any]]:
    """The grid ``controller`` (either spelling) is tuned over from the settings ``base``: its
    registry spec's ``tuning_grid`` (dotted keys of :class:`ExperimentConfig` -> values), plus the
    NDOB's gain (:data:`NDOB_GAINS`) when ``base`` runs it under an NDOB."""
    spec = controller_spec(controller)
    grid = {key: list(values) for key, values in spec.tuning_grid.items()}
    if spec.observer and base.observer.kind == "ndob":
        grid["observer.gain"] = list(NDOB_GAINS)
    return grid


@dataclass(frozen=True)
class TuneTask:
    """One run of the tuning: a grid ``point`` (dotted key -> value), clean or noisy."""

    id: str
    label: str
    controller: str
    point: tuple[tuple[str, Any], ...]
    noisy: bool
    settings: dict
    arm_key: str | None = None


def _task_id(controller: str, settings: dict) -> str:
    text = json.dumps({"controller": controller, "settings": settings}, sort_keys=True)
    return f"{controller}-{hashlib.sha256(text.encode()).hexdigest()[:16]}"


def plan_tuning(base: ExperimentConfig, controller: str, grid: Mapping[str, list[Any]] | None = None) -> list[TuneTask]:
    """The runs of tuning ``controller`` (any spelling) from the settings ``base`` (its arm,
    duration, control period): every grid point x {clean, noisy}, on the dry arm."""
    name = canonical_name(controller)
    grid = tuning_grid(base, name) if grid is None else grid
    keys = sorted(grid)
    tasks = []
    for values in itertools.product(*(grid[key] for key in keys)):
        point = tuple(zip(keys, values))
        for noisy in (False, True):
            overrides = {**DRY, **dict(point), "plant.noise_variance": NOISE_VARIANCE if noisy else 0.0}
            settings = with_overrides(base, overrides).canonical()
            label = f"{name} " + " ".join(f"{k}={v:g}" for k, v in point) + (" noisy" if noisy else " clean")
            tasks.append(TuneTask(_task_id(name, settings), label, name, point, noisy, settings))
    return tasks


def run_tuning_task(task: TuneTask, arm: Any, progress: Callable[[int, int], None] | None) -> dict:
    """One tuning run (an executor's run function): ``{"Ep_mean", "diverged"}``."""
    config = settings_from_record(task.settings, f"tuning run {task.id}", missing=SCHEMA)  # the compact form
    traj = build_experiment(config, task.controller).run(seed=0, progress=progress)
    ep = np.asarray(tracking_metrics(traj)["Ep"], dtype=float)
    mean = float(ep.mean())
    return {"Ep_mean": mean if math.isfinite(mean) else None, "diverged": bool(traj.diverged)}


class _TuneCache(RunCache):
    def read(self, task: TuneTask) -> dict | None:
        try:
            return json.loads(self.path(task).read_text())
        except (OSError, ValueError):
            return None

    def write(self, task: TuneTask, outcome: dict) -> dict:
        atomic_write(self.path(task), json.dumps(outcome))
        return outcome


@dataclass
class TuningResult:
    """The scored grid, best first (``rows``: point, clean, noisy, score), and ``best``:
    the best point's dotted keys and values."""

    controller: str
    rows: list[dict]
    best: dict[str, Any]


def tune(
    base: ExperimentConfig,
    controller: str,
    folder: Path,
    workers: int = 2,
    grid: Mapping[str, list[Any]] | None = None,
    on_progress=None,
) -> TuningResult:
    """Tune ``controller`` on the dry arm of ``base`` (module docstring); runs kept in ``folder``."""
    tasks = plan_tuning(base, controller, grid)
    cache = _TuneCache(folder)
    finished, todo = cache.lookup(tasks)
    report = run_tasks(todo, run_tuning_task, cache, make_executor(workers), reused=len(finished),
                       on_progress=on_progress)  # fmt: skip
    results = {**finished, **report.results}
    scores: dict[tuple, dict] = {}
    for task in tasks:
        row = scores.setdefault(task.point, {"point": dict(task.point)})
        outcome = results.get(task.id)
        value = None if outcome is None or outcome["diverged"] else outcome["Ep_mean"]
        row["noisy" if task.noisy else "clean"] = value
    rows = []
    for row in scores.values():
        parts = [row.get("clean"), row.get("noisy")]
        row["score"] = math.inf if any(p is None for p in parts) else 0.5 * (parts[0] + parts[1])
        rows.append(row)
    rows.sort(key=lambda r: r["score"])
    if not math.isfinite(rows[0]["score"]):
        raise ConfigError(f"tune {canonical_name(controller)}: every grid point diverged or failed on arm {base.arm!r}")
    return TuningResult(canonical_name(controller), rows, dict(rows[0]["point"]))


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(float(value)) if isinstance(value, float) else str(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {value!r} to TOML")


def _without_nulls(data: dict[str, Any]) -> dict[str, Any]:
    return {k: _without_nulls(v) if isinstance(v, dict) else v for k, v in data.items() if v is not None}


def write_settings(path: Path, best: Mapping[str, Any], header: str) -> None:
    """Merge the dotted ``best`` keys into the TOML settings file ``path`` (created if absent;
    other keys kept) and write it atomically with a ``header`` comment."""
    data: dict[str, Any] = tomllib.loads(path.read_text()) if path.exists() else {}
    # an older schema's file is migrated first: the tuned keys are today's, and so is its schema
    # (TOML has no null: a null a migration filled in is today's default, left out)
    data = _without_nulls(migrate(data, schema_of(data.pop("schema", None), str(path), SCHEMA)))
    data["schema"] = SCHEMA
    for key, value in best.items():
        target = data
        *sections, leaf = key.split(".")
        for section in sections:
            target = target.setdefault(section, {})
        target[leaf] = value
    lines = [f"# {line}" for line in header.splitlines()]
    scalars = {k: v for k, v in data.items() if not isinstance(v, dict)}
    lines += [f"{k} = {_toml_value(v)}" for k, v in sorted(scalars.items())]

    def section(prefix: str, table: dict) -> None:
        leaves = {k: v for k, v in table.items() if not isinstance(v, dict)}
        if leaves:
            lines.append(f"\n[{prefix}]")
            lines.extend(f"{k} = {_toml_value(v)}" for k, v in sorted(leaves.items()))
        for k, v in sorted(table.items()):
            if isinstance(v, dict):
                section(f"{prefix}.{k}", v)

    for key, table in sorted(data.items()):
        if isinstance(table, dict):
            section(key, table)
    atomic_write(path, "\n".join(lines).lstrip("\n") + "\n")
