"""The UVMS study: station keeping in a 0.2 m/s current while the Alpha 5 reaches and returns.

Runs (each one ordinary experiment on a vehicle, :func:`~hydroarm.sim.experiment.build_experiment`
with ``vehicle.name`` set, through the executor and its resume cache, ``<out>/runs/<id>.json``):

* the vehicle controllers, blind to the arm vs coupling-aware (GP feed-forward): PID and MPC;
* the PID pair again in still water (current 0): the GP's residual then holds the arm's forces
  only, so its gain there is the gain on the arm-induced disturbance alone (in the current
  the residual also holds the current's drag on the vehicle, which the vehicle model lacks);
* which of the arm's effects matter for the vehicle: the blind PID with one effect off at a
  time (arm buoyancy, arm added mass, arm drag, the current on the arm): the change of the
  drift and of the mean wrench the thrusters deliver, against the full model.

Writes ``metrics.json``, one figure per axis (``fig_<axis>.png``: blind vs aware, PID) and
``report.md`` into the output folder.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from hydroarm.sim.experiment import ExperimentConfig, build_experiment
from hydroarm.sim.files import atomic_write
from hydroarm.studies.executor import RunCache, make_executor, run_tasks

VEHICLE = "bluerov2-heavy"
ARM_CONTROLLER = "SMC"
"""The study's vehicle (with the arm its file mounts, the Alpha 5) and the arm's controller."""

AXES = ("x", "y", "z", "roll", "pitch", "yaw")
EFFECTS = {
    "arm_buoyancy": "arm buoyancy",
    "arm_added_mass": "arm added mass",
    "arm_drag": "arm drag",
    "arm_current": "the current on the arm",
}

GP_PAIRS = {  # GP gain key -> (blind run, aware run)
    "pid": ("pid_blind", "pid_aware"),
    "mpc": ("mpc_blind", "mpc_aware"),
    "pid_still_water": ("pid_blind_still_water", "pid_aware_still_water"),
}


@dataclass(frozen=True)
class UVMSTask:
    """One run of the study: ``id`` (file name), ``label``, the run's settings as JSON (an
    :class:`~hydroarm.sim.experiment.ExperimentConfig` with its ``vehicle`` section)."""

    id: str
    label: str
    settings: str
    arm_key: str | None = None


def study_tasks(duration: float) -> list[UVMSTask]:
    return _tasks(duration)


def _tasks(duration: float) -> list[UVMSTask]:
    variants = {
        "pid_blind": {"control": {"kind": "pid"}},
        "pid_aware": {"control": {"kind": "pid"}, "aware": True},
        "mpc_blind": {"control": {"kind": "mpc"}},
        "mpc_aware": {"control": {"kind": "mpc"}, "aware": True},
        "pid_blind_still_water": {"control": {"kind": "pid"}, "current": 0.0},
        "pid_aware_still_water": {"control": {"kind": "pid"}, "aware": True, "current": 0.0},
    }
    for effect in EFFECTS:
        variants[f"pid_blind_no_{effect}"] = {"control": {"kind": "pid"}, "plant": {effect: False}}
    return [
        UVMSTask(id=name, label=name, settings=_settings(duration, values).model_dump_json())
        for name, values in variants.items()
    ]


def _settings(duration: float, vehicle: dict) -> ExperimentConfig:
    return ExperimentConfig.model_validate(
        {"arm": "mount", "duration": duration, "vehicle": {"name": VEHICLE, **vehicle}}
    )


def run_task(task: UVMSTask, arm, progress=None) -> dict:
    """Module-level worker: the run's metrics and the series the figures need (the K control
    instants and the end of the run)."""
    config = ExperimentConfig.model_validate_json(task.settings)
    experiment = build_experiment(config, ARM_CONTROLLER)
    traj = experiment.run(progress=progress)
    final = np.asarray(traj.meta["final_state"])
    layout = experiment.uvms.layout
    poses = np.vstack([traj.extra["base_pose"], final[layout.base_pose]])
    errors = np.empty((poses.shape[0], 6))
    errors[:, :3] = poses[:, :3] - poses[0, :3]
    rot0 = pin.Quaternion(poses[0, 6], *poses[0, 3:6]).toRotationMatrix()
    for k, pose in enumerate(poses):
        rot = pin.Quaternion(pose[6], *pose[3:6]).toRotationMatrix()
        errors[k, 3:] = np.degrees(pin.rpy.matrixToRpy(rot0.T @ rot))
    wrench = traj.extra["thrust_command"] @ experiment.uvms.vehicle.allocation.T
    every = max(1, int(round(0.05 / config.control_period)))
    arm_q = np.vstack([traj.q, final[layout.arm_q]])
    return {
        "settings": json.loads(task.settings),
        "metrics": traj.meta["metrics"] | {"mean_abs_wrench": np.mean(np.abs(wrench), axis=0).tolist()},
        "t": (np.arange(poses.shape[0]) * config.control_period)[::every].tolist(),
        "errors": errors[::every].tolist(),
        "d_hat": traj.extra["vehicle_disturbance_estimate"][::every].tolist(),
        "arm_q": arm_q[::every].tolist(),
    }


class UVMSCache(RunCache):
    def read(self, task: UVMSTask):
        path = self.path(task)
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError):
            return None
        return data if data.get("settings") == json.loads(task.settings) else None

    def write(self, task: UVMSTask, outcome: dict):
        atomic_write(self.path(task), json.dumps(outcome))
        return outcome


def run_vehicle_study(out: str | Path, quick: bool = False, workers: int = 2, on_progress=None) -> dict:
    """Run (or resume) the study into ``out``; returns the metrics document."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    tasks = study_tasks(8.0 if quick else 30.0)  # (tests shorten the runs through study_tasks)
    cache = UVMSCache(out / "runs")
    finished, todo = cache.lookup(tasks)
    report = run_tasks(todo, run_task, cache, make_executor(workers), reused=len(finished), on_progress=on_progress)
    if report.failed:
        task, error = report.failed[0]
        raise RuntimeError(f"UVMS run {task.id} failed: {error}")
    done = finished | report.results
    results = {task.id: done[task.id] for task in tasks}  # the study's order, not the finishing order
    metrics = summarise(results)
    metrics["quick"] = quick
    atomic_write(out / "metrics.json", json.dumps(metrics, indent=2) + "\n")
    write_figures(results, out)
    atomic_write(out / "report.md", render_report(metrics))
    return metrics


def _gain(blind: float, aware: float) -> float:
    return 100.0 * (blind - aware) / blind if blind > 0 else 0.0


def summarise(results: dict) -> dict:
    runs = {name: result["metrics"] for name, result in results.items()}
    gains = {}
    for kind, (blind_run, aware_run) in GP_PAIRS.items():
        blind, aware = runs[blind_run], runs[aware_run]
        gains[kind] = {
            key: _gain(blind[key], aware[key])
            for key in ("drift_rms_m", "drift_max_m", "attitude_rms_deg", "ee_error_rms_m")
        }
    full = runs["pid_blind"]
    effects = {}
    for effect, label in EFFECTS.items():
        off = runs[f"pid_blind_no_{effect}"]
        effects[effect] = {
            "label": label,
            "drift_rms_change_m": off["drift_rms_m"] - full["drift_rms_m"],
            "attitude_rms_change_deg": off["attitude_rms_deg"] - full["attitude_rms_deg"],
            "mean_wrench_change": float(np.sum(np.abs(np.subtract(off["mean_abs_wrench"], full["mean_abs_wrench"])))),
        }
    ranking = sorted(effects, key=lambda e: abs(effects[e]["drift_rms_change_m"]), reverse=True)
    return {"runs": runs, "gp_gain_percent": gains, "effects": effects, "effect_ranking_by_drift": ranking}


def write_figures(results: dict, out: Path) -> None:
    from hydroarm.studies.figures import subplots

    units = ("m", "m", "m", "deg", "deg", "deg")
    for axis, name in enumerate(AXES):
        fig, ax = subplots(figsize=(7, 3))
        for run, style in (("pid_blind", "-"), ("pid_aware", "--"), ("mpc_blind", ":"), ("mpc_aware", "-.")):
            data = results[run]
            ax.plot(data["t"], np.asarray(data["errors"])[:, axis], style, label=run.replace("_", " "))
        ax.set_xlabel("t (s)")
        ax.set_ylabel(f"{name} error ({units[axis]})")
        ax.set_title(f"station keeping, {name}: blind vs GP feed-forward")
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out / f"fig_{name}.png", dpi=110)


def render_report(metrics: dict) -> str:
    runs = metrics["runs"]
    lines = [
        "# UVMS study: station keeping while the arm works",
        "",
        "BlueROV2 Heavy + Reach Alpha 5 (SMC on the fixed-base arm model), 0.2 m/s current along x, the arm",
        "reaching and returning every 6 s; the vehicle holds its start pose.",
        "",
        "| run | drift RMS (m) | drift max (m) | attitude RMS (deg) | saturation (s) | EE error RMS (m) | EE max (m) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, m in runs.items():
        lines.append(
            f"| {name} | {m['drift_rms_m']:.4f} | {m['drift_max_m']:.4f} | {m['attitude_rms_deg']:.3f} | "
            f"{m['saturation_time_s']:.2f} | {m['ee_error_rms_m']:.4f} | {m['ee_error_max_m']:.4f} |"
        )
    lines += ["", "GP feed-forward gain (blind -> aware, % reduction):", ""]
    for kind, gains in metrics["gp_gain_percent"].items():
        label = {"pid": "PID", "mpc": "MPC", "pid_still_water": "PID in still water (the arm's forces only)"}[kind]
        lines.append(f"- {label}: " + ", ".join(f"{k} {v:.1f}%" for k, v in gains.items()))
    lines += ["", "Which arm effects matter (blind PID, one effect off; change against the full model):", "",
              "| effect off | drift RMS change (m) | attitude RMS change (deg) | sum of mean wrench changes |",
              "|---|---:|---:|---:|"]  # fmt: skip
    for effect in metrics["effect_ranking_by_drift"]:
        e = metrics["effects"][effect]
        lines.append(
            f"| {e['label']} | {e['drift_rms_change_m']:+.4f} | {e['attitude_rms_change_deg']:+.3f} | "
            f"{e['mean_wrench_change']:.3f} |"
        )
    lines += ["", "Figures: " + ", ".join(f"`fig_{a}.png`" for a in AXES) + ".", ""]
    return "\n".join(lines)
