"""One experiment as validated data, and the one way to build it.

``ExperimentConfig`` is what a TOML file (``--config``) and ``--set key=value``
overrides describe. :func:`build_experiment` turns it into an :class:`Experiment`
(the true plant, the controller, the task's reference and the start state) and is
the only place where these are wired together: the runner (:func:`run_experiment`),
the sweep worker, the benchmark and the Gymnasium env all use it. The control period
is set once here (``ExperimentConfig.control_period``) and handed to the controller.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import pydantic

from hydroarm.config import (
    ConfigError,
    FrozenModel,
    check_joint_counts,
    dotted_keys,
    shown,
    unknown_key_message,
    validate,
)
from hydroarm.control import registry
from hydroarm.control.estimator import EstimatorConfig
from hydroarm.control.gp import GPConfig
from hydroarm.control.gpmpc import GPMPCConfig, feature_size
from hydroarm.control.idmpc import IDMPCConfig, gp_input_size
from hydroarm.control.interface import Controller
from hydroarm.control.mpc import MPCConfig
from hydroarm.control.observers import ObserverConfig
from hydroarm.control.registry import CONTROLLERS, canonical_name
from hydroarm.control.smc import SMCConfig
from hydroarm.control.water_model import WaterModelConfig
from hydroarm.model.arm import Arm
from hydroarm.model.loading import load_arm
from hydroarm.model.plant import PlantConfig, UnderwaterPlant
from hydroarm.model.task import SinusoidReference
from hydroarm.model.task_file import SplineReference, TaskConfig, reference_for
from hydroarm.model.water import Water
from hydroarm.studies.runner import Trajectory, run_closed_loop

__all__ = [
    "CONTROLLERS",
    "Experiment",
    "ExperimentConfig",
    "InitialState",
    "build_controller",
    "build_experiment",
    "canonical_name",
    "check_settings_for_arm",
    "run_experiment",
    "start_for_arm",
    "with_overrides",
]

SETTINGS_HINT = "`hydroarm settings` lists the allowed settings"
"""Where an unknown setting's message sends the reader (every key, default, unit and range)."""

MAX_CONTROL_STEPS = 1_000_000
"""Most control steps of one run (duration / control_period): every step's row is stored."""

CONTROLLER_SECTIONS: tuple[str, ...] = ("smc", "mpc", "gp", "gpmpc", "idmpc", "water_model", "observer", "estimator")
"""The sections of :class:`ExperimentConfig` that only controllers read."""

CONTROLLER_SETTINGS: dict[str, tuple[str, ...]] = {
    name: (*spec.sections, "estimator") for name, spec in registry.REGISTRY.items()
}
"""The controller sections each controller reads (from the registry): a sweep leaves the
other sections out of a run's id, so sweeping ``mpc.r`` runs SMC once."""


class InitialState(FrozenModel):
    """Where a run starts: the task's start x0 (:func:`task_for_arm`) plus a seeded uniform draw.

    Joint i starts at ``q0_i + U(-position_spread, position_spread)`` (rad) and
    ``v0_i + U(-velocity_spread, velocity_spread)`` (rad/s), drawn from
    ``numpy.random.default_rng(seed)`` (the n positions, then the n velocities).
    With both spreads 0 (the default) the start is x0 exactly and nothing is
    drawn. The draw is not clipped to joint limits. ``seed`` is independent of
    the measurement-noise seed of the run.
    """

    position_spread: float = pydantic.Field(
        0.0, ge=0.0, le=10.0, description="half-width of the uniform draw around each start position (rad)"
    )
    velocity_spread: float = pydantic.Field(
        0.0, ge=0.0, le=100.0, description="half-width of the uniform draw around each start velocity (rad/s)"
    )
    seed: int = pydantic.Field(0, ge=0, le=2**63 - 1, description="seed of the start draw, not of the noise (-)")

    def apply(self, x0: np.ndarray) -> np.ndarray:
        """The start state (2n,) from the task's start ``x0`` (2n,) = [q0, v0]."""
        x0 = np.asarray(x0, dtype=float)
        if self.position_spread == 0.0 and self.velocity_spread == 0.0:
            return x0.copy()
        n = x0.shape[0] // 2
        rng = np.random.default_rng(self.seed)
        dq = rng.uniform(-self.position_spread, self.position_spread, n)
        dv = rng.uniform(-self.velocity_spread, self.velocity_spread, n)
        return x0 + np.concatenate([dq, dv])


class ExperimentConfig(FrozenModel):
    """Everything that defines one closed-loop run (SPEC defaults).

    ``initial_state``: a seeded random start around the task's start (default:
    the task's start exactly, see :class:`InitialState`). Every key, its default, unit and
    allowed range: ``hydroarm settings`` (docs/settings.md).
    """

    settings_hint: ClassVar[str] = SETTINGS_HINT

    arm: str = pydantic.Field(
        "paper", description="a built-in arm (`hydroarm arms`) or an arm file: DH .toml, .urdf, .hydro.toml"
    )
    duration: float = pydantic.Field(10.0, gt=0.0, le=3600.0, description="length of a run (s)")
    control_period: float = pydantic.Field(
        0.01, ge=1e-4, le=1.0, description="T, the control period of every controller (s)"
    )
    water: Water = pydantic.Field(Water(), description="the water of the true plant (section)")
    plant: PlantConfig = pydantic.Field(PlantConfig(), description="the true plant's integration and sensing (section)")
    smc: SMCConfig = pydantic.Field(SMCConfig(), description="the sliding-mode controller (section)")
    mpc: MPCConfig = pydantic.Field(MPCConfig(), description="the paper's linear MPC, also inside GP-MPC (section)")
    gp: GPConfig = pydantic.Field(GPConfig(), description="the sliding-window GP of GP-MPC and GP-IDMPC (section)")
    gpmpc: GPMPCConfig = pydantic.Field(GPMPCConfig(), description="how the GP is wired into GP-MPC (section)")
    idmpc: IDMPCConfig = pydantic.Field(
        IDMPCConfig(), description="the inverse-dynamics MPC, IDMPC and GP-IDMPC (section)"
    )
    water_model: WaterModelConfig = pydantic.Field(
        WaterModelConfig(), description="PI-IDMPC's physics-informed water model and its remainder observer (section)"
    )
    observer: ObserverConfig = pydantic.Field(
        ObserverConfig(), description="the disturbance observer (TDE, NDOB) under SMC, MPC or IDMPC (section)"
    )
    estimator: EstimatorConfig = pydantic.Field(
        EstimatorConfig(), description="the state estimator any controller can run behind (section)"
    )
    task: TaskConfig = pydantic.Field(
        TaskConfig(), description="the reference: the arm's task, sinusoids or a file, and the start (section)"
    )
    initial_state: InitialState = pydantic.Field(
        InitialState(), description="a seeded random start around the task's start (section)"
    )

    @pydantic.model_validator(mode="after")
    def _bounded_step_count(self) -> ExperimentConfig:
        steps = self.duration / self.control_period
        if steps > MAX_CONTROL_STEPS:
            raise ValueError(
                f"control_period = {self.control_period!r}: duration / control_period = {steps:.3g} control steps; "
                f"at most {MAX_CONTROL_STEPS:.0e} (the runner stores every step)"
            )
        return self

    def digest(self) -> str:
        """A short hash of the settings (to tell a finished run of these settings from others)."""
        text = json.dumps(self.model_dump(mode="json"), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def with_overrides(config: ExperimentConfig, overrides: dict[str, Any]) -> ExperimentConfig:
    """A copy with dotted-key overrides (``{"mpc.r": 1e-3}``), validated like a file."""
    data = config.model_dump(mode="python")
    for key, value in overrides.items():
        target = data
        parts = key.split(".")
        for part in parts[:-1]:
            if not isinstance(target, dict) or part not in target:
                raise ConfigError(unknown_key_message(key, dotted_keys(ExperimentConfig), SETTINGS_HINT))
            target = target[part]
        if not isinstance(target, dict) or parts[-1] not in target:
            raise ConfigError(unknown_key_message(key, dotted_keys(ExperimentConfig), SETTINGS_HINT))
        target[parts[-1]] = value
    return validate(ExperimentConfig, data, "settings")


def gp_inputs(name: str, config: ExperimentConfig, n_joints: int) -> tuple[int, str] | None:
    """``(d, why)``: the GP input count of controller ``name`` under ``config`` on n joints and
    the setting that decides it; None for a controller without a GP."""
    canonical = canonical_name(name)
    if canonical == "GP-MPC":
        features = config.gpmpc.features
        return feature_size(features, n_joints), f"GP-MPC: gpmpc.features = '{features}'"
    if canonical == "GP-IDMPC":
        features = config.idmpc.gp_features
        return gp_input_size(features, n_joints), f"GP-IDMPC: idmpc.gp_features = '{features}'"
    return None


def check_settings_for_arm(
    config: ExperimentConfig, arm: Arm, source: str = "settings", controllers: Sequence[str] | None = None
) -> None:
    """What the settings' types cannot say until the arm is known; raises :class:`ConfigError`.

    Every per-joint list (``smc.*``, ``mpc.*``) must have one value per joint; the GP's
    ``theta0`` (d + 2 values), ``input_scale`` (d) and ``output_scale`` (1 or n) must fit
    the d GP inputs (:func:`gp_inputs`) of each GP controller among ``controllers`` (default:
    every registered controller; the section is shared) on the arm's n joints; ``plant.friction`` must
    suit the RK4 step on this arm (:class:`~hydroarm.model.plant.UnderwaterPlant` checks it); a
    task from settings or a file must be readable and have the arm's joint count.
    Nothing is run (with friction, the plant is built: about a millisecond).
    """
    n = arm.n_joints
    try:
        check_joint_counts(config, n)
        if config.task.kind != "arm":  # the task's joint count, its file
            reference_for(config.task, arm)
        if config.plant.friction > 0.0:
            UnderwaterPlant(arm, config.water, config.plant)
    except ConfigError as error:
        raise ConfigError(f"{source}: {error}") from None
    gp = config.gp
    for controller in CONTROLLERS if controllers is None else controllers:
        found = gp_inputs(controller, config, n)
        if found is None:
            continue
        d, why = found
        inputs = f"{why} gives d = {d} GP inputs on {n} joints"
        for name, value, allowed in (
            ("theta0", gp.theta0, (d + 2,)),
            ("input_scale", gp.input_scale, (d,)),
            ("output_scale", gp.output_scale, (1, n)),
        ):
            if value is not None and len(value) not in allowed:
                wanted = " or ".join(str(k) for k in allowed)
                raise ConfigError(
                    f"{source}: gp.{name} = {shown(value)}: {len(value)} values: give {wanted} ({inputs})"
                )


def build_controller(name: str, arm: Arm, config: ExperimentConfig) -> Controller:
    """The controller ``name`` (any spelling of :data:`~hydroarm.control.registry.CONTROLLERS`)
    on ``arm`` with the experiment's settings and its one control period."""
    sections = {section: getattr(config, section) for section in CONTROLLER_SECTIONS}
    return registry.build_controller(
        name, arm, sections, config.control_period, sensor_variance=config.plant.noise_variance
    )


def start_for_arm(arm: Arm, config: ExperimentConfig) -> tuple[SinusoidReference | SplineReference, np.ndarray]:
    """The reference and the start state (2n,) of a run of ``config`` on ``arm``: the task of
    ``config.task`` (:func:`~hydroarm.model.task_file.reference_for`; default the arm's,
    :func:`~hydroarm.model.task.task_for_arm`), moved by ``config.initial_state``
    (:class:`InitialState`)."""
    reference, x0 = reference_for(config.task, arm)
    return reference, config.initial_state.apply(x0)


@dataclass
class Experiment:
    """A closed loop ready to run: what :func:`build_experiment` returns.

    ``arm``: the arm the controller knows; ``plant``: the true plant (its arm may differ:
    a mismatch study); ``controller`` (canonical ``controller.name``; None when the torques
    come from outside, e.g. the Gymnasium env); ``reference``: the task on this arm; ``x0``
    (2n,): the start state; ``config``: the settings.
    """

    config: ExperimentConfig
    arm: Arm
    plant: UnderwaterPlant
    controller: Controller | None
    reference: SinusoidReference | SplineReference
    x0: np.ndarray

    @property
    def control_period(self) -> float:
        return self.config.control_period

    def run(self, seed: int = 0, progress: Callable[[int, int], None] | None = None) -> Trajectory:
        """The closed loop over ``config.duration`` with measurement-noise ``seed``; the
        trajectory's ``meta`` records the settings and their digest."""
        if self.controller is None:
            raise ValueError("this experiment has no controller (built with controller=None): nothing to run")
        traj = run_closed_loop(
            self.plant, self.controller, self.reference, self.config.duration, seed, x0=self.x0, progress=progress
        )
        traj.meta["settings"] = self.config.model_dump(mode="json")
        traj.meta["digest"] = self.config.digest()
        traj.meta["arm"] = self.config.arm
        return traj


def build_experiment(
    config: ExperimentConfig,
    controller: str | None,
    arm: Arm | None = None,
    plant_arm: Arm | None = None,
) -> Experiment:
    """The one experiment builder: plant, controller, reference and start from ``config``.

    ``controller``: any spelling of a registered controller (``"gp-mpc"``, ``"GP-MPC"``), or
    None for no controller (the torques come from outside: the Gymnasium env).
    ``arm``: the arm, if already loaded (default: ``load_arm(config.arm)``); ``plant_arm``:
    a different arm for the true plant only (default: ``arm``). The settings are checked
    against the arm first (:func:`check_settings_for_arm`); the reference and start are
    :func:`start_for_arm`'s.
    """
    arm = load_arm(config.arm) if arm is None else arm
    check_settings_for_arm(config, arm, controllers=() if controller is None else (controller,))
    plant = UnderwaterPlant(arm if plant_arm is None else plant_arm, config.water, config.plant)
    reference, x0 = start_for_arm(arm, config)
    built = None if controller is None else build_controller(controller, arm, config)
    return Experiment(config, arm, plant, built, reference, x0)


def run_experiment(
    config: ExperimentConfig,
    controller: str,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
) -> Trajectory:
    """Run ``controller`` (any spelling) on the true plant of ``config`` along the arm's task
    (:func:`~hydroarm.model.task.task_for_arm`) from :func:`start_for_arm`'s state;
    ``seed`` drives the measurement noise. See :func:`build_experiment`."""
    return build_experiment(config, controller).run(seed, progress)
