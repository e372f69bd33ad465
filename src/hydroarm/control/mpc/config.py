"""Settings of the linear time-varying MPC (:class:`MPCConfig`).

Per-joint fields take one value or a list of n. Units: Q weights in 1/rad^2 and s^2/rad^2,
R in 1/(N m)^2, torques in N m. The control period is not a setting of the MPC: it is
``LinearMPC``'s ``control_period`` argument, set once per experiment.
"""

from __future__ import annotations

from typing import Annotated, Literal

import pydantic

from hydroarm.config import FrozenModel

PositiveFloat = Annotated[float, pydantic.Field(gt=0.0)]
NonNegativeFloat = Annotated[float, pydantic.Field(ge=0.0)]
PositiveList = Annotated[list[PositiveFloat], pydantic.Field(min_length=1, max_length=12)]
NonNegativeList = Annotated[list[NonNegativeFloat], pydantic.Field(min_length=1, max_length=12)]


class MPCConfig(FrozenModel):
    """Settings of :class:`~hydroarm.control.mpc.LinearMPC`. Per-joint fields take one value
    or a list of n.

    Defaults are the paper's (Section 4) where it gives them: Q = diag(300 x n,
    0.01 x n), R = 0.1 I, |u| <= 500 N m (the paper arm's limit: the arm file's
    ``torque_limit``, which the experiment's ``torque_limit`` overrides); N = 10 is our reading's choice (the paper
    gives none). The control period T (paper reading: 10 ms) is not a field: it is
    ``LinearMPC``'s ``control_period`` argument. ``discretisation`` departs from the
    paper's Euler step by default: in the second-order Taylor step the held torque
    also moves the position within the step, which keeps the light wrist stable
    on a lighter plant than Euler's gains do (measured in docs/deviations.md and
    docs/robustness.md).
    """

    horizon: int = pydantic.Field(10, ge=1, le=200, description="prediction horizon N (steps)")
    q_position: PositiveFloat | PositiveList = pydantic.Field(
        300.0, description="Q weight on the joint position error (1/rad^2), within [1e-6, 1e8]"
    )
    q_velocity: NonNegativeFloat | NonNegativeList = pydantic.Field(
        0.01, description="Q weight on the joint velocity error (s^2/rad^2), within [0, 1e8]"
    )
    r: PositiveFloat | PositiveList = pydantic.Field(
        0.1, description="R weight on the torque deviation u - u_r (1/(N m)^2), within [1e-6, 1e6]"
    )
    terminal_set: Literal["off", "soft", "hard"] = pydantic.Field(
        "off", description="terminal constraint x_N' P x_N <= alpha: off, soft (penalised slack) or hard"
    )
    terminal_alpha: float = pydantic.Field(1e-3, gt=0.0, description="terminal set level alpha (-)")
    terminal_slack_penalty: float = pydantic.Field(
        300.0, gt=0.0, le=1e12, description="linear penalty rho_s on the terminal slack (-)"
    )
    solver: Literal["daqp", "osqp", "quadprog", "clarabel"] = pydantic.Field(
        "daqp", description="the box-QP solver of the condensed MPC problem"
    )
    discretisation: Literal["euler", "taylor2"] = pydantic.Field(
        "taylor2",
        description="prediction model: second-order Taylor (ZOH-consistent, default) or explicit Euler (paper)",
    )
    riccati_tolerance: float = pydantic.Field(
        1e-12, gt=0.0, le=1e-3, description="doubling stops when the relative change of P is below this (-)"
    )
    riccati_max_iterations: int = pydantic.Field(
        60, ge=1, le=1000, description="cap on Riccati doubling iterations, then scipy's DARE (-)"
    )

    @pydantic.model_validator(mode="after")
    def _check_ranges(self) -> MPCConfig:
        """Weights within [1e-6, 1e8] (q_velocity from 0), r within [1e-6, 1e6]: beyond these the
        Riccati equation and the QP lose all precision."""
        from hydroarm.config import field_error

        for name, low, high in (("q_position", 1e-6, 1e8), ("q_velocity", 0.0, 1e8), ("r", 1e-6, 1e6)):
            value = getattr(self, name)
            for k, entry in enumerate(value if isinstance(value, list) else [value]):
                if entry is not None and not low <= entry <= high:
                    where = f"{name}.{k}" if isinstance(value, list) else name
                    raise field_error(where, entry, f"must be >= {low:g} and <= {high:g}")
        return self
