"""The classic disturbance observers, usable under SMC, the paper's MPC and the inverse-dynamics MPC.

The plant is ``M(q) q'' + h(q, v) = tau + w`` (N m; ``h = C(q, v) v + G(q)`` the dry model's
bias, w the water and current the dry model misses). Both observers see the measured (or
filtered) transition ``y_{k-1} -> y_k`` under the applied torque ``u_{k-1}`` and estimate w.

Time-delay estimation (TDE, Hsia & Gao 1990; Youcef-Toumi & Ito 1990): the disturbance of the
last step, from the dynamics with the acceleration replaced by its backward difference::

    r_k = M(q_{k-1}) (v_k - v_{k-1}) / T + h(q_{k-1}, v_{k-1}) - u_{k-1}        (N m, (n,))
    w_hat_k = r_k

Under a zero-order-hold torque on a plant of constant inertia and zero bias (a single joint
turning about a vertical axis) ``r_k`` is exactly the constant disturbance after one step.

First-order nonlinear disturbance observer (NDOB, Chen et al. 2000): the estimate follows the
disturbance through a first-order lag of gain L per control step, ``w_hat' = (L / T) (w - w_hat)``
discretised with the same backward difference (the observer's auxiliary variable then needs no
acceleration measurement, and its update is algebraically the TDE's residual filtered)::

    w_hat_k = w_hat_{k-1} + L (r_k - w_hat_{k-1}),   0 < L <= 1

For a constant disturbance its error shrinks by the factor ``(1 - L)`` every step (rate L); L = 1
is the TDE. A smaller L trades lag for less measurement noise (TDE's difference amplifies it by
``M / T``).

Saturation gate (``gate``): on the step after a torque saturated, the estimate is not fed forward
(zero instead): that step's residual mixes the unmodelled clipping of the torque with the water.
The observer itself still updates.

:class:`ObservedController` puts an observer under any controller whose ``compute`` takes a
``feedforward_torque`` (SMC, MPC, IDMPC): it feeds the estimate forward as the generalised force
the controller compensates (sign: ``M q'' + h = tau + w``, so the controller plans with
``tau - w_hat``) and updates the observer in ``observe``.
"""

from __future__ import annotations

import time
from typing import Literal

import numpy as np
import pydantic

from hydroarm.config import FrozenModel
from hydroarm.control.interface import ControlOutput, Reference, TorqueFeedforward, require_port
from hydroarm.model.arm import Arm
from hydroarm.model.nominal import NominalModel

ObserverKind = Literal["none", "tde", "ndob"]

OBSERVER_LABELS: dict[str, str] = {"tde": "TDE", "ndob": "NDOB"}


class ObserverConfig(FrozenModel):
    """The disturbance observer under SMC, MPC or IDMPC (module docstring).

    ``kind``: ``"none"`` (default: the controllers as they are), ``"tde"`` or ``"ndob"``;
    ``gain``: the NDOB's L per control step; ``gate``: do not feed the estimate forward on the
    step after a torque saturated.
    """

    kind: ObserverKind = pydantic.Field(
        "none", description="none, tde (time-delay estimate) or ndob (first-order NDOB)"
    )
    gain: float = pydantic.Field(
        0.1, gt=0.0, le=1.0, description="NDOB: L, the share of the estimate's error removed per step, 0 < L <= 1 (-)"
    )
    gate: bool = pydantic.Field(False, description="do not feed the estimate forward on the step after a saturation")

    @property
    def label(self) -> str:
        """``"TDE"``, ``"NDOB"``, with ``"-gated"`` when gated; ``""`` for ``kind = "none"``."""
        if self.kind == "none":
            return ""
        return OBSERVER_LABELS[self.kind] + ("-gated" if self.gate else "")


class DisturbanceObserver:
    """TDE or first-order NDOB on ``arm``'s dry model with control period T (module docstring).

    :meth:`update` takes each measured transition; :attr:`estimate` (n,) N m is the current
    w_hat (zero before the first transition); :meth:`feedforward` is what the controller uses
    (zero on the step after a saturation when gated).
    """

    def __init__(self, arm: Arm, control_period: float, config: ObserverConfig):
        if config.kind == "none":
            raise ValueError("observer.kind = 'none': no observer to build")
        self.arm = arm
        self.n = arm.n_joints
        self.period = float(control_period)
        self.config = config
        self.gain = 1.0 if config.kind == "tde" else float(config.gain)
        self.nominal = NominalModel(arm, inner_step=None)  # own workspace
        self.reset()

    def reset(self) -> None:
        """Forget the estimate."""
        self.estimate = np.zeros(self.n)
        self.updates = 0
        self._saturated = False

    def residual(self, y: np.ndarray, u: np.ndarray, y_next: np.ndarray) -> np.ndarray:
        """``r = M(q) (v_next - v) / T + h(q, v) - u`` (n,) N m of the transition ``y -> y_next``
        (2n,) under ``u`` (n,), with M and h at y (:meth:`~hydroarm.model.nominal.NominalModel.tde_residual`,
        with NumPy's product as the observers always had it)."""
        return self.nominal.tde_residual(y, u, y_next, self.period, product="blas")

    def update(self, y: np.ndarray, u: np.ndarray, y_next: np.ndarray, saturated: bool = False) -> None:
        """Take the transition ``y -> y_next`` under the applied ``u``; ``saturated``: a torque of
        ``u`` was at its limit (the gate then holds the next feed-forward). A non-finite residual
        is not taken."""
        r = self.residual(np.asarray(y, dtype=float), np.asarray(u, dtype=float), np.asarray(y_next, dtype=float))
        self.update_residual(r, saturated)

    def update_residual(self, r: np.ndarray, saturated: bool = False) -> None:
        """Take an already computed residual r (n,) N m (e.g. what a model left of the TDE's)."""
        self._saturated = bool(saturated)
        if not np.all(np.isfinite(r)):
            return
        if self.gain == 1.0:  # TDE: the residual itself, bit for bit
            self.estimate = r
        else:
            self.estimate = self.estimate + self.gain * (r - self.estimate)
        self.updates += 1

    def feedforward(self) -> np.ndarray:
        """The estimate to feed forward now (n,) N m: zero when gated after a saturated step."""
        if self.config.gate and self._saturated:
            return np.zeros(self.n)
        return self.estimate.copy()


SATURATION_TOLERANCE = 1e-9
"""A torque within this relative margin of its limit counts as saturated."""


class ObservedController:
    """A controller with a :class:`DisturbanceObserver` under it (module docstring).

    ``controller`` must have the torque feed-forward port (``compute(..., feedforward_torque=)``
    (n,) N m, :class:`~hydroarm.control.interface.TorqueFeedforward`; checked here, TypeError
    otherwise); its ``torque_limit`` (n,) decides saturation. ``name``: the controller's with
    ``+TDE`` / ``+NDOB`` (``-gated``).
    ``ControlOutput.disturbance_mean`` is the estimate fed forward.
    """

    def __init__(self, controller: TorqueFeedforward, observer: DisturbanceObserver):
        require_port(controller, "torque", f"the disturbance observer ({observer.config.label})")
        self.controller = controller
        self.observer = observer
        self.name = f"{controller.name}+{observer.config.label}"
        self.control_period = controller.control_period
        self.torque_limit = np.asarray(controller.torque_limit, dtype=float)
        self._saturated = False

    def reset(self) -> None:
        self.controller.reset()
        self.observer.reset()
        self._saturated = False

    def compute(self, t: float, y: np.ndarray, reference: Reference) -> ControlOutput:
        start = time.perf_counter()
        w_hat = self.observer.feedforward()
        elapsed = time.perf_counter() - start
        out = self.controller.compute(t, y, reference, feedforward_torque=w_hat)
        self._saturated = out.status == "saturated" or bool(
            np.any(np.abs(out.tau) >= self.torque_limit * (1.0 - SATURATION_TOLERANCE))
        )
        out.disturbance_mean = w_hat
        out.timings["observer"] = elapsed
        out.timings["total"] = out.timings.get("total", 0.0) + elapsed
        return out

    def observe(self, t: float, y: np.ndarray, u: np.ndarray, y_next: np.ndarray) -> None:
        self.observer.update(y, u, y_next, self._saturated)
        self.controller.observe(t, y, u, y_next)
