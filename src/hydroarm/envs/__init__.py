"""Gymnasium environments of hydroarm (``pip install hydroarm[gym]``).

Importing this package registers ``hydroarm/UnderwaterArm-v0`` (and ``hydroarm/UVMS-v0``,
:mod:`hydroarm.envs.vehicle`: a vehicle holding station under its working arm) with Gymnasium by a
string entry point (the environment's module is imported only when an environment is
made). ``import hydroarm`` does not import it, nor Gymnasium. Gymnasium 1.x has no
plugin discovery (it reads no package entry points), so name the module in the id to
have Gymnasium import it, or import it yourself::

    import gymnasium

    env = gymnasium.make("hydroarm.envs:hydroarm/UnderwaterArm-v0", arm="alpha5")

    import hydroarm.envs

    gymnasium.register_envs(hydroarm.envs)  # a no-op that shows the import is used
    env = gymnasium.make("hydroarm/UnderwaterArm-v0", arm="alpha5")

:func:`register` does the registration again if needed (idempotent). The environment
and :class:`~hydroarm.envs.underwater_arm.ControllerPolicy` are documented in
:mod:`hydroarm.envs.underwater_arm`. Both ids name :mod:`hydroarm.envs.vector`'s
:class:`~hydroarm.envs.vector.WorkerVectorEnv` as their ``vector_entry_point``:
``gymnasium.make_vec("hydroarm/UnderwaterArm-v0", num_envs=8)`` runs the 8 copies on as many
worker processes as there are cores. ``hydroarm/UnderwaterArmBatched-v0`` is the arm env on the
compiled plant: ``gymnasium.make_vec("hydroarm/UnderwaterArmBatched-v0", num_envs=64,
vectorization_mode="vector_entry_point")`` gives :class:`~hydroarm.envs.batched.BatchedArmVectorEnv`
(every copy's control period in one compiled call), ``gymnasium.make`` of it one such copy.
"""

from __future__ import annotations

import importlib
from typing import Any

ENV_ID = "hydroarm/UnderwaterArm-v0"
ENTRY_POINT = "hydroarm.envs.underwater_arm:UnderwaterArmEnv"
UVMS_ENV_ID = "hydroarm/UVMS-v0"
UVMS_ENTRY_POINT = "hydroarm.envs.vehicle:UVMSEnv"
VECTOR_ENTRY_POINT = "hydroarm.envs.vector:make_arm_vector_env"
UVMS_VECTOR_ENTRY_POINT = "hydroarm.envs.vector:make_uvms_vector_env"
BATCHED_ENV_ID = "hydroarm/UnderwaterArmBatched-v0"
BATCHED_ENTRY_POINT = "hydroarm.envs.batched:make_compiled_arm_env"
BATCHED_VECTOR_ENTRY_POINT = "hydroarm.envs.batched:make_batched_arm_vector_env"

__all__ = ["BATCHED_ENV_ID", "ENV_ID", "UVMS_ENV_ID", "ControllerPolicy", "UnderwaterArmEnv", "register"]


def register() -> None:
    """Register ``hydroarm/UnderwaterArm-v0`` with Gymnasium (idempotent; imports Gymnasium,
    not the environment's module)."""
    try:
        import gymnasium
    except ImportError as error:  # pragma: no cover - depends on the environment
        raise ImportError("hydroarm.envs needs Gymnasium: pip install 'hydroarm[gym]'") from error
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(id=ENV_ID, entry_point=ENTRY_POINT, vector_entry_point=VECTOR_ENTRY_POINT)
    if UVMS_ENV_ID not in gymnasium.registry:
        gymnasium.register(id=UVMS_ENV_ID, entry_point=UVMS_ENTRY_POINT, vector_entry_point=UVMS_VECTOR_ENTRY_POINT)
    if BATCHED_ENV_ID not in gymnasium.registry:
        gymnasium.register(id=BATCHED_ENV_ID, entry_point=BATCHED_ENTRY_POINT,
                           vector_entry_point=BATCHED_VECTOR_ENTRY_POINT)  # fmt: skip


def __getattr__(name: str) -> Any:
    """``UnderwaterArmEnv`` and ``ControllerPolicy``, imported on first use (PEP 562)."""
    if name in ("UnderwaterArmEnv", "ControllerPolicy"):
        value = getattr(importlib.import_module("hydroarm.envs.underwater_arm"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'hydroarm.envs' has no attribute {name!r}")


register()
