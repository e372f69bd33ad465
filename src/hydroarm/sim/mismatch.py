"""The true plant's model mismatch: how its arm differs from the arm file the controllers know.

``ExperimentConfig.mismatch`` (:class:`Mismatch`) is a settings section like the others (a
settings file's ``[mismatch]``, ``hydroarm run --set mismatch.mass_scale=0.8``, a sweep's
``[mismatch]`` or swept ``mismatch.*`` keys), validated with its ranges;
:func:`~hydroarm.sim.experiment.build_experiment` builds the plant on :func:`perturbed_arm`.
At its defaults (no mismatch) it is left out of the settings' compact form, so run ids made
before it lived in the settings are unchanged (:mod:`hydroarm.sim.settings_schema`, schema 12).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pydantic

from hydroarm.config import FrozenModel
from hydroarm.model.arm.description import Arm

__all__ = ["Mismatch", "perturbed_arm"]


class Mismatch(FrozenModel):
    """How the true plant's rigid body differs from the arm file the controllers use.

    ``mass_scale``: every link's mass and rotational inertia (about its centre
    of gravity) times this factor, centres of gravity unchanged; ``payload_kg``:
    a point mass at the flange (DH arms) or at the last link's centre of gravity
    (URDF arms), in the plant only.
    """

    mass_scale: float = pydantic.Field(
        1.0, gt=0.0, le=100.0, description="factor on every link's mass and inertia, in the plant only (-)"
    )
    payload_kg: float = pydantic.Field(
        0.0, ge=0.0, le=1000.0, description="a point mass at the flange, in the plant only (kg)"
    )

    @property
    def is_identity(self) -> bool:
        return self.mass_scale == 1.0 and self.payload_kg == 0.0


def perturbed_arm(arm: Arm, mismatch: Mismatch) -> Arm:
    """The plant's arm: ``arm`` with its masses scaled and a payload added (see
    :class:`Mismatch`); ``arm`` itself if there is no mismatch. The geometry, the
    wetted cylinders and the limits are the nominal arm's."""
    if mismatch.is_identity:
        return arm
    model = arm.model.copy()
    scale = mismatch.mass_scale
    for joint in range(1, model.njoints):
        inertia = model.inertias[joint]
        model.inertias[joint] = pin.Inertia(inertia.mass * scale, inertia.lever.copy(), inertia.inertia * scale)
    if mismatch.payload_kg > 0.0:
        last = model.njoints - 1
        where = model.inertias[last].lever.copy()
        if model.existFrame("flange"):
            frame = model.frames[model.getFrameId("flange")]
            if frame.parentJoint == last:
                where = frame.placement.translation.copy()
        model.inertias[last] = model.inertias[last] + pin.Inertia(mismatch.payload_kg, where, np.zeros((3, 3)))
    return Arm(
        name=f"{arm.name} (plant: mass x{scale:g}, payload {mismatch.payload_kg:g} kg)",
        model=model,
        cylinders=arm.cylinders,
        torque_limit=arm.torque_limit,
        spec=None,
        position_limit=arm.position_limit,
    )
