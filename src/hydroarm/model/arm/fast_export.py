"""The compiled arm plant's constants as plain NumPy arrays, for the JAX path
(:mod:`hydroarm.model.arm.fast_jax`, which imports nothing of hydroarm).

:func:`export_constants` reads them out of the compiled handle itself
(:class:`~hydroarm.model.arm.fast.FastArmDynamics`'s ``compiled``, a numba StructRef, and its
:class:`~hydroarm.model.water.strips.Strips`), so the JAX plant steps exactly what the numba kernels step:
the tree, the rigid and rigid + added inertias, the gravity, the strips' table, quadrature,
switches and current, the viscous and the joint friction.
"""

from __future__ import annotations

import numba
import numpy as np

from hydroarm.model.arm.fast import FastArmDynamics


@numba.njit(cache=True)
def _arm_fields(arm):  # pragma: no cover - compiled
    tree = (arm.parents, arm.place_rotation, arm.place_translation, arm.axes, arm.rigid, arm.total, arm.gravity)
    friction = (arm.coulomb, arm.breakaway, arm.viscous, arm.stribeck_velocity, arm.width)
    return (*tree, arm.uniform, arm.friction_on, *friction)


@numba.njit(cache=True)
def _strip_fields(arm):  # pragma: no cover - compiled
    s = arm.strips
    switches = np.array([int(s.drag), int(s.added_mass), int(s.buoyancy), int(s.axial), s.drag_model,
                         s.added_mass_model])  # fmt: skip
    return (s.joint_ids, s.start, s.axis, s.table, s.nodes, s.weights, switches, s.floating, s.current_joint,
            s.current_world)  # fmt: skip


ARM_KEYS = ("parents", "place_rotation", "place_translation", "axes", "rigid", "total", "gravity", "uniform",
            "friction_on", "coulomb", "breakaway", "viscous", "stribeck_velocity", "width")  # fmt: skip
STRIP_KEYS = ("joint_ids", "start", "axis", "table", "nodes", "weights", "switches", "floating", "current_joint",
              "current_world")  # fmt: skip


def export_constants(fast: FastArmDynamics) -> dict[str, np.ndarray]:
    """The constants of ``fast`` (:data:`hydroarm.model.arm.fast_jax.REQUIRED`, each a NumPy array,
    ``np.savez``-able; copies, not views of the compiled handle's arrays)."""
    values = dict(zip(ARM_KEYS, _arm_fields(fast.compiled), strict=True))
    values.update(zip(STRIP_KEYS, _strip_fields(fast.compiled), strict=True))
    return {key: np.array(value) for key, value in values.items()}


__all__ = ["export_constants"]
