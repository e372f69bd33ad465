"""State estimation in front of any controller: a steady-state Kalman filter per joint.

Per joint i the filter's model is the exact zero-order-hold double integrator driven by the
commanded joint acceleration a (rad/s^2) over the control period T (s)::

    z+ = A z + B a + noise,   A = [[1, T], [0, 1]],   B = [T^2/2, T]
    y  = z + measurement noise                         (q and v are both measured)

with z = [q_i, v_i], process noise ``sigma_a^2 B B^T`` (an unknown acceleration of variance
``sigma_a^2``: what the commanded acceleration misses) and measurement noise
``sigma_m^2 I``. The steady-state prior covariance Sigma solves the filter's discrete
algebraic Riccati equation

    Sigma = A Sigma A^T - A Sigma (Sigma + R)^-1 Sigma A^T + Q_w,

found at construction by iterating it to a fixed point (:func:`steady_state_covariance`);
the gain is ``L = Sigma (Sigma + R)^-1`` (2 x 2 per joint). The filter is designed for the
sensor it sits behind: by default (``measurement_variance = "plant"``) sigma_m^2 is the
plant's measurement-noise variance, and a noise-free sensor (sigma_m^2 = 0) gives L = I, the
measurement passed through unchanged. Each step::

    z_pred = A z_hat + B a_prev          (predict with the last commanded acceleration)
    z_hat  = z_pred + L (y - z_pred)     (correct with the measurement)

:class:`FilteredController` puts a filter in front of any controller: it filters the
measurement before ``compute`` and ``observe``, and drives the filter with the
controller's commanded acceleration (``ControlOutput.acceleration`` when the controller
states it, else the dry model's ``ABA(q_hat, v_hat, tau)``).
"""

from __future__ import annotations

import time
from typing import Literal

import numpy as np
import pydantic

from hydroarm.config import ConfigError, FrozenModel
from hydroarm.control.interface import Controller, ControlOutput, Reference
from hydroarm.model.nominal import NominalModel

EstimatorKind = Literal["auto", "none", "kalman"]


class EstimatorConfig(FrozenModel):
    """The state estimator in front of the controller.

    ``kind``: ``"none"`` (the controller sees the raw measurement), ``"kalman"`` (a
    steady-state Kalman filter per joint) or ``"auto"``: the controller's own default (the
    registry's: ``kalman`` for hydroarm's ID-MPCs, ``none`` for the paper's controllers, so
    the reproduction is unchanged).
    """

    kind: EstimatorKind = pydantic.Field("auto", description="none, kalman, or auto (the controller's default)")
    measurement_variance: float | Literal["plant"] = pydantic.Field(
        "plant",
        description=(
            "sigma_m^2 the filter assumes on q and v (rad^2, (rad/s)^2), 0 <= x <= 10; "
            "'plant' = the plant's own (plant.noise_variance): a noise-free sensor gets a pass-through filter"
        ),
    )
    acceleration_variance: float = pydantic.Field(
        1e2, gt=0.0, le=1e8, description="sigma_a^2: variance of the acceleration the command misses ((rad/s^2)^2)"
    )

    @pydantic.field_validator("measurement_variance", mode="before")
    @classmethod
    def _variance_in_range(cls, value):
        if value == "plant":
            return value
        try:
            variance = float(value)
        except (TypeError, ValueError):
            variance = float("nan")
        if isinstance(value, bool) or not 0.0 <= variance <= 10.0:
            raise ValueError(f"must be 'plant' or a variance 0 <= x <= 10 (rad^2), got {value!r}")
        return variance

    def for_sensor(self, noise_variance: float) -> EstimatorConfig:
        """This config with ``measurement_variance = "plant"`` resolved to the sensor's
        ``noise_variance`` (rad^2); a numeric setting is kept."""
        if self.measurement_variance != "plant":
            return self
        return self.model_copy(update={"measurement_variance": float(noise_variance)})


def double_integrator(period: float) -> tuple[np.ndarray, np.ndarray]:
    """``(A (2, 2), B (2,))`` of the exact zero-order-hold double integrator with period T (s)."""
    return np.array([[1.0, period], [0.0, 1.0]]), np.array([0.5 * period * period, period])


def steady_state_covariance(
    period: float, measurement_variance: float, acceleration_variance: float,
    tolerance: float = 1e-14, max_iterations: int = 1_000_000,
) -> np.ndarray:  # fmt: skip
    """The steady-state prior covariance Sigma (2, 2) of the filter (module docstring), by
    fixed-point iteration of the Riccati recursion from Sigma = Q_w.

    Raises :class:`ConfigError` if it does not converge (it does for any positive variances:
    the pair (A, I) is observable and (A, B) controllable)."""
    a_mat, b_vec = double_integrator(period)
    process = acceleration_variance * np.outer(b_vec, b_vec)
    noise = measurement_variance * np.eye(2)
    sigma = process.copy()
    for _ in range(max_iterations):
        gain = sigma @ np.linalg.inv(sigma + noise)
        posterior = (np.eye(2) - gain) @ sigma
        updated = a_mat @ posterior @ a_mat.T + process
        if np.all(np.abs(updated - sigma) <= tolerance * np.abs(updated)):
            return 0.5 * (updated + updated.T)
        sigma = updated
    raise ConfigError(
        f"estimator: the Kalman covariance did not converge in {max_iterations} iterations "
        f"(measurement_variance = {measurement_variance!r}, acceleration_variance = {acceleration_variance!r})"
    )


class JointKalmanFilter:
    """Steady-state Kalman filters, one per joint, on the measured state [q, v] (2n,).

    ``gain`` (2, 2): the same for every joint (same model and variances); ``covariance``:
    the steady-state prior Sigma. :meth:`update` returns the filtered state (2n,).
    """

    def __init__(self, n_joints: int, period: float, config: EstimatorConfig):
        if config.measurement_variance == "plant":
            raise ConfigError(
                "estimator.measurement_variance = 'plant' needs the plant's noise variance: "
                "resolve it with EstimatorConfig.for_sensor(noise_variance), or give a variance 0 <= x <= 10 (rad^2)"
            )
        self.n = n_joints
        self.period = float(period)
        self.config = config
        variance = float(config.measurement_variance)
        self._a, self._b = double_integrator(period)
        self._exact = variance == 0.0  # L = I: the estimate is the measurement, bit for bit
        if self._exact:  # the prior is the process noise alone
            self.covariance = config.acceleration_variance * np.outer(self._b, self._b)
            self.gain = np.eye(2)
        else:
            self.covariance = steady_state_covariance(period, variance, config.acceleration_variance)
            self.gain = self.covariance @ np.linalg.inv(self.covariance + variance * np.eye(2))
        self.reset()

    @property
    def posterior_covariance(self) -> np.ndarray:
        """``(I - L) Sigma`` (2, 2): the steady-state covariance of the estimate's error after a
        correction, per joint (rad^2, rad^2/s, (rad/s)^2); zero on an exact sensor."""
        return (np.eye(2) - self.gain) @ self.covariance

    def reset(self) -> None:
        """Forget the estimate: the next measurement is taken as it is."""
        self._q: np.ndarray | None = None
        self._v: np.ndarray | None = None

    def predict(self, acceleration: np.ndarray) -> None:
        """Advance the estimate by one period under the commanded ``acceleration`` (n,) rad/s^2."""
        if self._q is None:
            return
        period = self.period
        self._q = self._q + period * self._v + 0.5 * period * period * acceleration
        self._v = self._v + period * acceleration

    def update(self, y: np.ndarray) -> np.ndarray:
        """Correct with the measurement ``y = [q, v]`` (2n,); return the estimate (2n,)."""
        n = self.n
        q_meas, v_meas = y[:n], y[n:]
        if self._q is None or self._exact:
            self._q, self._v = q_meas.copy(), v_meas.copy()
        else:
            dq, dv = q_meas - self._q, v_meas - self._v
            gain = self.gain
            self._q = self._q + gain[0, 0] * dq + gain[0, 1] * dv
            self._v = self._v + gain[1, 0] * dq + gain[1, 1] * dv
        return np.concatenate([self._q, self._v])

    @property
    def estimate(self) -> np.ndarray | None:
        """The current estimate [q, v] (2n,), or None before the first measurement."""
        return None if self._q is None else np.concatenate([self._q, self._v])


class FilteredController:
    """Any controller behind a :class:`JointKalmanFilter` (see the module docstring).

    Same interface as the controller it wraps; ``name`` is the wrapped one's with ``+KF``.
    ``timings["estimator"]`` (s) is the filter's share of each step.
    """

    def __init__(self, controller: Controller, kalman: JointKalmanFilter, nominal: NominalModel):
        self.controller = controller
        self.kalman = kalman
        self.nominal = nominal
        self.name = f"{controller.name}+KF"
        self.control_period = controller.control_period
        self._filtered: np.ndarray | None = None
        self._next: np.ndarray | None = None

    def reset(self) -> None:
        self.controller.reset()
        self.kalman.reset()
        self._filtered = None
        self._next = None

    def compute(self, t: float, y: np.ndarray, reference: Reference) -> ControlOutput:
        start = time.perf_counter()
        filtered = self._next if self._next is not None else self.kalman.update(np.asarray(y, dtype=float))
        self._next = None
        elapsed = time.perf_counter() - start
        out = self.controller.compute(t, filtered, reference)
        start = time.perf_counter()
        n = self.kalman.n
        if out.acceleration is not None:
            acceleration = np.asarray(out.acceleration, dtype=float)
        else:
            acceleration = self.nominal.forward_dynamics(filtered[:n], filtered[n:], out.tau)
        self.kalman.predict(acceleration)
        self._filtered = filtered
        out.timings["estimator"] = elapsed + time.perf_counter() - start
        out.timings["total"] = out.timings.get("total", 0.0) + out.timings["estimator"]
        return out

    def observe(self, t: float, y: np.ndarray, u: np.ndarray, y_next: np.ndarray) -> None:
        """Filter ``y_next`` (it is the next step's measurement too) and pass the filtered
        transition to the wrapped controller."""
        filtered_next = self.kalman.update(np.asarray(y_next, dtype=float))
        self._next = filtered_next
        previous = self._filtered if self._filtered is not None else np.asarray(y, dtype=float)
        self.controller.observe(t, previous, u, filtered_next)
