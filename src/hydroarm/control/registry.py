"""One registry of controllers for the CLI, the Python API, sweeps and the Gymnasium env.

Every controller has a canonical name (``"SMC"``, ``"MPC"``, ``"GP-MPC"``), the config
sections it reads, and a builder. Names are matched case-insensitively, with ``_`` and
``-`` alike: ``"gp-mpc"``, ``"GP_MPC"`` and ``"GP-MPC"`` are one controller.

To add a controller: write it in :mod:`hydroarm.control` with the
:class:`~hydroarm.control.interface.Controller` interface and a config model, then add one
:class:`ControllerSpec` to :data:`REGISTRY` (and its config section to
:class:`~hydroarm.sim.experiment.ExperimentConfig`). From outside the package: :func:`register`
a spec that declares its own section (``settings={"toy": ToyConfig}``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import pydantic

from hydroarm.config import ConfigError, per_joint
from hydroarm.control.delay_design import delayed_observer_gain
from hydroarm.control.drive_limits import DrivesTold
from hydroarm.control.estimator import EstimatorConfig, FilteredController, JointKalmanFilter
from hydroarm.control.friction_feedforward import FrictionFeedforward, told_friction
from hydroarm.control.gpmpc import GPMPC, feature_size
from hydroarm.control.idmpc import InverseDynamicsMPC, gp_input_size
from hydroarm.control.interface import Controller
from hydroarm.control.mpc import LinearMPC
from hydroarm.control.observers import DisturbanceObserver, ObservedController
from hydroarm.control.pi_idmpc import PhysicsInformedIDMPC
from hydroarm.control.smc import SlidingModeController
from hydroarm.model.arm.description import Arm
from hydroarm.model.dynamics.nominal import NominalModel
from hydroarm.model.real_loop.friction import FrictionConfig
from hydroarm.model.real_loop.sensing import ActuatorConfig, SensorConfig


@dataclass(frozen=True)
class ControllerSpec:
    """A controller of the registry, declared once: its canonical ``name``, the config
    ``sections`` it reads (keys of the ``sections`` mapping :func:`build_controller` takes;
    every controller also reads ``estimator``), a one-line ``description`` (the CLI's help),
    its ``build(arm, sections, control_period)``, the state estimator it uses when
    ``estimator.kind = "auto"``; ``observer``: it can run over a disturbance observer (reads
    the ``observer`` section, :mod:`hydroarm.control.observers`); ``gp_inputs(sections,
    n_joints) -> (d, why)``: the input count of its GP on n joints and the setting that decides
    it (None: no GP); ``tuning_grid``: the gains ``hydroarm tune`` searches (dotted setting ->
    values)."""

    name: str
    sections: tuple[str, ...]
    description: str
    build: Callable[[Arm, Mapping[str, Any], float], Controller]
    default_estimator: str = "none"
    observer: bool = False
    gp_inputs: Callable[[Mapping[str, Any], int], tuple[int, str]] | None = None
    tuning_grid: Mapping[str, Sequence[Any]] = field(default_factory=dict)
    settings: Mapping[str, type[pydantic.BaseModel]] = field(default_factory=dict)
    """Settings sections the controller declares, section name -> its config model (a frozen
    pydantic model with a default for every field): a controller registered from outside
    hydroarm brings its own section; the run's settings then take it (``--set toy.kp=400``,
    ``[toy]`` in a settings file), validate it, list it (``hydroarm settings``) and hand it to
    ``build`` as ``sections[name]``. Its names join ``sections`` (:func:`register`)."""


def _smc(arm: Arm, sections: Mapping[str, Any], period: float) -> Controller:
    return SlidingModeController(arm, sections["smc"], control_period=period)


def _mpc(arm: Arm, sections: Mapping[str, Any], period: float) -> Controller:
    return LinearMPC(arm, sections["mpc"], control_period=period)


def _gpmpc(arm: Arm, sections: Mapping[str, Any], period: float) -> Controller:
    return GPMPC(arm, LinearMPC(arm, sections["mpc"], control_period=period), sections["gp"], sections["gpmpc"])


def _idmpc(arm: Arm, sections: Mapping[str, Any], period: float) -> Controller:
    return InverseDynamicsMPC(arm, sections["idmpc"], control_period=period)


def _gp_idmpc(arm: Arm, sections: Mapping[str, Any], period: float) -> Controller:
    return InverseDynamicsMPC(arm, sections["idmpc"], control_period=period, gp_config=sections["gp"])


def _pi_idmpc(arm: Arm, sections: Mapping[str, Any], period: float) -> Controller:
    return PhysicsInformedIDMPC(
        arm, sections["idmpc"], sections["water_model"], control_period=period, planner_config=sections["pi_idmpc"]
    )


def _gpmpc_inputs(sections: Mapping[str, Any], n: int) -> tuple[int, str]:
    features = sections["gpmpc"].features
    return feature_size(features, n), f"GP-MPC: gpmpc.features = '{features}'"


def _gp_idmpc_inputs(sections: Mapping[str, Any], n: int) -> tuple[int, str]:
    features = sections["idmpc"].gp_features
    return gp_input_size(features, n), f"GP-IDMPC: idmpc.gp_features = '{features}'"


_SMC_GRID = {
    "smc.surface_slope": [10.0, 20.0, 40.0],
    "smc.switching_gain": [50.0, 200.0, 800.0],
    "smc.boundary_layer": [0.5, 2.0],
    "smc.linear_gain": [0.0, 10.0, 30.0],
}
_MPC_GRID = {"mpc.r": [1e-1, 1e-2, 1e-3, 1e-4, 1e-5], "mpc.q_velocity": [0.01, 1.0]}
_IDMPC_GRID = {"idmpc.r_acceleration": [1e-4, 1e-5, 1e-6], "idmpc.q_velocity": [0.01, 0.1, 1.0]}

REGISTRY: dict[str, ControllerSpec] = {
    spec.name: spec
    for spec in (
        ControllerSpec(
            "SMC",
            ("smc", "observer"),
            "boundary-layer sliding-mode computed torque on the dry model",
            _smc,
            observer=True,
            tuning_grid=_SMC_GRID,
        ),
        ControllerSpec(
            "MPC",
            ("mpc", "observer"),
            "linear time-varying MPC about the reference (the paper's)",
            _mpc,
            observer=True,
            tuning_grid=_MPC_GRID,
        ),
        ControllerSpec(
            "GP-MPC",
            ("mpc", "gp", "gpmpc"),
            "the paper's MPC with a sliding-window GP disturbance model",
            _gpmpc,
            gp_inputs=_gpmpc_inputs,
            tuning_grid=_MPC_GRID,  # on land the GP has nothing to learn: its MPC is tuned as the MPC
        ),
        ControllerSpec(
            "IDMPC",
            ("idmpc", "observer"),
            "hydroarm's inverse-dynamics MPC (acceleration-space MPC + computed torque)",
            _idmpc,
            default_estimator="kalman",
            observer=True,
            tuning_grid=_IDMPC_GRID,
        ),
        ControllerSpec(
            "GP-IDMPC",
            ("idmpc", "gp"),
            "the inverse-dynamics MPC with the sliding-window GP fed forward",
            _gp_idmpc,
            default_estimator="kalman",
            gp_inputs=_gp_idmpc_inputs,
            tuning_grid=_IDMPC_GRID,
        ),
        ControllerSpec(
            "PI-IDMPC",
            ("idmpc", "water_model", "pi_idmpc"),
            "the inverse-dynamics MPC with a physics-informed water model along the horizon + an observer on the rest",
            _pi_idmpc,
            default_estimator="kalman",
            tuning_grid=_IDMPC_GRID,  # on land the water model has nothing to learn either
        ),
    )
}

RATE_AWARE: tuple[str, ...] = ("IDMPC", "GP-IDMPC", "PI-IDMPC")
"""The controllers that take the drives' rate limit (``drive_limits``: the ID-MPCs)."""

CONTROLLERS: tuple[str, ...] = tuple(REGISTRY)
"""The built-in controllers' canonical names, in the order tables show them (every registered
one, including those added by :func:`register`: :func:`controller_names`)."""


def register(spec: ControllerSpec) -> ControllerSpec:
    """Add ``spec`` to the registry: the builder, ``run``, sweeps, ``tune`` and the env then
    know it by its name (either spelling). Raises :class:`ConfigError` if a controller of that
    name (either spelling) is registered already."""
    key = _key(spec.name)
    taken = [name for name in (*REGISTRY, *ALIASES) if _key(name) == key]
    if taken:
        raise ConfigError(f"controller {spec.name!r}: a controller of that name is registered already ({taken[0]})")
    for section, model in spec.settings.items():
        held = declared_settings().get(section)
        if held is not None and held is not model:
            raise ConfigError(f"controller {spec.name!r}: settings section {section!r} is declared already ({held})")
    extra = tuple(section for section in spec.settings if section not in spec.sections)
    spec = dataclasses.replace(spec, sections=(*spec.sections, *extra)) if extra else spec
    REGISTRY[spec.name] = spec
    return spec


def declared_settings() -> dict[str, type[pydantic.BaseModel]]:
    """The settings sections registered controllers declare (:attr:`ControllerSpec.settings`):
    section name -> config model."""
    return {section: model for spec in REGISTRY.values() for section, model in spec.settings.items()}


def controller_names() -> tuple[str, ...]:
    """Every registered controller's canonical name, the built-ins first."""
    return tuple(REGISTRY)


def settings_read_by(name: str) -> tuple[str, ...]:
    """The config sections controller ``name`` (either spelling) reads: its own and ``estimator``."""
    return (*controller_spec(name).sections, "estimator")


def controller_sections() -> tuple[str, ...]:
    """Every config section some registered controller reads (and ``estimator``), in order."""
    found: list[str] = []
    for spec in REGISTRY.values():
        found.extend(section for section in spec.sections if section not in found)
    return (*found, "estimator")


PAPER_CONTROLLERS: tuple[str, ...] = ("SMC", "MPC", "GP-MPC")
"""The controllers of Liu et al. 2023's tables (the reproduction's rows)."""


ALIASES: dict[str, str] = {"flagship": "GP-IDMPC"}
"""Stable names for registered controllers: ``flagship`` means the controller hydroarm recommends,
the most accurate one that keeps its control period (docs/controllers.md, "Which controller to
pick": GP-IDMPC; PI-IDMPC tracks better in the ideal loop but its replanning steps still miss the
period, bench.json ``planner``), so scripts and papers that name it keep working as it improves.
:func:`canonical_name` resolves them."""


def _key(name: str) -> str:
    return name.strip().upper().replace("_", "-")


def canonical_name(name: str) -> str:
    """The canonical name of controller ``name`` (either spelling, or an alias of :data:`ALIASES`);
    raises :class:`ConfigError` naming the allowed names otherwise."""
    if isinstance(name, str):
        key = _key(name)
        for alias, target in ALIASES.items():
            if _key(alias) == key:
                return target
        for canonical in REGISTRY:
            if _key(canonical) == key:
                return canonical
    allowed = ", ".join([*(f"{c} ({c.lower()})" for c in REGISTRY), *(f"{a} (= {t})" for a, t in ALIASES.items())])
    raise ConfigError(f"controller = {name!r}: must be one of {allowed}")


def controller_spec(name: str) -> ControllerSpec:
    """The :class:`ControllerSpec` of controller ``name`` (either spelling)."""
    return REGISTRY[canonical_name(name)]


def estimator_kind(
    name: str, estimator: EstimatorConfig | None, sensor: SensorConfig | None = None, loop_delay: int = 0
) -> str:
    """``"none"`` or ``"kalman"``: the estimator controller ``name`` runs behind (``"auto"``:
    :meth:`EstimatorConfig.resolved_kind`, the filter behind a non-ideal sensor or a loop delay,
    else the controller's default)."""
    config = EstimatorConfig() if estimator is None else estimator
    return config.resolved_kind(controller_spec(name).default_estimator, sensor, loop_delay)


def told_loop_delay(sections: Mapping[str, Any], delay: int) -> Mapping[str, Any]:
    """``sections`` told the loop delay ``delay`` (periods): the one the state estimator predicts
    across (0 without one: nothing tells the controller of a delay). ``idmpc.loop_delay =
    "plant"`` is resolved to it (the ID-MPCs' bandwidth is designed for it), and with d > 0
    PI-IDMPC's remainder observer (``water_model.remainder``) runs as an NDOB of gain at most
    :func:`~hydroarm.control.delay_design.delayed_observer_gain` (d) (its TDE is the NDOB of
    gain 1: the fastest-settling gain without delay)."""
    told = dict(sections)
    idmpc = sections.get("idmpc")
    if idmpc is not None and idmpc.loop_delay == "plant":
        told["idmpc"] = idmpc.model_copy(update={"loop_delay": int(delay)})
    water_model = sections.get("water_model")
    if water_model is not None and delay > 0 and water_model.remainder.kind != "none":
        remainder = water_model.remainder  # PI-IDMPC's observer on what its model leaves: L capped at L*(d)
        gain = min(1.0 if remainder.kind == "tde" else remainder.gain, delayed_observer_gain(delay))
        remainder = remainder.model_copy(update={"kind": "ndob", "gain": gain})  # NDOB with L = 1 is the TDE
        told["water_model"] = water_model.model_copy(update={"remainder": remainder})
    return told


def build_controller(
    name: str,
    arm: Arm,
    sections: Mapping[str, Any],
    control_period: float,
    sensor_variance: float | None = None,
    sensor: SensorConfig | None = None,
    loop_delay: int = 0,
    actuator: ActuatorConfig | None = None,
    friction: FrictionConfig | None = None,
) -> Controller:
    """Controller ``name`` on ``arm`` from its config ``sections`` (section name -> config
    model, e.g. ``{"mpc": MPCConfig()}``) with the control period (s), behind the state
    estimator of ``sections["estimator"]`` (an :class:`EstimatorConfig`; absent = ``auto``).

    With ``sections["observer"]`` (an :class:`~hydroarm.control.observers.ObserverConfig`) of
    a kind other than ``"none"``, the controller runs over that disturbance observer
    (:class:`ObservedController`), inside the estimator: the observer sees the filtered state.

    ``sensor_variance``: the measurement-noise variance of the plant it will run on (rad^2),
    what ``estimator.measurement_variance = "plant"`` stands for; needed only then. ``sensor``:
    the plant's sensor (None: q and v measured) and ``loop_delay`` (periods, ``sensor.delay +
    actuator.delay``): what ``estimator.measures`` and ``estimator.delay = "plant"`` stand for;
    ``actuator``: the drives (their clip, lag and rate limit go into the filter's prediction, and
    a controller with ``drive_limits`` (the ID-MPCs) is told their rate limit every step, from the
    filter's copy of the drives or, without a filter, from :class:`DrivesTold`'s);
    ``friction``: the arm's joint friction model (the ``friction`` section), fed forward under an
    ID-MPC at the scale ``idmpc.friction_feedforward`` tells it
    (:class:`~hydroarm.control.friction_feedforward.FrictionFeedforward`; never the plant's scale)."""
    spec = controller_spec(name)
    estimator = sections.get("estimator")
    filtered = estimator_kind(spec.name, estimator, sensor, loop_delay) == "kalman"
    config = estimator if estimator is not None else EstimatorConfig()
    design = config.design(sensor_variance, sensor, loop_delay) if filtered else None  # "plant": noise, quantum
    controller = spec.build(arm, told_loop_delay(sections, design.delay if filtered else 0), control_period)
    observer = sections.get("observer")
    if observer is not None and observer.kind != "none":
        if not spec.observer:
            takes = ", ".join(c for c, s in REGISTRY.items() if s.observer)
            raise ConfigError(
                f"observer.kind = {observer.kind!r}: {spec.name} learns the disturbance itself; "
                f"an observer runs under {takes} (or set observer.kind = 'none')"
            )
        controller = ObservedController(controller, DisturbanceObserver(arm, control_period, observer), arm)
    idmpc = sections.get("idmpc") if "idmpc" in spec.sections else None
    told = told_friction(friction, idmpc.friction_feedforward) if idmpc is not None else None
    if told is not None:
        limit = per_joint(arm.torque_limit, arm.n_joints, "torque_limit")
        controller = FrictionFeedforward(controller, told, arm.n_joints, limit)
    if not filtered and actuator is not None and actuator.rate_limit is not None and spec.name in RATE_AWARE:
        controller = DrivesTold(controller, actuator, arm.n_joints, control_period)  # told without the filter's copy
    if filtered:
        if sensor_variance is not None:
            config = config.for_sensor(sensor_variance)
        kalman = JointKalmanFilter(arm.n_joints, control_period, config, design)
        controller = FilteredController(controller, kalman, NominalModel(arm, inner_step=None), actuator)
    return controller
