"""One run of a sweep, in a worker: :func:`execute_run` and what a run file records.

The worker builds the experiment with the one builder
(:func:`~hydroarm.sim.experiment.build_experiment`): the controller gets the nominal
arm, the true plant the perturbed one (:func:`~hydroarm.sim.mismatch.perturbed_arm`).
It returns the run file's content (settings, metrics, one number per metric, fault counts
and the error envelope, as strict JSON) and, on request, the trajectory's ``.npz`` bytes;
the driver writes both.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from hydroarm.model.arm.description import Arm
from hydroarm.sim.experiment import build_experiment, settings_from_record
from hydroarm.sim.files import file_bytes
from hydroarm.sim.runner import Trajectory, fault_counts, stop_reason, tracking_metrics
from hydroarm.sim.settings_schema import SCHEMA
from hydroarm.studies.executor import StepHook
from hydroarm.studies.sweep.plan import FORMAT, RunTask

ENVELOPE_WINDOW = 0.1
"""s: a run file keeps the largest |q_r - q| over joints per window of this length (at
least one control step), so the robustness bound can be checked from any time on."""


def finite(value: Any) -> Any:
    """NaN/inf -> None, recursively (strict JSON)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, list):
        return [finite(v) for v in value]
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    return value


def error_envelope(traj: Trajectory, window: float = ENVELOPE_WINDOW) -> dict:
    """The largest |q_r - q| over joints per window: ``{"window_s": w, "max_abs_error": [...]}``
    (rad), window i covering t in [i w, (i + 1) w); w is ``window`` rounded to whole control
    steps (at least one)."""
    period = float(traj.meta["control_period"])
    steps = max(1, int(round(window / period)))
    error = np.max(np.abs(traj.q_ref - traj.q), axis=1)  # (K,)
    peaks = [float(np.max(error[k : k + steps])) for k in range(0, len(error), steps)]
    return {"window_s": steps * period, "max_abs_error": peaks}


def _scalars(metrics: dict, traj: Trajectory) -> dict:
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


def execute_run(task: RunTask, arm: Arm, progress: StepHook | None = None) -> dict:
    """Run one task on ``arm`` (the nominal arm: the controller's; the plant gets
    :func:`~hydroarm.sim.mismatch.perturbed_arm`'s), from
    :func:`~hydroarm.sim.experiment.start_for_arm`'s state; ``progress(k, total)``.

    Returns ``{"record": <the run file's content>, "trajectory": <.npz bytes or None>}``;
    the driver writes both (so workers need no shared disk, e.g. on a Ray cluster).
    """
    from hydroarm import __version__

    start = time.perf_counter()
    config = settings_from_record(task.settings, f"run {task.id}", missing=SCHEMA)  # the compact form
    experiment = build_experiment(config, task.controller, arm=arm)  # the plant on the arm its mismatch perturbs
    traj: Trajectory = experiment.run(task.seed, progress)
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
        blob = file_bytes(traj.save, "run.npz")
    return {"record": finite(record), "trajectory": blob}
