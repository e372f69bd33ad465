"""The design of the per-joint Kalman filter (:mod:`hydroarm.control.estimator`): what it is
designed for (:class:`FilterDesign`), its default process noise derived from the sensor
(:func:`derived_acceleration_variance`, Kalata's tracking index), the zero-order-hold double
integrator it predicts on and the steady-state covariance of its Riccati equation (both from
:mod:`hydroarm.control.linear`: :func:`~hydroarm.control.linear.double_integrator`,
:func:`~hydroarm.control.linear.filter_covariance`).

Defaults that follow the sensor (issue 32; docs/robustness.md, section 6):

* ``kind = "auto"``: the filter behind any sensor but the ideal q-and-v one, or with a loop delay
  (:meth:`EstimatorConfig.resolved_kind`); else the controller's own default.
* ``acceleration_variance = null``: :func:`derived_acceleration_variance`: 100 with q and v
  measured; position only, ``min(100, 30^2 sigma_m^2 / T^4)`` with sigma_m^2 the noise plus
  ``resolution^2 / 12``, i.e. a tracking index of at most :data:`TRACKING_INDEX_LIMIT`.
* after a bridged sample the correction's gain is the one of the covariance grown over the gap
  (``P C^T (C P C^T + R)^-1``), until it is back at the steady gain.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hydroarm.control.linear import filter_covariance


@dataclass(frozen=True)
class FilterDesign:
    """What a :class:`JointKalmanFilter` is designed for: ``position_only`` (C = [1, 0]) or the
    state measured (C = I); the measurement-noise variances ``position_variance`` (rad^2) and
    ``velocity_variance`` ((rad/s)^2); the loop ``delay`` it predicts across (periods), of which
    ``sensor_delay`` periods are the sensor's (the first sample is delivered until then, so the
    filter starts predicting after them); sigma_a^2 ``acceleration_variance`` ((rad/s^2)^2; None:
    :func:`derived_acceleration_variance`'s)."""

    position_only: bool = False
    position_variance: float = 0.0
    velocity_variance: float = 0.0
    delay: int = 0
    sensor_delay: int = 0
    acceleration_variance: float | None = None


VARIANCE_FLOOR = 1e-12
"""Smallest measurement variance (rad^2) of the general Riccati equation (a noise-free
position-only sensor: the filter is then all but deadbeat)."""

MEASURED_VELOCITY_ACCELERATION_VARIANCE = 100.0
"""sigma_a^2 ((rad/s^2)^2) behind a sensor that measures q and v: the value tuned on the paper's
noisy sensor (variance 1e-3 on both; its tracking index is 0.03), kept so the reproduction's
numbers are unchanged; a noise-free q-and-v sensor gets the pass-through filter whatever it is."""


def tracking_index(acceleration_variance: float, measurement_variance: float, period: float) -> float:
    """Kalata's tracking index ``lambda = sigma_a T^2 / sigma_m`` (-) of a position-measuring
    filter: its steady-state gains depend on it alone (an alpha-beta filter: lambda -> infinity
    is deadbeat, the velocity the last position difference; lambda -> 0 trusts the model)."""
    return float(np.sqrt(acceleration_variance) * period**2 / np.sqrt(max(measurement_variance, VARIANCE_FLOOR)))


TRACKING_INDEX_LIMIT = 30.0
"""The largest tracking index (-) a position-only filter gets by default. As lambda grows the
filter tends to the deadbeat one (alpha -> 1, beta -> 2: the position taken as measured, the
velocity the last backward difference, half a period late), and the ID-MPCs' near-deadbeat
wrist gains go unstable on that lagging velocity: measured on the paper arm with the published
friction and no loop delay (docs/robustness.md, section 6), lambda = 360 and 1000 diverge
within 3 s, 36 and 111 do not; 30 keeps a factor of 12 from the first failure. With a loop
delay the controller is given the state predicted across it on the commanded accelerations, and
lambda = 1000 did not diverge at one period: the delay does not lower the limit."""


def derived_acceleration_variance(position_only: bool, position_variance: float, period: float) -> float:
    """The default sigma_a^2 ((rad/s^2)^2) for the sensor the filter is given and the control
    period T (``period``, s).

    With q and v measured: :data:`MEASURED_VELOCITY_ACCELERATION_VARIANCE` (100). Position only
    (an encoder): the filter's gains depend on its tracking index ``lambda = sigma_a T^2 /
    sigma_m`` alone (:func:`tracking_index`), with sigma_m^2 the position's measurement variance
    (``position_variance``: noise + res^2 / 12, floored at :data:`VARIANCE_FLOOR`). 100 is kept
    while lambda stays at most :data:`TRACKING_INDEX_LIMIT`; a finer or noise-free encoder (a
    continuous one: lambda = 1000 at 100) is capped there::

        sigma_a^2 = min(100, lambda_max^2 sigma_m^2 / T^4),   lambda_max = 30

    A 16-bit encoder at T = 10 ms: sigma_m^2 = 7.66e-10 rad^2, lambda = 36 at 100, so
    sigma_a^2 = 69. The loop delay does not enter: it is handled by the prediction across it
    (:class:`FilteredController`), not by a slower filter (:data:`TRACKING_INDEX_LIMIT`)."""
    if not position_only:
        return MEASURED_VELOCITY_ACCELERATION_VARIANCE
    capped = TRACKING_INDEX_LIMIT**2 * max(position_variance, VARIANCE_FLOOR) / period**4
    return float(min(MEASURED_VELOCITY_ACCELERATION_VARIANCE, capped))


def steady_state_covariance(
    period: float, measurement_variance: float, acceleration_variance: float,
    tolerance: float = 1e-14, max_iterations: int = 1_000_000,
) -> np.ndarray:  # fmt: skip
    """The steady-state prior covariance Sigma (2, 2) of the filter (module docstring) measuring
    q and v with noise ``measurement_variance`` each: :func:`~hydroarm.control.linear.filter_covariance` with C = I
    (the same arithmetic: products with the identity are exact).

    Raises :class:`ConfigError` if it does not converge (it does for any positive variances:
    the pair (A, I) is observable and (A, B) controllable)."""
    noise = measurement_variance * np.eye(2)
    return filter_covariance(period, np.eye(2), noise, acceleration_variance, tolerance, max_iterations)
