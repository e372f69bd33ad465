"""Joint friction of a geared arm: Coulomb + Stribeck, regularised for RK4.

The friction torque on joint i at joint velocity v (rad/s), opposing the motion::

    f_i(v) = (F_c + (F_s - F_c) exp(-(v / v_s)^2)) tanh(v / w) + F_v v        (N m)

with the Coulomb level ``F_c``, the breakaway (static) level ``F_s >= F_c`` and the Stribeck
velocity ``v_s``; ``tanh(v / w)`` replaces ``sign(v)`` with a stated width w (rad/s), so the
force is smooth (C-infinity) and classic RK4 can integrate it; it acts like a viscous term of
slope ``F_s / w`` near v = 0, for which :class:`~hydroarm.model.arm.plant.UnderwaterPlant` shortens
its RK4 step as far as classic RK4's stability needs (on the paper arm, whose wrist inertia is
1.2e-4 kg m^2, the published values need steps of about 0.23 ms, 0.12 ms at twice them). A
viscous term ``F_v v`` (``friction.viscous``, per joint) adds to it, and to the paper SPEC's
uniform viscous option ``plant.friction``. A torque below ``F_s`` holds a joint nearly still: it
creeps at about ``w atanh(tau / F_s)`` (rad/s), the price of the regularisation.

Published defaults (:data:`PUBLISHED_COULOMB`, :data:`PUBLISHED_WIDTH`): the joint friction of
the Franka Emika Panda identified by Gaz, Cognetti, Oliva, Robuffo Giordano and De Luca,
"Dynamic Identification of the Franka Emika Panda Robot With Retrieval of Feasible Parameters
Using Penalty-Based Optimization", IEEE RA-L 4(4), 2019, eq. (13) and its table of friction
parameters: ``tau_f = phi1 / (1 + exp(-phi2 (v + phi3))) - phi1 / (1 + exp(-phi2 phi3))``. With
the small offset phi3 dropped that is exactly ``(phi1 / 2) tanh(phi2 v / 2)``: a regularised
Coulomb term with ``F_c = phi1 / 2`` and ``w = 2 / phi2``. The Panda is a harmonic-drive arm of
the UR5's size class (about 18 kg, 0.85 m reach, 3-5 kg payload); joint i of an arm takes the
Panda's joint i (base to wrist; an arm of more than 7 joints must give its own values). That
identification has no Stribeck peak and no viscous term: the defaults are ``F_s = F_c`` and no
viscous friction; ``breakaway`` and ``stribeck_velocity`` set a Stribeck peak.
"""

from __future__ import annotations

from typing import Annotated

import numba
import numpy as np
import pydantic

from hydroarm.config import ConfigError, FrozenModel, per_joint

PANDA_PHI1 = (0.54615, 0.87224, 0.64068, 1.2794, 0.83904, 0.30301, 0.56489)
"""phi1 of Gaz et al. 2019 per Panda joint (N m): the sigmoid's full height, twice the Coulomb level."""

PANDA_PHI2 = (5.1181, 9.0657, 10.136, 5.5903, 8.3469, 17.133, 10.336)
"""phi2 of Gaz et al. 2019 per Panda joint (s/rad): the sigmoid's steepness."""

PUBLISHED_COULOMB = tuple(phi1 / 2.0 for phi1 in PANDA_PHI1)
"""F_c per joint (N m): phi1 / 2 of Gaz et al. 2019 (module docstring)."""

PUBLISHED_WIDTH = tuple(2.0 / phi2 for phi2 in PANDA_PHI2)
"""w per joint (rad/s): 2 / phi2 of Gaz et al. 2019, the published sigmoid's own width."""

NonNegative = Annotated[float, pydantic.Field(ge=0.0, le=1e4)]
Positive = Annotated[float, pydantic.Field(gt=0.0, le=1e4)]


class FrictionConfig(FrozenModel):
    """Coulomb + Stribeck joint friction of the true plant (module docstring); off by default.

    ``scale`` (-): factor on ``coulomb``, ``breakaway`` and ``viscous``; 0 = no such friction (the paper's
    frictionless joints), 1 = the values as given (by default the published ones).
    ``coulomb`` (N m), ``breakaway`` (N m, >= coulomb; null = coulomb: no Stribeck peak),
    ``stribeck_velocity`` (rad/s), ``width`` (rad/s, the tanh regularisation): one value or one
    per joint; null = the published values of Gaz et al. 2019 for joints 1..n.
    """

    scale: float = pydantic.Field(
        0.0, ge=0.0, le=100.0, description="factor on the Coulomb, breakaway and viscous terms; 0 = off (paper) (-)"
    )
    coulomb: NonNegative | list[NonNegative] | None = pydantic.Field(
        None, description="F_c, the Coulomb torque per joint; null = Gaz et al. 2019's Panda (N m)"
    )
    breakaway: NonNegative | list[NonNegative] | None = pydantic.Field(
        None, description="F_s >= F_c, the breakaway (static) torque per joint; null = F_c, no Stribeck peak (N m)"
    )
    viscous: NonNegative | list[NonNegative] = pydantic.Field(
        0.0, description="F_v, viscous friction per joint, on top of plant.friction (N m s/rad)"
    )
    stribeck_velocity: Positive | list[Positive] = pydantic.Field(
        0.1, description="v_s, how fast the torque falls from F_s to F_c (rad/s)"
    )
    width: Annotated[float, pydantic.Field(ge=1e-6, le=100.0)] | list[
        Annotated[float, pydantic.Field(ge=1e-6, le=100.0)]
    ] | None = pydantic.Field(
        None, description="w, the tanh width replacing sign(v); null = Gaz et al. 2019's per joint (rad/s)"
    )  # fmt: skip

    @property
    def active(self) -> bool:
        return self.scale > 0.0

    def arrays(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(F_c, F_s, F_v, v_s, w)``, each (n,), scale applied to the first three; raises :class:`ConfigError` for a
        wrong count, a breakaway below the Coulomb level, or published values for more than 7
        joints."""

        def published(values: tuple[float, ...], field: str) -> np.ndarray:
            if n > len(values):
                raise ConfigError(
                    f"friction.{field} = null: the published values cover {len(values)} joints, "
                    f"the arm has {n}: give one value or a list of {n}"
                )
            return np.array(values[:n])

        coulomb = (
            published(PUBLISHED_COULOMB, "coulomb")
            if self.coulomb is None
            else per_joint(self.coulomb, n, "friction.coulomb")
        )
        width = (
            published(PUBLISHED_WIDTH, "width") if self.width is None else per_joint(self.width, n, "friction.width")
        )
        breakaway = coulomb.copy() if self.breakaway is None else per_joint(self.breakaway, n, "friction.breakaway")
        if np.any(breakaway < coulomb):
            raise ConfigError(
                f"friction.breakaway = {self.breakaway!r}: must be >= friction.coulomb on every joint "
                f"(coulomb = {coulomb.tolist()} N m)"
            )
        stribeck = per_joint(self.stribeck_velocity, n, "friction.stribeck_velocity")
        viscous = per_joint(self.viscous, n, "friction.viscous")
        return self.scale * coulomb, self.scale * breakaway, self.scale * viscous, stribeck, width

    def max_slope(self, n: int) -> np.ndarray:
        """An upper bound on the slope of f_i (N m s/rad, (n,)): ``F_s / w + F_v`` (at v = 0)."""
        _, breakaway, viscous, _, width = self.arrays(n)
        return breakaway / width + viscous


@numba.njit(cache=True)
def friction_torque(v, coulomb, breakaway, viscous, stribeck_velocity, width):  # pragma: no cover - compiled
    """f(v) + F_v v (N m, (n,)) of the module docstring at joint velocities v (rad/s, (n,))."""
    n = v.shape[0]
    out = np.empty(n)
    for i in range(n):
        ratio = v[i] / stribeck_velocity[i]
        level = coulomb[i] + (breakaway[i] - coulomb[i]) * np.exp(-ratio * ratio)
        out[i] = level * np.tanh(v[i] / width[i]) + viscous[i] * v[i]
    return out
