"""hydroarm: simulation and control of underwater robot manipulators.

Quick tour::

    import hydroarm
    arm = hydroarm.load_arm("paper")               # Liu et al. 2023's arm; also "ur5", "alpha5" or a file
    plant = hydroarm.UnderwaterPlant(arm, hydroarm.Water())
    config = hydroarm.ExperimentConfig()           # validated settings (the defaults of docs/paper-reading.md)
    traj = hydroarm.run_experiment(config, "gp-mpc", seed=0)
    hydroarm.tracking_metrics(traj)["Ep"]          # E_p per joint (rad^2)

The package is layered (docs/architecture.md): :mod:`hydroarm.model` (arm, water, plant,
nominal model) <- :mod:`hydroarm.control` (GP, QP backends, MPC, GP-MPC, SMC, registry)
<- :mod:`hydroarm.sim` (experiment builder, runner, Trajectory) <- :mod:`hydroarm.studies`
(reproduce, sweep, figures) <- :mod:`hydroarm.envs` and :mod:`hydroarm.cli`. The names below are imported on first use,
so ``import hydroarm`` itself loads no controller, study or Gymnasium.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_EXPORTS: dict[str, str] = {
    # model
    "Arm": "hydroarm.model.arm.description",
    "ArmSpec": "hydroarm.model.arm.description",
    "WettedCylinder": "hydroarm.model.arm.description",
    "load_arm": "hydroarm.model.arm.loading",
    "arm_to_urdf": "hydroarm.model.arm.urdf_export",
    "CurrentConfig": "hydroarm.model.water.current",
    "Water": "hydroarm.model.water.morison",
    "WaterModel": "hydroarm.model.water.morison",
    "HydroTorques": "hydroarm.model.water.morison",
    "hydrodynamic_torques": "hydroarm.model.water.morison",
    "added_mass_matrix": "hydroarm.model.water.morison",
    "PlantConfig": "hydroarm.model.arm.plant",
    "StepInfo": "hydroarm.model.dynamics.integrator",
    "UnderwaterPlant": "hydroarm.model.arm.plant",
    "NominalModel": "hydroarm.model.dynamics.nominal",
    "SinusoidReference": "hydroarm.model.task.references",
    "paper_reference": "hydroarm.model.task.references",
    "task_for_arm": "hydroarm.model.task.references",
    "ConfigError": "hydroarm.config",
    # control
    "ControlOutput": "hydroarm.control.interface",
    "Controller": "hydroarm.control.interface",
    "CONTROLLERS": "hydroarm.control.registry",
    "SMCConfig": "hydroarm.control.smc",
    "SlidingModeController": "hydroarm.control.smc",
    "MPCConfig": "hydroarm.control.mpc",
    "LinearMPC": "hydroarm.control.mpc",
    "GPMPCConfig": "hydroarm.control.gpmpc",
    "GPMPC": "hydroarm.control.gpmpc",
    "GPConfig": "hydroarm.control.gp",
    "SlidingWindowGP": "hydroarm.control.gp",
    # sim
    "ExperimentConfig": "hydroarm.sim.experiment",
    "Experiment": "hydroarm.sim.experiment",
    "build_experiment": "hydroarm.sim.experiment",
    "build_controller": "hydroarm.sim.experiment",
    "run_experiment": "hydroarm.sim.experiment",
    "Trajectory": "hydroarm.sim.runner",
    "run_closed_loop": "hydroarm.sim.runner",
    "tracking_metrics": "hydroarm.sim.runner",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    """The public names, imported from their module on first use (PEP 562)."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'hydroarm' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
