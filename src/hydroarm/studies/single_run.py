"""One run, as ``hydroarm run`` makes it: the request (:class:`RunRequest`), the experiment it
builds (:func:`prepare_run`: the arm, the vehicle, the plant mismatch, the learner's saved model)
and the files it writes (:func:`write_run`: trajectory, metrics, figures). The command only
parses its options into a request, shows progress and prints the summary."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hydroarm.config import ConfigError
from hydroarm.control.interface import ModelLearner, learner_of
from hydroarm.sim.experiment import Experiment, ExperimentConfig, build_experiment, canonical_name, with_overrides
from hydroarm.sim.runner import Trajectory, tracking_metrics
from hydroarm.studies.compare import STEADY_AFTER
from hydroarm.studies.sweep.schema import Mismatch

__all__ = ["STEADY_AFTER", "PreparedRun", "RunRequest", "prepare_run", "write_run"]


@dataclass(frozen=True)
class RunRequest:
    """What ``hydroarm run`` was asked: ``config`` (the settings file, --tuned and --set applied),
    the options that override it (None: not given), the plant ``mismatch`` and the learner's
    model files (PI-IDMPC: ``model`` to start from, ``save_model`` to write)."""

    config: ExperimentConfig
    controller: str | None = None
    arm: str | None = None
    noise: float | None = None
    vehicle: str | None = None
    seed: int = 0
    mismatch: Mismatch = Mismatch()
    model: Path | None = None
    save_model: Path | None = None


@dataclass
class PreparedRun:
    """A run ready to go: its settings, controller name, whether the arm is on a vehicle, the
    experiment, the learner whose model is loaded or saved (None if neither), and what the
    output folder records of it (``what``: the settings; ``made_by``: the command)."""

    request: RunRequest
    config: ExperimentConfig
    name: str
    on_vehicle: bool
    experiment: Experiment
    learner: ModelLearner | None
    what: dict
    made_by: str


def prepare_run(request: RunRequest) -> PreparedRun:
    """The experiment of ``request``: the options over the settings (on a vehicle, the arm the
    vehicle file mounts unless --arm), the controller (default GP-MPC; on a vehicle the arm's
    SMC), the plant's arm perturbed by the mismatch, the learner's model loaded. Raises
    :class:`ConfigError` naming the option that cannot apply."""
    from hydroarm.model.arm.loading import load_arm
    from hydroarm.studies.sweep.plan import perturbed_arm

    on_vehicle = request.vehicle is not None or request.config.vehicle.name is not None
    if on_vehicle and request.noise is not None:
        raise ConfigError("--noise does not apply on a vehicle: the floating plant gives its true state")
    options = {"arm": request.arm, "plant.noise_variance": request.noise, "vehicle.name": request.vehicle}
    config = with_overrides(request.config, {key: value for key, value in options.items() if value is not None})
    if on_vehicle and request.arm is None and config.arm == "paper":
        config = with_overrides(config, {"arm": "mount"})  # the arm the vehicle file mounts
    name = canonical_name(request.controller if request.controller is not None else ("smc" if on_vehicle else "gp-mpc"))
    files = request.model is not None or request.save_model is not None
    if files and name != "PI-IDMPC":
        raise ConfigError(
            f"--model / --save-model: only PI-IDMPC has a water model to load or save (controller {name})"
        )
    if request.model is not None and not request.model.is_file():
        raise ConfigError(f"--model '{request.model}': no such file")
    mismatch = request.mismatch
    if on_vehicle:
        if not mismatch.is_identity:
            raise ConfigError("mismatch.*: not on a vehicle run (the floating plant's arm is the arm file's)")
        experiment = build_experiment(config, name)
    else:
        arm_model = load_arm(config.arm)
        experiment = build_experiment(config, name, arm=arm_model, plant_arm=perturbed_arm(arm_model, mismatch))
    learner = learner_of(experiment.controller) if files else None
    if files and learner is None:  # pragma: no cover - PI-IDMPC is a ModelLearner (tests/test_ports.py)
        raise ConfigError(f"--model / --save-model: controller {experiment.controller.name} has no model to load")
    if request.model is not None:
        learner.load_model(request.model)
    what = {"experiment": config.model_dump(mode="json"), "controller": name, "seed": request.seed}
    if not mismatch.is_identity:
        what["mismatch"] = mismatch.model_dump()
    made_by = f"hydroarm run --controller {name.lower()} --seed {request.seed} --arm {config.arm}"
    if on_vehicle:
        made_by += f" --vehicle {config.vehicle.name}"
    return PreparedRun(request, config, name, on_vehicle, experiment, learner, what, made_by)


def write_run(run: PreparedRun, traj: Trajectory, out: Path) -> dict:
    """Into ``out``: the learner's model (``--save-model``), trajectory.npz, metrics.json
    (:func:`~hydroarm.sim.runner.tracking_metrics`, steady after :data:`STEADY_AFTER` s; on a vehicle
    with ``station_keeping``) and the figures. Returns the metrics."""
    from hydroarm.studies import figures
    from hydroarm.studies.outputs import dumps

    traj.meta["mismatch"] = run.request.mismatch.model_dump()
    if run.request.save_model is not None:
        run.learner.save_model(run.request.save_model)
        traj.meta["model_saved"] = str(run.request.save_model)
    traj.save(out / "trajectory.npz")
    metrics = tracking_metrics(traj, steady_after=STEADY_AFTER)
    if run.on_vehicle:
        metrics["station_keeping"] = traj.meta["metrics"]
    (out / "metrics.json").write_text(dumps(metrics, indent=1))
    label = run.experiment.controller.name
    figures.plot_tracking(traj, out / "position.png", f"{label}: position tracking", "position")
    figures.plot_tracking(traj, out / "velocity.png", f"{label}: velocity tracking", "velocity")
    figures.plot_torque(traj, out / "torque.png", f"{label}: joint torques", run.experiment.arm.torque_limit)
    if np.isfinite(traj.disturbance_estimate).any() and np.isfinite(traj.disturbance).any():
        figures.plot_disturbance(traj, out / "disturbance.png", f"{label}: true vs estimated disturbance")
    return metrics
