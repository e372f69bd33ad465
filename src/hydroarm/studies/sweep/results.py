"""A sweep's results: the run files (the resume cache), the tracking bound, results.csv.

``runs/<id>.json`` is one finished run (:func:`~hydroarm.studies.sweep.worker.execute_run`'s
record), ``runs/<id>.npz`` its trajectory when asked for; :class:`RunFiles` reads and writes
them for :func:`~hydroarm.studies.executor.run_tasks`. :func:`assess` checks a run against the
sweep's tracking bound. :class:`ResultsTable` is ``results.csv``: one row per plan row with
every setting and metric, rewritten atomically.
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from hydroarm.sim.files import atomic_write
from hydroarm.studies.executor import RunCache
from hydroarm.studies.sweep.plan import FORMAT, Plan, PlanRow, RunTask
from hydroarm.studies.sweep.schema import MISMATCH_PREFIX, Robustness
from hydroarm.studies.sweep.worker import finite

DEFAULT_BOUND = Robustness()
"""The tracking bound of a sweep file without ``[robustness]``."""

FAULT_PREFIX = "faults."
"""Results-table columns of the fault counts: ``faults.<key>``, one per key that occurred."""


def steady_max_error(envelope: Mapping[str, Any] | None, after: float) -> float:
    """The largest |q_r - q| (rad) from ``after`` s on (windows starting at or after it), from
    :func:`~hydroarm.studies.sweep.worker.error_envelope`'s dict; inf if an error there was
    not finite, NaN if no window starts that late."""
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


class RunFiles(RunCache):
    """The sweep's resume cache: ``runs/<id>.json`` (and ``runs/<id>.npz`` if the task keeps
    its trajectory). A run is finished if its file is whole, of this id and :data:`FORMAT`
    (and its trajectory is there when asked for)."""

    suffix = ".json"

    def read(self, task: RunTask) -> dict | None:
        record = read_run(self.path(task), task.id)
        if record is None or (task.save_trajectory and not self.path(task, ".npz").is_file()):
            return None
        return record

    def write(self, task: RunTask, outcome: dict) -> dict:
        """Write the trajectory (if any), then the record (the record marks the run finished)."""
        if outcome.get("trajectory") is not None:
            atomic_write(self.path(task, ".npz"), outcome["trajectory"])
        record = outcome["record"]
        atomic_write(self.path(task), json.dumps(record, indent=1, allow_nan=False))
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
"""The per-joint metrics of :func:`hydroarm.sim.runner.tracking_metrics`: columns ``Ep_1``, ``Ep_2``, ..."""


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
    row: PlanRow, record: Mapping[str, Any], settings: Mapping[str, Any], robustness: Robustness = DEFAULT_BOUND
) -> dict[str, Any]:
    """One CSV row: the row's settings (as written in the sweep), the run's metrics, the run
    against the tracking bound and its fault counts (``faults.<key>``)."""
    out: dict[str, Any] = {"id": row.id, "controller": row.controller, "seed": row.seed, "point": row.point}
    out.update(settings)
    out.update({key: _cell(value) for key, value in row.params.items()})
    summary = record["summary"]
    out.update({key: _cell(summary.get(key)) for key in SUMMARY_COLUMNS})
    verdict = assess(record, robustness)
    out.update({key: _cell(finite(verdict[key])) for key in BOUND_COLUMNS})
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
        atomic_write(self.path, buffer.getvalue())
