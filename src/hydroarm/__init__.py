"""hydroarm: simulation and control of underwater robot manipulators.

Quick tour::

    import hydroarm
    arm = hydroarm.load_arm("paper")          # Liu et al. 2023's arm; also "ur5" or a file
    water = hydroarm.Water()                  # rho=1000, cd=1.0, cm=2.0
    w = hydroarm.hydrodynamic_torques(arm, water, q, v, a)
    plant = hydroarm.UnderwaterPlant(arm, water)
"""

from hydroarm.model.arm import Arm, ArmSpec, WettedCylinder
from hydroarm.model.loading import load_arm
from hydroarm.config import ConfigError
from hydroarm.model.nominal import NominalModel
from hydroarm.model.plant import PlantConfig, StepInfo, UnderwaterPlant
from hydroarm.model.task import SinusoidReference, paper_reference
from hydroarm.model.water import (
    CurrentConfig,
    HydroTorques,
    Water,
    WaterModel,
    added_mass_matrix,
    hydrodynamic_torques,
)

__all__ = [
    "Arm",
    "ArmSpec",
    "ConfigError",
    "CurrentConfig",
    "HydroTorques",
    "NominalModel",
    "PlantConfig",
    "SinusoidReference",
    "StepInfo",
    "UnderwaterPlant",
    "Water",
    "WaterModel",
    "WettedCylinder",
    "added_mass_matrix",
    "hydrodynamic_torques",
    "load_arm",
    "paper_reference",
]
__version__ = "0.1.0"

try:  # Gymnasium is optional (pip install hydroarm[gym])
    import gymnasium as _gymnasium  # noqa: F401
except ImportError:  # pragma: no cover - depends on the environment
    pass
else:
    from hydroarm.envs.underwater_arm import register as _register_env

    _register_env()
