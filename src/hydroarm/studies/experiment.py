"""One experiment as validated data: arm, water, plant, task, controller settings, seed.

``ExperimentConfig`` is what a TOML file (``--config``) and ``--set key=value``
overrides describe; :func:`run_experiment` builds the arm, the plant and the
controller from it and runs the closed loop from the task's start (moved by
a seeded draw if ``initial_state`` asks for it). The control period is set once
here and passed to every controller.
"""

from __future__ import annotations

import hashlib
import json

import numpy as np
from collections.abc import Callable
from typing import Any, Literal

import pydantic

from hydroarm.model.arm import Arm, load_arm
from hydroarm.config import ConfigError, FrozenModel, check_joint_counts, shown, validate
from hydroarm.control.gp import GPConfig
from hydroarm.control.gpmpc import GPMPC, GPMPCConfig, feature_size
from hydroarm.control.mpc import LinearMPC, MPCConfig
from hydroarm.model.plant import PlantConfig, UnderwaterPlant
from hydroarm.studies.runner import Trajectory, run_closed_loop
from hydroarm.control.smc import SlidingModeController, SMCConfig
from hydroarm.model.task import SinusoidReference, paper_reference
from hydroarm.model.water import Water

MAX_CONTROL_STEPS = 1_000_000
"""Most control steps of one run (duration / control_period): every step's row is stored."""

ControllerName = Literal["SMC", "MPC", "GP-MPC"]
CONTROLLERS: tuple[str, ...] = ("SMC", "MPC", "GP-MPC")

CONTROLLER_SECTIONS: tuple[str, ...] = ("smc", "mpc", "gp", "gpmpc")
"""The sections of :class:`ExperimentConfig` that only controllers read."""

CONTROLLER_SETTINGS: dict[str, tuple[str, ...]] = {
    "SMC": ("smc",),
    "MPC": ("mpc",),
    "GP-MPC": ("mpc", "gp", "gpmpc"),
}
"""The controller sections each controller reads in :func:`build_controller` (keep the
two in step): a sweep leaves the other sections out of a run's id, so sweeping
``mpc.r`` runs SMC once."""


class InitialState(FrozenModel):
    """Where a run starts: the task's start x0 (:func:`task_for_arm`) plus a seeded uniform draw.

    Joint i starts at ``q0_i + U(-position_spread, position_spread)`` (rad) and
    ``v0_i + U(-velocity_spread, velocity_spread)`` (rad/s), drawn from
    ``numpy.random.default_rng(seed)`` (the n positions, then the n velocities).
    With both spreads 0 (the default) the start is x0 exactly and nothing is
    drawn. The draw is not clipped to joint limits. ``seed`` is independent of
    the measurement-noise seed of the run.
    """

    position_spread: float = pydantic.Field(0.0, ge=0.0, le=10.0, description="rad")
    velocity_spread: float = pydantic.Field(0.0, ge=0.0, le=100.0, description="rad/s")
    seed: int = pydantic.Field(0, ge=0, le=2**63 - 1)

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
    the task's start exactly, see :class:`InitialState`).
    """

    arm: str = "paper"
    duration: float = pydantic.Field(10.0, gt=0.0, le=3600.0, description="s")
    control_period: float = pydantic.Field(0.01, ge=1e-4, le=1.0, description="T (s), for every controller")
    water: Water = Water()
    plant: PlantConfig = PlantConfig()
    smc: SMCConfig = SMCConfig()
    mpc: MPCConfig = MPCConfig()
    gp: GPConfig = GPConfig()
    gpmpc: GPMPCConfig = GPMPCConfig()
    initial_state: InitialState = InitialState()

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
                raise ConfigError(f"unknown setting '{key}'")
            target = target[part]
        if not isinstance(target, dict) or parts[-1] not in target:
            raise ConfigError(f"unknown setting '{key}'")
        target[parts[-1]] = value
    return validate(ExperimentConfig, data, "settings")


def check_settings_for_arm(config: ExperimentConfig, arm: Arm, source: str = "settings") -> None:
    """What the settings' types cannot say until the arm is known; raises :class:`ConfigError`.

    Every per-joint list (``smc.*``, ``mpc.*``) must have one value per joint; the GP's
    ``theta0`` (d + 2 values), ``input_scale`` (d) and ``output_scale`` (1 or n) must fit
    the d GP inputs of ``gpmpc.features`` on the arm's n joints; ``plant.friction`` must
    suit the RK4 step on this arm (:class:`~hydroarm.model.plant.UnderwaterPlant` checks it).
    Nothing is run (with friction, the plant is built: about a millisecond).
    """
    n = arm.n_joints
    try:
        check_joint_counts(config, n)
        if config.plant.friction > 0.0:
            UnderwaterPlant(arm, config.water, config.plant)
    except ConfigError as error:
        raise ConfigError(f"{source}: {error}") from None
    gp = config.gp
    d = feature_size(config.gpmpc.features, n)
    inputs = f"gpmpc.features = '{config.gpmpc.features}' gives d = {d} GP inputs on {n} joints"
    for name, value, allowed in (
        ("theta0", gp.theta0, (d + 2,)),
        ("input_scale", gp.input_scale, (d,)),
        ("output_scale", gp.output_scale, (1, n)),
    ):
        if value is not None and len(value) not in allowed:
            wanted = " or ".join(str(k) for k in allowed)
            raise ConfigError(f"{source}: gp.{name} = {shown(value)}: {len(value)} values: give {wanted} ({inputs})")


def build_controller(name: str, arm: Arm, config: ExperimentConfig):
    """The controller ``name`` (SMC, MPC, GP-MPC) on ``arm`` with the experiment's settings."""
    period = {"control_period": config.control_period}
    if name == "SMC":
        return SlidingModeController(arm, config.smc.model_copy(update=period))
    mpc = LinearMPC(arm, config.mpc.model_copy(update=period))
    if name == "MPC":
        return mpc
    if name == "GP-MPC":
        return GPMPC(arm, mpc, config.gp, config.gpmpc)
    raise ConfigError(f"controller '{name}': must be one of {', '.join(CONTROLLERS)}")


def task_for_arm(arm: Arm) -> tuple[SinusoidReference, np.ndarray]:
    """The reference and the initial state (2n,) for ``arm``.

    A 6-joint arm without position limits (the paper's, UR5) gets the paper
    task from rest at q = 0. Other arms get the same shape (joint i follows the
    paper's joint i mod 6), scaled so that it stays within 80 % of each joint's
    range around its middle, starting at rest at the middle. Velocity limits are
    not enforced by the plant; the scaled task is a tracking test, not a
    certified motion.
    """
    paper = paper_reference()
    n = arm.n_joints
    if n == 6 and arm.position_limit is None:
        return paper, np.zeros(12)
    rows = [i % 6 for i in range(n)]
    base = SinusoidReference(paper.offset[rows], paper.cos_amp[rows], paper.sin_amp[rows], paper.omega[rows])
    if arm.position_limit is None:
        return base, np.zeros(2 * n)
    limits = np.asarray(arm.position_limit, dtype=float)
    finite = np.all(np.isfinite(limits), axis=1)
    middle = np.where(finite, 0.5 * (limits[:, 0] + limits[:, 1]), 0.0)
    half = np.where(finite, 0.5 * (limits[:, 1] - limits[:, 0]), np.inf)
    amplitude = np.sum(np.abs(base.cos_amp) + np.abs(base.sin_amp), axis=1)
    scale = np.minimum(1.0, 0.8 * half / np.maximum(amplitude, 1e-12))
    return base.scaled(scale, offset=middle), np.concatenate([middle, np.zeros(n)])


def start_for_arm(arm: Arm, config: ExperimentConfig) -> tuple[SinusoidReference, np.ndarray]:
    """The reference and the start state (2n,) of a run of ``config`` on ``arm``:
    :func:`task_for_arm`'s, moved by ``config.initial_state`` (:class:`InitialState`)."""
    reference, x0 = task_for_arm(arm)
    return reference, config.initial_state.apply(x0)


def run_experiment(
    config: ExperimentConfig,
    controller: str,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
) -> Trajectory:
    """Run ``controller`` on the true plant of ``config`` along the paper task
    (scaled to the arm's joint limits for other arms: :func:`task_for_arm`),
    from the start of :func:`start_for_arm`.

    ``seed`` drives the measurement noise; the trajectory's ``meta`` records the
    settings and their digest.
    """
    arm = load_arm(config.arm)
    check_settings_for_arm(config, arm)
    plant = UnderwaterPlant(arm, config.water, config.plant)
    reference, x0 = start_for_arm(arm, config)
    controller_object = build_controller(controller, arm, config)
    traj = run_closed_loop(plant, controller_object, reference, config.duration, seed, x0=x0, progress=progress)
    traj.meta["settings"] = config.model_dump(mode="json")
    traj.meta["digest"] = config.digest()
    traj.meta["arm"] = config.arm
    return traj
