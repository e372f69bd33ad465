"""One experiment as validated data: arm, water, plant, task, controller settings, seed.

``ExperimentConfig`` is what a TOML file (``--config``) and ``--set key=value``
overrides describe; :func:`run_experiment` builds the arm, the plant and the
controller from it and runs the closed loop. The control period is set once
here and passed to every controller.
"""

from __future__ import annotations

import hashlib
import json

import numpy as np
from collections.abc import Callable
from typing import Any, Literal

import pydantic

from hydroarm.arm import Arm, load_arm
from hydroarm.config import ConfigError, FrozenModel, validate
from hydroarm.gp import GPConfig
from hydroarm.gpmpc import GPMPC, GPMPCConfig
from hydroarm.mpc import LinearMPC, MPCConfig
from hydroarm.plant import PlantConfig, UnderwaterPlant
from hydroarm.simulate import Trajectory, run_closed_loop
from hydroarm.smc import SlidingModeController, SMCConfig
from hydroarm.task import SinusoidReference, paper_reference
from hydroarm.water import Water

ControllerName = Literal["SMC", "MPC", "GP-MPC"]
CONTROLLERS: tuple[str, ...] = ("SMC", "MPC", "GP-MPC")


class ExperimentConfig(FrozenModel):
    """Everything that defines one closed-loop run (SPEC defaults)."""

    arm: str = "paper"
    duration: float = pydantic.Field(10.0, gt=0.0, le=3600.0, description="s")
    control_period: float = pydantic.Field(0.01, gt=0.0, le=1.0, description="T (s), for every controller")
    water: Water = Water()
    plant: PlantConfig = PlantConfig()
    smc: SMCConfig = SMCConfig()
    mpc: MPCConfig = MPCConfig()
    gp: GPConfig = GPConfig()
    gpmpc: GPMPCConfig = GPMPCConfig()

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


def run_experiment(
    config: ExperimentConfig,
    controller: str,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
) -> Trajectory:
    """Run ``controller`` on the true plant of ``config`` along the paper task
    (scaled to the arm's joint limits for other arms: :func:`task_for_arm`).

    ``seed`` drives the measurement noise; the trajectory's ``meta`` records the
    settings and their digest.
    """
    arm = load_arm(config.arm)
    plant = UnderwaterPlant(arm, config.water, config.plant)
    reference, x0 = task_for_arm(arm)
    controller_object = build_controller(controller, arm, config)
    traj = run_closed_loop(plant, controller_object, reference, config.duration, seed, x0=x0, progress=progress)
    traj.meta["settings"] = config.model_dump(mode="json")
    traj.meta["digest"] = config.digest()
    traj.meta["arm"] = config.arm
    return traj
