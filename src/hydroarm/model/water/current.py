"""The ocean current, one formula for every user (the plant's compiled step, the water
model, the MuJoCo cross-check).

* ``paper``: eq. (22) of Liu et al. 2023: joint-velocity kicks d(t) (deg/s) applied as
  the joint acceleration ``d(t) / T_ref`` (rad/s^2) inside the plant's integration
  (docs/paper-reading.md, section 2). Not a water force.
* ``uniform``: a world-frame water velocity
  ``V_c(t) = mean + amplitude sin(2 pi f t + phase)`` (m/s); the drag acts on the
  velocity relative to it.
* ``none``: still water.

:class:`CurrentField` holds the current as two constant arrays and :func:`current_at`
(compiled) evaluates both models at a time t; the models not in use have zero
amplitudes, so each formula gives exactly 0 there.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

import numba
import numpy as np
import pydantic

from hydroarm.config import FrozenModel

MAX_CURRENT_SPEED = 20.0
"""m/s: bound on every component of a uniform current's mean and amplitude."""

Velocity3 = Annotated[
    list[Annotated[float, pydantic.Field(ge=-MAX_CURRENT_SPEED, le=MAX_CURRENT_SPEED)]],
    pydantic.Field(min_length=3, max_length=3),
]

PAPER_CURRENT_AMPLITUDE_DEG_S = (0.5, 0.3, 0.4, 0.2, 0.1, 0.0)
PAPER_CURRENT_OMEGA = (0.1 * math.pi, 0.3 * math.pi, 0.2 * math.pi, 0.4 * math.pi, 0.5 * math.pi, 0.0)
PAPER_CURRENT_PHASE = (-0.2 * math.pi, -0.2 * math.pi, -0.3 * math.pi, -0.2 * math.pi, -0.25 * math.pi, 0.0)


class CurrentConfig(FrozenModel):
    """The ocean current model.

    ``model = "paper"``: eq. (22) joint-velocity kicks d(t) (deg/s), scaled by
    ``scale``, as the joint acceleration ``d(t) / reference_period`` (rad/s^2).
    ``model = "uniform"``: world-frame water velocity
    ``mean + amplitude * sin(2 pi frequency_hz t + phase)`` (m/s), in the drag.
    """

    model: Literal["paper", "uniform", "none"] = pydantic.Field(
        "paper", description="the current: the paper's eq. (22) kicks, a uniform world-frame flow, or none"
    )
    scale: float = pydantic.Field(1.0, ge=0.0, le=1000.0, description="factor on the paper current (-)")
    reference_period: float = pydantic.Field(
        0.01,
        gt=0.0,
        le=1.0,
        description="T_ref, the paper's simulation cycle that turns its kicks into accelerations (s)",
    )
    mean: Velocity3 = pydantic.Field(
        [0.0, 0.0, 0.0], description="uniform current: mean world-frame water velocity x, y, z (m/s)"
    )
    amplitude: Velocity3 = pydantic.Field(
        [0.0, 0.0, 0.0], description="uniform current: amplitude of the sinusoid on the velocity x, y, z (m/s)"
    )
    frequency_hz: float = pydantic.Field(
        0.0, ge=0.0, le=100.0, description="uniform current: frequency of the sinusoid (Hz)"
    )
    phase: float = pydantic.Field(0.0, description="uniform current: phase of the sinusoid (rad)")


class CurrentField:
    """The current of one :class:`CurrentConfig` on an n-joint arm, as the compiled code takes it.

    ``joint`` (3, n): the paper current's amplitude (rad/s^2, zero unless ``paper``),
    angular frequency (rad/s) and phase (rad) per joint (joints beyond the sixth: zero);
    ``world`` (8,): the uniform current's mean (3) and amplitude (3) (m/s, zero unless
    ``uniform``), ``2 pi f`` (rad/s) and phase (rad).
    """

    def __init__(self, current: CurrentConfig, n_joints: int):
        self.config = current
        self.n_joints = n_joints
        m = min(n_joints, 6)
        self.joint = np.zeros((3, n_joints))
        if current.model == "paper":
            self.joint[0, :m] = current.scale * np.deg2rad(PAPER_CURRENT_AMPLITUDE_DEG_S[:m]) / current.reference_period
        self.joint[1, :m] = PAPER_CURRENT_OMEGA[:m]
        self.joint[2, :m] = PAPER_CURRENT_PHASE[:m]
        self.world = np.zeros(8)
        if current.model == "uniform":
            self.world[:3] = current.mean
            self.world[3:6] = current.amplitude
            self.world[6] = 2.0 * math.pi * current.frequency_hz
            self.world[7] = current.phase

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """``(joint acceleration (n,) rad/s^2, water velocity (3,) m/s)`` at time t (s)."""
        joint_acceleration = np.empty(self.n_joints)
        water_velocity = np.empty(3)
        current_at(float(t), self.joint, self.world, joint_acceleration, water_velocity)
        return joint_acceleration, water_velocity


@numba.njit(cache=True)
def current_at(t, joint, world, joint_acceleration, water_velocity):  # pragma: no cover - compiled
    """Write the paper current's joint acceleration (n,) and the uniform current's water
    velocity (3,) at time t into the output arrays (see :class:`CurrentField`)."""
    for i in range(joint_acceleration.shape[0]):
        joint_acceleration[i] = joint[0, i] * np.cos(joint[1, i] * t + joint[2, i])
    wave = math.sin(world[6] * t + world[7])
    for i in range(3):
        water_velocity[i] = world[i] + world[3 + i] * wave


def paper_current_acceleration(current: CurrentConfig, t: float, n_joints: int) -> np.ndarray:
    """Joint acceleration (rad/s^2), shape (n,), of the paper's current d(t) / T_ref.

    Eq. (22) gives d(t) in deg/s for six joints; joints beyond the sixth get zero.
    Zero unless ``current.model == "paper"``.
    """
    return CurrentField(current, n_joints).at(t)[0]


def current_velocity(current: CurrentConfig, t: float) -> np.ndarray:
    """World-frame water velocity V_c(t) (m/s), shape (3,); zero unless ``uniform``."""
    return CurrentField(current, 0).at(t)[1]
