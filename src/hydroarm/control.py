"""The one controller interface shared by SMC, MPC and GP-MPC.

One control step, as data: the runner gives the measured state ``y_k`` and the
reference to ``controller.compute(t_k, y_k, reference)``, which returns a
:class:`ControlOutput`; after the plant has moved, the runner calls
``controller.observe(t_k, y_k, u_k, y_next)`` so learning controllers can add
the new sample (a no-op for the others).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np


class Reference(Protocol):
    """A reference trajectory: ``sample(t) -> (q, v, a)``, each shape (n,)."""

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


@dataclass
class ControlOutput:
    """The result of one control step.

    ``tau`` (n,) N m, within the torque limits; ``status``: ``"ok"`` or what
    fallback was used (e.g. ``"qp_failed_lqr"``); ``timings``: seconds per
    phase (``"gp"``, ``"linearise"``, ``"qp_update"``, ``"qp_solve"``,
    ``"total"``); ``disturbance_mean``/``disturbance_var`` (n,): the learned
    disturbance estimate (N m, (N m)^2) fed forward, None if the controller
    has none; ``terminal_violation``: slack of the soft terminal set (0 if off).
    """

    tau: np.ndarray
    status: str = "ok"
    timings: dict[str, float] = field(default_factory=dict)
    disturbance_mean: np.ndarray | None = None
    disturbance_var: np.ndarray | None = None
    terminal_violation: float = 0.0


@runtime_checkable
class Controller(Protocol):
    """What every controller implements."""

    name: str
    control_period: float

    def reset(self) -> None:
        """Forget all state (warm starts, learned data)."""

    def compute(self, t: float, y: np.ndarray, reference: Reference) -> ControlOutput:
        """Torque for measured state ``y = [q, v]`` (2n,) at time t (s)."""

    def observe(self, t: float, y: np.ndarray, u: np.ndarray, y_next: np.ndarray) -> None:
        """The step from ``y`` under ``u`` ended at ``y_next`` (measured)."""
