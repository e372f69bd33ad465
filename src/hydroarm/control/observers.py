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

:class:`ObservedController` puts an observer (or any
:class:`~hydroarm.control.interface.DisturbanceEstimator` on the state) under any controller
whose ``compute`` takes a ``feedforward_torque`` (SMC, MPC, IDMPC): it feeds the estimate forward
as the generalised force the controller compensates (sign: ``M q'' + h = tau + w``, so the
controller plans with ``tau - w_hat``) and, in ``observe``, updates it with the transition's
one-step residual (:meth:`~hydroarm.model.dynamics.nominal.NominalModel.tde_residual`).
"""

from __future__ import annotations

import time
from typing import Literal

import numpy as np
import pydantic

from hydroarm.config import FrozenModel
from hydroarm.control.idmpc_limits import SATURATION_TOLERANCE  # a torque this near its limit is saturated
from hydroarm.control.interface import (
    ControlOutput,
    DisturbanceEstimator,
    Reference,
    TorqueFeedforward,
    require_port,
)
from hydroarm.model.arm.description import Arm
from hydroarm.model.dynamics.nominal import NominalModel

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
    """TDE or first-order NDOB with control period T (module docstring): a
    :class:`~hydroarm.control.interface.DisturbanceEstimator` without an input.

    :meth:`update` takes each residual (the one-step residual of a measured transition,
    :meth:`~hydroarm.model.dynamics.nominal.NominalModel.tde_residual`, or what a model left of it);
    :meth:`mean` (n,) N m is the current w_hat (zero before the first residual) whatever its
    input; :meth:`variance` is NaN (an observer has no variance model); :meth:`feedforward` is
    what PI-IDMPC's remainder uses (zero on the step after a saturation when gated).
    """

    def __init__(self, arm: Arm, control_period: float, config: ObserverConfig):
        if config.kind == "none":
            raise ValueError("observer.kind = 'none': no observer to build")
        self.arm = arm
        self.n = arm.n_joints
        self.period = float(control_period)
        self.config = config
        self.gain = 1.0 if config.kind == "tde" else float(config.gain)
        self.reset()

    def reset(self) -> None:
        """Forget the estimate."""
        self.estimate = np.zeros(self.n)
        self.updates = 0
        self._saturated = False

    @property
    def n_samples(self) -> int:
        """The residuals taken since the last reset."""
        return self.updates

    def update(self, x: np.ndarray | None, r: np.ndarray, saturated: bool = False) -> bool:
        """Take the residual r (n,) N m (``x`` is not read: the observer has no input);
        ``saturated``: a torque of the step was at its limit (the gate then holds the next
        :meth:`feedforward`). A non-finite residual is not taken (False)."""
        self._saturated = bool(saturated)
        if not np.all(np.isfinite(r)):
            return False
        if self.gain == 1.0:  # TDE: the residual itself, bit for bit
            self.estimate = r
        else:
            self.estimate = self.estimate + self.gain * (r - self.estimate)
        self.updates += 1
        return True

    def mean(self, x: np.ndarray | None = None) -> np.ndarray:
        """The estimate w_hat (n,) N m (``x`` is not read)."""
        return self.estimate.copy()

    def variance(self, x: np.ndarray | None = None) -> np.ndarray:
        """NaN (n,): an observer keeps no variance of its estimate."""
        return np.full(self.n, np.nan)

    def feedforward(self) -> np.ndarray:
        """The estimate to feed forward now (n,) N m: zero when gated after a saturated step."""
        if self.config.gate and self._saturated:
            return np.zeros(self.n)
        return self.estimate.copy()


class ObservedController:
    """A controller with a disturbance estimator under it (module docstring).

    ``controller`` must have the torque feed-forward port (``compute(..., feedforward_torque=)``
    (n,) N m, :class:`~hydroarm.control.interface.TorqueFeedforward`; checked here, TypeError
    otherwise); its ``torque_limit`` (n,) decides saturation. ``estimator``: any
    :class:`~hydroarm.control.interface.DisturbanceEstimator` whose input is the measured state
    y (2n,) (a :class:`DisturbanceObserver` ignores it; a
    :class:`~hydroarm.control.gp.SlidingWindowGP` with 2n inputs and n outputs learns on it);
    it is updated with the one-step residual of each transition
    (:meth:`~hydroarm.model.dynamics.nominal.NominalModel.tde_residual` on ``arm``'s dry model, NumPy's
    product as the observers always had it) and its mean at y is fed forward. ``gate``: feed
    zero on the step after a saturated one (default: the observer's ``config.gate``, else False).
    ``name``: the controller's with ``+TDE`` / ``+NDOB`` (``-gated``), or ``+label``.
    ``ControlOutput.disturbance_mean`` is the estimate fed forward.
    """

    def __init__(
        self,
        controller: TorqueFeedforward,
        estimator: DisturbanceEstimator,
        arm: Arm,
        gate: bool | None = None,
        label: str | None = None,
    ):
        observer = estimator if isinstance(estimator, DisturbanceObserver) else None
        if label is None:
            label = observer.config.label if observer is not None else type(estimator).__name__
        require_port(controller, "torque", f"the disturbance estimator ({label})")
        self.controller = controller
        self.estimator = estimator
        self.gate = bool(observer.config.gate if observer is not None and gate is None else gate)
        self.name = f"{controller.name}+{label}"
        self.control_period = controller.control_period
        self.torque_limit = np.asarray(controller.torque_limit, dtype=float)
        self.nominal = NominalModel(arm, inner_step=None)  # own workspace
        self._saturated = False  # the last computed torque saturated
        self._hold = False  # the last observed step saturated: gate the next feed-forward

    def reset(self) -> None:
        self.controller.reset()
        self.estimator.reset()
        self._saturated = False
        self._hold = False

    def drive_limits(self, output: np.ndarray, step: np.ndarray) -> None:
        """The drives' rate limit, passed to the controller if it takes it (the estimate is inside
        its torque: :meth:`~hydroarm.control.idmpc.InverseDynamicsMPC.drive_limits`)."""
        tell = getattr(self.controller, "drive_limits", None)
        if tell is not None:
            tell(output, step)

    def compute(self, t: float, y: np.ndarray, reference: Reference) -> ControlOutput:
        start = time.perf_counter()
        w_hat = np.zeros(self.torque_limit.shape[0]) if self.gate and self._hold else self.estimator.mean(y)
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
        y, u, y_next = (np.asarray(x, dtype=float) for x in (y, u, y_next))
        r = self.nominal.tde_residual(y, u, y_next, self.control_period, product="blas")
        self._hold = self._saturated
        if isinstance(self.estimator, DisturbanceObserver):
            self.estimator.update(y, r, self._saturated)
        elif np.all(np.isfinite(r)) and np.all(np.isfinite(y)):
            self.estimator.update(y, r)
        self.controller.observe(t, y, u, y_next)
