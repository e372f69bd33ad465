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
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import pydantic

from hydroarm.config import (
    ConfigError,
    FrozenModel,
    check_joint_counts,
    dotted_keys,
    read_mapping,
    shown,
    unknown_key_message,
    validate,
)
from hydroarm.control import registry
from hydroarm.control.estimator import EstimatorConfig
from hydroarm.control.filter_design import MEASURED_VELOCITY_ACCELERATION_VARIANCE
from hydroarm.control.gp import GPConfig
from hydroarm.control.gpmpc import GPMPCConfig
from hydroarm.control.idmpc import IDMPCConfig
from hydroarm.control.interface import CONTROL_PERIOD_RANGE, DEFAULT_CONTROL_PERIOD, Controller, Reference
from hydroarm.control.learned_water import WaterModelConfig
from hydroarm.control.mpc import MPCConfig
from hydroarm.control.observers import ObserverConfig
from hydroarm.control.pi_idmpc import PIIDMPCConfig
from hydroarm.control.registry import CONTROLLERS, canonical_name, controller_sections, controller_spec
from hydroarm.control.smc import SMCConfig
from hydroarm.model.arm.description import Arm, TorqueLimit
from hydroarm.model.arm.loading import BUILTIN_ARMS, load_arm
from hydroarm.model.arm.plant import PlantConfig, UnderwaterPlant
from hydroarm.model.real_loop.friction import FrictionConfig
from hydroarm.model.real_loop.sensing import ActuatorConfig, SensorConfig
from hydroarm.model.task.references import SinusoidReference
from hydroarm.model.task.task_file import SplineReference, TaskConfig, reference_for
from hydroarm.model.water.morison import Water
from hydroarm.sim.mismatch import Mismatch, perturbed_arm
from hydroarm.sim.plant_protocol import Plant
from hydroarm.sim.runner import Trajectory, run_closed_loop
from hydroarm.sim.settings_rules import check_one_system, compact_declared, declared_section_of, split_declared
from hydroarm.sim.settings_schema import MIGRATIONS, SCHEMA, compact, migrated, moved_settings
from hydroarm.sim.vehicle import (
    VehicleRun,
    check_vehicle_settings,
    source_name,
    station_keeper,
    station_keeping_metrics,
    vehicle_parts,
)

if TYPE_CHECKING:
    from hydroarm.model.vehicle.system import UVMS

__all__ = [
    "CONTROLLERS",
    "Experiment",
    "ExperimentConfig",
    "InitialState",
    "build_controller",
    "build_experiment",
    "arm_for_settings_file",
    "canonical_name",
    "check_settings_for_arm",
    "load_experiment_config",
    "run_settings",
    "settings_from_record",
    "run_experiment",
    "start_for_arm",
    "with_overrides",
]

SETTINGS_HINT = "`hydroarm settings` lists the allowed settings"
"""Where an unknown setting's message sends the reader (every key, default, unit and range)."""

MAX_CONTROL_STEPS = 1_000_000
"""Most control steps of one run (duration / control_period): every step's row is stored."""

REAL_LOOP_SECTIONS: tuple[str, ...] = ("sensor", "actuator", "friction")
"""The sections of the real loop (issue 23): at their defaults, the idealised loop."""

MOVED_SETTINGS: dict[str, str] = moved_settings()
"""Settings that moved, old dotted key -> new (the migrations' ``moved``,
:mod:`hydroarm.sim.settings_schema`): in today's settings an old key is refused with a message
naming the new one (:attr:`ExperimentConfig.moved_settings`); a record of an older schema is
migrated."""


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
    """Everything that defines one closed-loop run (the defaults of docs/paper-reading.md).

    ``initial_state``: a seeded random start around the task's start (default:
    the task's start exactly, see :class:`InitialState`). Every key, its default, unit and
    allowed range: ``hydroarm settings`` (docs/settings.md).
    """

    settings_hint: ClassVar[str] = SETTINGS_HINT
    moved_settings: ClassVar[dict[str, str]] = MOVED_SETTINGS

    arm: str = pydantic.Field(
        "paper", description="a built-in arm (`hydroarm arms`) or an arm file: DH .toml, .urdf, .hydro.toml"
    )
    duration: float = pydantic.Field(10.0, gt=0.0, le=3600.0, description="length of a run (s)")
    control_period: float = pydantic.Field(
        DEFAULT_CONTROL_PERIOD,
        ge=CONTROL_PERIOD_RANGE[0],
        le=CONTROL_PERIOD_RANGE[1],
        description="T, the control period of every controller (s)",
    )
    torque_limit: TorqueLimit | list[TorqueLimit] | None = pydantic.Field(
        None,
        description="|tau_i| <= limit (N m) every controller holds, one value or one per joint, at most 1e12; "
        "null: the arm file's (its actuators')",
    )
    water: Water = pydantic.Field(Water(), description="the water of the true plant (section)")
    plant: PlantConfig = pydantic.Field(PlantConfig(), description="the true plant's integration and sensing (section)")
    sensor: SensorConfig = pydantic.Field(
        SensorConfig(), description="the real loop's sensor: encoder-only, quantisation, delay, dropout (section)"
    )
    actuator: ActuatorConfig = pydantic.Field(
        ActuatorConfig(), description="the real loop's drives: delay, torque, rate and bandwidth limits (section)"
    )
    friction: FrictionConfig = pydantic.Field(
        FrictionConfig(), description="the true plant's Coulomb, Stribeck and viscous joint friction (section)"
    )
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
    pi_idmpc: PIIDMPCConfig = pydantic.Field(
        PIIDMPCConfig(), description="PI-IDMPC's planner: the long plan with the model's water and the limits (section)"
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
    vehicle: VehicleRun = pydantic.Field(
        VehicleRun(), description="the arm on a vehicle holding station (section; off unless vehicle.name is set)"
    )
    mismatch: Mismatch = pydantic.Field(
        Mismatch(), description="the true plant's rigid body away from the arm file the controllers know (section)"
    )

    _declared: dict[str, pydantic.BaseModel] = pydantic.PrivateAttr(default_factory=dict)

    @pydantic.model_validator(mode="wrap")
    @classmethod
    def _declared_sections(cls, data: Any, handler: Any) -> ExperimentConfig:
        """The sections registered controllers declare, validated and kept (:meth:`section`)."""
        rest, declared = split_declared(data, set(cls.model_fields))
        config = handler(rest)
        config._declared.update(declared)
        return config

    @pydantic.model_serializer(mode="wrap")
    def _with_declared(self, handler: Any, info: Any) -> dict[str, Any]:
        data = handler(self)
        for name, section in self._declared.items():
            data[name] = section.model_dump(mode=info.mode)
        return data

    def section(self, name: str) -> pydantic.BaseModel:
        """Settings section ``name``: a built-in one or one a registered controller declares."""
        return getattr(self, name) if name in type(self).model_fields else declared_section_of(self._declared, name)

    @pydantic.model_validator(mode="after")
    def _bounded_step_count(self) -> ExperimentConfig:
        steps = self.duration / self.control_period
        if self.control_period > self.duration or round(steps) < 1:
            raise ValueError(
                f"control_period = {self.control_period!r}: must be <= duration = {self.duration!r} (s); "
                "a run needs at least one control step"
            )
        if steps > MAX_CONTROL_STEPS:
            raise ValueError(
                f"control_period = {self.control_period!r}: duration / control_period = {steps:.3g} control steps; "
                f"at most {MAX_CONTROL_STEPS:.0e} (the runner stores every step)"
            )
        return self

    @pydantic.model_validator(mode="after")
    def _one_system(self) -> ExperimentConfig:
        check_one_system(self)  # a fixed arm or an arm on a vehicle, each with its own settings
        return self

    def canonical(self) -> dict[str, Any]:
        """The settings as JSON data in their compact form (what digests, run ids and summaries
        hold): what a migration added left out where it holds the migration's value
        (:func:`~hydroarm.sim.settings_schema.compact`), so runs made before it keep their ids.
        Read back with :func:`settings_from_record`."""
        data = self.model_dump(mode="json")
        if self.estimator.acceleration_variance is None and self.estimator.measures_velocity(self.sensor):
            data["estimator"]["acceleration_variance"] = MEASURED_VELOCITY_ACCELERATION_VARIANCE  # null = 100 here
        sections = [section for migration in MIGRATIONS for section in migration.sections]
        data = compact(data, {s: type(getattr(self, s))().model_dump(mode="json") for s in sections})
        return compact_declared(data)

    def digest(self) -> str:
        """A short hash of the settings (to tell a finished run of these settings from others)."""
        text = json.dumps(self.canonical(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def _is_arm_file(arm: Any) -> bool:
    return isinstance(arm, str) and arm not in BUILTIN_ARMS and bool(arm)


def load_experiment_config(path: str | Path) -> ExperimentConfig:
    """The settings of file ``path`` (TOML/YAML), validated. A relative ``arm`` file in it is
    read relative to the settings file's folder (as ``hydroarm tune`` writes it), so the file
    works from any working directory; if no such file is there, relative to the working
    directory (as older settings files meant it). A top-level ``schema = k`` (as ``hydroarm
    tune`` writes it) says which settings schema the file was written at: it is migrated to
    today's (:mod:`hydroarm.sim.settings_schema`); without it the file is read as today's."""
    path = Path(path)
    data = read_mapping(path)
    arm = data.get("arm")
    if _is_arm_file(arm) and not Path(arm).is_absolute():
        beside = path.parent / arm
        if beside.exists():
            data = {**data, "arm": str(beside)}
    return settings_from_record(data, str(path), missing=SCHEMA)


def settings_from_record(data: dict[str, Any], source: str, missing: int = 1) -> ExperimentConfig:
    """Settings written by any hydroarm, validated: ``data`` (nested, a settings file's or the
    compact form of :meth:`ExperimentConfig.canonical`, e.g. a run's ``meta["settings"]``) with
    its schema number in ``data["schema"]`` (default ``missing``: 1, a record made before schema
    numbers), migrated to today's schema. A newer schema, or settings that do not validate,
    raise :class:`ConfigError` naming ``source``."""
    return validate(ExperimentConfig, migrated(data, source, missing), source)


def run_settings(meta: dict[str, Any], source: str) -> ExperimentConfig:
    """The settings of a saved run (:class:`~hydroarm.sim.runner.Trajectory` ``meta``: its
    ``settings`` and ``schema``; runs saved before schema numbers read as schema 1)."""
    settings = meta.get("settings")
    if not isinstance(settings, dict):
        raise ConfigError(f"{source}: holds no settings (not a run saved by hydroarm)")
    return settings_from_record({**settings, "schema": meta.get("schema")}, source)


def arm_for_settings_file(arm: str, settings_file: str | Path) -> str:
    """``arm`` as a settings file at ``settings_file`` should name it: a built-in name as is, an
    arm file relative to the settings file's folder (what :func:`load_experiment_config` reads)."""
    if not _is_arm_file(arm) or not Path(arm).exists():
        return arm
    return os.path.relpath(Path(arm).resolve(), Path(settings_file).resolve().parent)


def with_overrides(config: ExperimentConfig, overrides: dict[str, Any]) -> ExperimentConfig:
    """A copy with dotted-key overrides (``{"mpc.r": 1e-3}``), validated like a file."""
    data = config.model_dump(mode="python")

    def unknown(key: str, value: Any) -> ConfigError:
        known = dotted_keys(ExperimentConfig)
        return ConfigError(unknown_key_message(key, known, SETTINGS_HINT, moved=MOVED_SETTINGS, value=value))

    for key, value in overrides.items():
        target = data
        parts = key.split(".")
        for part in parts[:-1]:
            if not isinstance(target, dict) or part not in target:
                raise unknown(key, value)
            target = target[part]
        if not isinstance(target, dict) or parts[-1] not in target:
            raise unknown(key, value)
        target[parts[-1]] = value
    return validate(ExperimentConfig, data, "settings")


def controller_settings(config: ExperimentConfig) -> dict[str, Any]:
    """The config sections the registered controllers read, by name, from ``config`` (the
    ``sections`` mapping of :func:`hydroarm.control.registry.build_controller`)."""
    return {section: config.section(section) for section in controller_sections()}


def gp_inputs(name: str, config: ExperimentConfig, n_joints: int) -> tuple[int, str] | None:
    """``(d, why)``: the GP input count of controller ``name`` under ``config`` on n joints and
    the setting that decides it (its spec's ``gp_inputs``); None for a controller without a GP."""
    spec = controller_spec(name)
    return None if spec.gp_inputs is None else spec.gp_inputs(controller_settings(config), n_joints)


def check_settings_for_arm(
    config: ExperimentConfig, arm: Arm, source: str = "settings", controllers: Sequence[str] | None = None
) -> None:
    """What the settings' types cannot say until the arm is known; raises :class:`ConfigError`.

    Every per-joint list (``smc.*``, ``mpc.*``) must have one value per joint; the GP's
    ``theta0`` (d + 2 values), ``input_scale`` (d) and ``output_scale`` (1 or n) must fit
    the d GP inputs (:func:`gp_inputs`) of each GP controller among ``controllers`` (default:
    every registered controller; the section is shared) on the arm's n joints; ``plant.friction`` and
    the joint friction model (``friction``) must suit the RK4 step on this arm
    (:class:`~hydroarm.model.arm.plant.UnderwaterPlant` checks it); a task from settings or a file
    must be readable and have the arm's joint count. Nothing is run (with friction or a
    real-loop setting, the plant is built: about a millisecond).
    """
    n = arm.n_joints
    try:
        check_joint_counts(config, n)
        for name in registry.declared_settings():  # the sections registered controllers declare
            check_joint_counts(config.section(name), n, f"{name}.")
        if config.task.kind != "arm":  # the task's joint count, its file
            reference_for(config.task, arm)
        real_loop = any(getattr(config, s) != type(getattr(config, s))() for s in REAL_LOOP_SECTIONS)
        if config.plant.friction > 0.0 or real_loop:
            make_plant(arm, config)
    except ConfigError as error:
        raise ConfigError(f"{source}: {error}") from None
    gp = config.gp
    for controller in registry.controller_names() if controllers is None else controllers:
        found = gp_inputs(controller, config, n)
        if found is None:
            continue
        d, why = found
        for name, problem in gp.size_problems(d, n).items():
            inputs = f"{why} gives d = {d} GP inputs on {n} joints"
            raise ConfigError(f"{source}: gp.{name} = {shown(getattr(gp, name))}: {problem} ({inputs})")


def make_plant(arm: Arm, config: ExperimentConfig) -> UnderwaterPlant:
    """The true plant of ``config`` on ``arm``: water, integration, friction, sensor and drives."""
    return UnderwaterPlant(arm, config.water, config.plant, config.friction, config.sensor, config.actuator)


def build_controller(name: str, arm: Arm, config: ExperimentConfig) -> Controller:
    """The controller ``name`` (any spelling of :data:`~hydroarm.control.registry.CONTROLLERS`)
    on ``arm`` with the experiment's settings and its one control period; its state estimator is
    told the plant's sensor (encoder-only or not, its noise and quantum) and the loop delay
    (``sensor.delay + actuator.delay`` periods)."""
    sections = controller_settings(config)
    return registry.build_controller(
        name,
        arm.with_torque_limit(config.torque_limit),
        sections,
        config.control_period,
        sensor_variance=config.plant.noise_variance,
        sensor=config.sensor,
        loop_delay=config.sensor.delay + config.actuator.delay,
        actuator=config.actuator,
        friction=config.friction,
    )


def start_for_arm(arm: Arm, config: ExperimentConfig) -> tuple[SinusoidReference | SplineReference, np.ndarray]:
    """The reference and the start state (2n,) of a run of ``config`` on ``arm``: the task of
    ``config.task`` (:func:`~hydroarm.model.task.task_file.reference_for`; default the arm's,
    :func:`~hydroarm.model.task.references.task_for_arm`), moved by ``config.initial_state``
    (:class:`InitialState`)."""
    reference, x0 = reference_for(config.task, arm)
    return reference, config.initial_state.apply(x0)


@dataclass
class Experiment:
    """A closed loop ready to run: what :func:`build_experiment` returns.

    ``arm``: the arm the controller knows; ``plant``: the true plant (its arm may differ:
    a mismatch study); ``controller`` (canonical ``controller.name``; None when the torques
    come from outside, e.g. the Gymnasium env); ``reference``: the task on this arm; ``x0``
    (``plant.state_size``,): the start state; ``config``: the settings; ``uvms``: the floating
    system of a vehicle run (``config.vehicle.name`` set), else None.
    """

    config: ExperimentConfig
    arm: Arm
    plant: Plant
    controller: Controller | None
    reference: Reference
    x0: np.ndarray
    uvms: UVMS | None = None

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
        traj.meta["settings"] = self.config.canonical()
        traj.meta["schema"] = SCHEMA  # the settings' schema version (read back with run_settings)
        traj.meta["digest"] = self.config.digest()
        traj.meta["arm"] = self.config.arm
        if self.uvms is not None:
            vehicle = self.config.vehicle
            arm = self.uvms.vehicle.mount_arm if self.config.arm == "mount" else self.config.arm
            traj.meta["arm"] = source_name(arm)
            traj.meta["vehicle"] = source_name(vehicle.name)
            traj.meta["target_pose"] = self.x0[self.uvms.layout.base_pose].tolist()
            traj.meta["metrics"] = station_keeping_metrics(self.uvms, traj, self.reference)
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
    a different arm for the true plant only (default: ``arm`` perturbed by ``config.mismatch``,
    :func:`~hydroarm.sim.mismatch.perturbed_arm`). The settings are checked
    against the arm first (:func:`check_settings_for_arm`); the reference and start are
    :func:`start_for_arm`'s.

    With ``config.vehicle.name`` set, the arm is mounted on that vehicle
    (:mod:`hydroarm.sim.vehicle`): the plant is the floating system's, the controller the
    named arm controller on the mounted arm inside the whole system's
    :class:`~hydroarm.control.uvms_control.UVMSController`, the reference the arm's
    reach-and-return task, the start the vehicle level at the origin with the arm at home.
    """
    if config.vehicle.name is not None:
        return _build_vehicle_experiment(config, controller, arm)
    arm = (load_arm(config.arm) if arm is None else arm).with_torque_limit(config.torque_limit)
    check_settings_for_arm(config, arm, controllers=() if controller is None else (controller,))
    plant = make_plant(perturbed_arm(arm, config.mismatch) if plant_arm is None else plant_arm, config)
    reference, x0 = start_for_arm(arm, config)
    built = None if controller is None else build_controller(controller, arm, config)
    return Experiment(config, arm, plant, built, reference, x0)


def _build_vehicle_experiment(config: ExperimentConfig, controller: str | None, arm: Arm | None) -> Experiment:
    """:func:`build_experiment` for a vehicle run; fixed-base settings are refused (:func:`check_vehicle_settings`)."""
    check_vehicle_settings(config)
    parts = vehicle_parts(config.vehicle, config.arm if arm is None else arm, config.water, config.torque_limit)
    check_settings_for_arm(config, parts.arm, controllers=() if controller is None else (controller,))
    built = None
    if controller is not None:
        # the floating plant gives its true state: an estimator set to "plant" passes it through
        arm_controller = registry.build_controller(
            controller, parts.arm, controller_settings(config), config.control_period, sensor_variance=0.0
        )
        built = station_keeper(config.vehicle, parts, arm_controller, config.control_period)
    return Experiment(config, parts.arm, parts.plant, built, parts.reference, parts.x0, uvms=parts.uvms)


def run_experiment(
    config: ExperimentConfig,
    controller: str,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
) -> Trajectory:
    """Run ``controller`` (any spelling) on the true plant of ``config`` along the arm's task
    (:func:`~hydroarm.model.task.references.task_for_arm`) from :func:`start_for_arm`'s state;
    ``seed`` drives the measurement noise. See :func:`build_experiment`."""
    return build_experiment(config, controller).run(seed, progress)
