"""Several saved runs side by side: ``hydroarm compare RUN.npz RUN.npz ...``.

:func:`load_runs` reads the trajectories (from ``hydroarm run``, ``reproduce``, ``sweep
--trajectories``; a ROS 2 bag of ``hydroarm ros2 sim --record``:
:func:`~hydroarm.sim.rosbag.trajectory_from_bag`), :func:`compare_rows` gives each run's E_p
over the whole run and after the start-up (per joint and the mean over joints, rad^2), and
:func:`plot_comparison` overlays their joint errors, torques and disturbance estimates, one row
of axes per joint, each axis scaled to its own joint (a light wrist's torques are not flattened by the shoulder's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import matplotlib
import numpy as np

from hydroarm.config import ConfigError
from hydroarm.sim.logs import LogError
from hydroarm.sim.rosbag import is_bag, trajectory_from_bag
from hydroarm.sim.runner import Trajectory, tracking_metrics
from hydroarm.studies.figures import subplots

STEADY_AFTER = 2.0
"""s: where "after the start-up" starts by default (the start-up from the task's start)."""


@dataclass
class ComparedRun:
    """One run of a comparison: its ``label`` (controller and file), ``path`` and trajectory."""

    label: str
    path: Path
    trajectory: Trajectory


def load_runs(paths: list[Path]) -> list[ComparedRun]:
    """The trajectories at ``paths``; :class:`ConfigError` naming the file for a missing or
    unreadable one, and when the runs do not have the same number of joints."""
    if not paths:
        raise ConfigError("RUNS: give at least one trajectory .npz")
    runs = []
    for path in paths:
        path = Path(path)
        if is_bag(path):
            try:
                traj = trajectory_from_bag(path)
            except LogError as error:
                raise ConfigError(f"RUN '{path}': {error}") from None
            runs.append(ComparedRun(_label(traj, path), path, traj))
            continue
        if not path.is_file():
            kind = "a folder, not a file" if path.is_dir() else "no such file"
            raise ConfigError(f"RUN '{path}': {kind}")
        try:
            traj = Trajectory.load(path)
        except Exception:  # noqa: BLE001 - any unreadable file is bad input
            raise ConfigError(
                f"RUN '{path}': not a hydroarm trajectory (a .npz from run, reproduce or sweep --trajectories)"
            ) from None
        runs.append(ComparedRun(_label(traj, path), path, traj))
    joints = {run.trajectory.n_joints for run in runs}
    if len(joints) > 1:
        counts = ", ".join(f"{run.path.name}: {run.trajectory.n_joints}" for run in runs)
        raise ConfigError(f"RUNS: the runs have different numbers of joints ({counts}); compare runs of one arm")
    labels = [run.label for run in runs]
    for run in runs:  # the same controller twice: tell them apart by their files
        if labels.count(run.label) > 1:
            run.label = f"{run.label} ({_short(run.path)})"
    return runs


def _label(traj: Trajectory, path: Path) -> str:
    controller = traj.meta.get("controller")
    return str(controller) if controller else path.stem


def _short(path: Path) -> str:
    return path.stem if path.stem != "trajectory" else f"{path.parent.name}/{path.name}"


def compare_rows(runs: list[ComparedRun], steady_after: float = STEADY_AFTER) -> list[dict]:
    """Per run: ``label``, ``file``, ``duration`` (s), ``Ep`` and ``Ep_steady`` per joint
    (rad^2; ``Ep_steady`` over t > ``steady_after`` s, None if the run ends before), their means
    over joints ``Ep_mean``/``Ep_steady_mean``, and ``diverged``."""
    rows = []
    for run in runs:
        metrics = tracking_metrics(run.trajectory, steady_after=steady_after)
        steady = [None if math.isnan(x) else x for x in metrics["Ep_steady"]]
        rows.append(
            {
                "label": run.label,
                "file": str(run.path),
                "duration": float(run.trajectory.meta.get("duration", len(run.trajectory.t) * _period(run))),
                "Ep": metrics["Ep"],
                "Ep_mean": float(np.mean(metrics["Ep"])),
                "Ep_steady": steady,
                "Ep_steady_mean": None if None in steady else float(np.mean(steady)),
                "diverged": bool(metrics["diverged"]),
            }
        )
    return rows


def _period(run: ComparedRun) -> float:
    t = run.trajectory.t
    return float(t[1] - t[0]) if len(t) > 1 else 0.0


def plot_comparison(runs: list[ComparedRun], path: Path, steady_after: float = STEADY_AFTER) -> Path:
    """Overlay the runs: per joint (rows), the tracking error q_r - q (rad), the torque (N m)
    and the disturbance estimate (N m; the true disturbance dotted where the run has it).
    Every axis is scaled to its own data; a dashed line marks ``steady_after``. Writes a PNG."""
    n = runs[0].trajectory.n_joints
    has_estimate = any(np.isfinite(run.trajectory.disturbance_estimate).any() for run in runs)
    columns = ["tracking error q_r - q (rad)", "torque (N m)"]
    columns += ["disturbance estimate (N m)"] if has_estimate else []
    fig, axes = subplots(n, len(columns), figsize=(4.6 * len(columns), 1.9 * n + 1.2), sharex=True, squeeze=False)
    colours = matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, run in enumerate(runs):
        traj, colour = run.trajectory, colours[k % len(colours)]
        error = traj.q_ref - traj.q
        for j in range(n):
            axes[j, 0].plot(traj.t, error[:, j], color=colour, lw=0.9, label=run.label)
            axes[j, 1].plot(traj.t, traj.u[:, j], color=colour, lw=0.9)
            if has_estimate:
                axes[j, 2].plot(traj.t, traj.disturbance_estimate[:, j], color=colour, lw=0.9)
                if np.isfinite(traj.disturbance[:, j]).any():
                    axes[j, 2].plot(traj.t, traj.disturbance[:, j], color=colour, lw=0.7, ls=":")
    for j in range(n):
        axes[j, 0].set_ylabel(f"joint {j + 1}")
        for ax in axes[j]:
            ax.axvline(steady_after, color="0.6", lw=0.7, ls="--")
            ax.grid(alpha=0.3)
    for c, title in enumerate(columns):
        axes[0, c].set_title(title, fontsize=10)
        axes[-1, c].set_xlabel("time (s)")
    fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="upper center", ncol=min(len(runs), 4), fontsize=9)
    note = f"dashed: t = {steady_after:g} s, where E_p after the start-up starts"
    if has_estimate:
        note += "; dotted: the true disturbance"
    fig.text(0.5, 0.005, note, ha="center", fontsize=8, color="0.4")
    fig.tight_layout(rect=(0, 0.02, 1, 1 - 0.5 / (1.9 * n + 1.2)))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path
