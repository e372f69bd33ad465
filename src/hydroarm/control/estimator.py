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
the gain is ``L = Sigma (Sigma + R)^-1`` (2 x 2 per joint), both in scalar fixed-order arithmetic
(:func:`~hydroarm.control.linear.kalman_correction`: the same bits under any BLAS kernel, as the
closed loop needs). The filter is designed for the
sensor it sits behind: by default (``measurement_variance = "plant"``) sigma_m^2 is the
plant's measurement-noise variance, and a noise-free sensor (sigma_m^2 = 0) gives L = I, the
measurement passed through unchanged. Each step::

    z_pred = A z_hat + B a_prev          (predict with the last commanded acceleration)
    z_hat  = z_pred + L (y - z_pred)     (correct with the measurement)

:class:`FilteredController` puts a filter in front of any controller: it filters the
measurement before ``compute`` and ``observe``, and drives the filter with the
controller's commanded acceleration (``ControlOutput.acceleration`` when the controller
states it, else the dry model's ``ABA(q_hat, v_hat, tau)``).

The real loop (issue 23, :mod:`hydroarm.model.real_loop.sensing`):

* **encoder-only sensing** (``sensor.velocity = "differenced"``; ``estimator.measures``): the
  filter measures the position alone, ``y = C z + noise`` with C = [1, 0] and the variance of
  the position noise plus the quantisation's ``resolution^2 / 12``; the velocity is estimated,
  the sensor's differenced velocity is not used. The Riccati equation and gain
  ``L = Sigma C^T (C Sigma C^T + R)^-1`` (2 x 1) are the general ones
  (:func:`~hydroarm.control.linear.filter_covariance`).
* **loop delay** (``sensor.delay + actuator.delay`` = d periods; ``estimator.delay``): the
  measurement at step k is of x_{k - d_s} and the command of step k acts from step k + d_a. The
  filter runs d_s periods behind, each predict driven by the command that was acting then, and
  the controller is given a Smith-predictor-style forward prediction: the filtered state
  stepped d periods on the filter's nominal model (the double integrator above) under the d
  commanded accelerations still in flight. A learning controller observes the filtered
  transition with the torque that acted during it, not the one just commanded.
* **dropout**: a measurement equal to the previous one in every channel (the sensor repeated a
  lost sample) is not corrected with (``estimator.repeated = "skip"``): the filter predicts only
  (the pass-through filter of a noise-free sensor too), and the transitions into and out of the
  bridged sample are not passed to a learning controller (as the runner does for a held one).
* **the drives' rate limit** (``actuator.rate_limit``): the filter's copy of the drives tells the
  controller their output before its command acts (:mod:`hydroarm.control.drive_limits`).

Defaults that follow the sensor (``kind = "auto"``, a derived ``acceleration_variance``):
:mod:`hydroarm.control.filter_design`; on the idealised loop every number is as before.
"""

from __future__ import annotations

import time
from collections import deque
from typing import Literal

import numpy as np
import pydantic

from hydroarm.config import ConfigError, FrozenModel
from hydroarm.control.drive_limits import tell_drive_limits
from hydroarm.control.filter_design import (
    VARIANCE_FLOOR,
    FilterDesign,
    derived_acceleration_variance,
    steady_state_covariance,
)
from hydroarm.control.interface import Controller, ControlOutput, Reference
from hydroarm.control.linear import covariance_prediction, double_integrator_step, filter_covariance, kalman_correction
from hydroarm.model.dynamics import fixed_order
from hydroarm.model.dynamics.nominal import NominalModel
from hydroarm.model.real_loop.sensing import Actuator, ActuatorConfig, SensorConfig

EstimatorKind = Literal["auto", "none", "kalman"]


class EstimatorConfig(FrozenModel):
    """The state estimator in front of the controller.

    ``kind``: ``"none"`` (the controller sees the raw measurement), ``"kalman"`` (a
    steady-state Kalman filter per joint) or ``"auto"``: the Kalman filter behind any sensor
    other than the ideal q-and-v one or with a loop delay (:meth:`resolved_kind`: a controller
    is never handed an encoder's differenced velocity or a late state by default), else the
    controller's own default (the registry's: ``kalman`` for hydroarm's ID-MPCs, ``none`` for
    the paper's controllers, so the reproduction is unchanged).
    """

    kind: EstimatorKind = pydantic.Field(
        "auto",
        description="none, kalman, or auto (kalman behind a non-ideal sensor or a loop delay, else the controller's)",
    )
    measurement_variance: float | Literal["plant"] = pydantic.Field(
        "plant",
        description=(
            "sigma_m^2 the filter assumes on q and v (rad^2, (rad/s)^2), 0 <= x <= 10; "
            "'plant' = the plant's own (plant.noise_variance): a noise-free sensor gets a pass-through filter"
        ),
    )
    acceleration_variance: float | None = pydantic.Field(
        None,
        gt=0.0,
        le=1e8,
        description=(
            "sigma_a^2: variance of the acceleration the command misses ((rad/s^2)^2); null = derived from the "
            "sensor: 100 with q and v measured; position only min(100, 30^2 sigma_m^2 / T^4), sigma_m^2 = noise "
            "+ resolution^2 / 12: a tracking index of at most 30 (docs/robustness.md)"
        ),
    )
    measures: Literal["plant", "state", "position"] = pydantic.Field(
        "plant",
        description=(
            "what the filter corrects with: state (q and v), position (q alone, the velocity estimated), "
            "plant = position when sensor.velocity = 'differenced', else state"
        ),
    )
    delay: int | Literal["plant"] = pydantic.Field(
        "plant",
        description=(
            "loop delay the filter predicts across, 0 <= x <= 1000 (periods); plant = sensor.delay + actuator.delay"
        ),
    )
    repeated: Literal["skip", "use"] = pydantic.Field(
        "skip",
        description="a measurement equal to the previous one in every channel (a lost sample): skip = predict only",
    )

    @pydantic.field_validator("delay", mode="before")
    @classmethod
    def _delay_in_range(cls, value):
        if value == "plant":
            return value
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 1000:
            raise ValueError(f"must be 'plant' or a whole number of periods 0 <= x <= 1000, got {value!r}")
        return value

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

    def design(
        self, noise_variance: float | None, sensor: SensorConfig | None = None, loop_delay: int | None = None
    ) -> FilterDesign:
        """The :class:`FilterDesign` for a plant with ``noise_variance`` (``plant.noise_variance``,
        rad^2), ``sensor`` (None: the paper's, q and v measured) and a loop delay of
        ``loop_delay`` periods (``sensor.delay + actuator.delay``; None: the sensor's delay).
        ``acceleration_variance = null`` stays None: the filter derives it for its period
        (:func:`derived_acceleration_variance`)."""
        sensor = sensor if sensor is not None else SensorConfig()
        loop_delay = sensor.delay if loop_delay is None else loop_delay
        position_only = not self.measures_velocity(sensor)
        if self.measurement_variance == "plant":
            if noise_variance is None:
                raise ConfigError(
                    "estimator.measurement_variance = 'plant' needs the plant's noise variance: "
                    "give a variance 0 <= x <= 10 (rad^2)"
                )
            position = sensor.position_variance(noise_variance)
            velocity = sensor.variances(noise_variance)[1]
        else:
            position = velocity = float(self.measurement_variance)
        delay = loop_delay if self.delay == "plant" else int(self.delay)
        return FilterDesign(
            position_only, position, velocity, delay, min(sensor.delay, delay), self.acceleration_variance
        )

    def measures_velocity(self, sensor: SensorConfig | None = None) -> bool:
        """Whether the filter corrects with a measured velocity behind ``sensor`` (None: the
        paper's): ``measures = "state"``, or ``"plant"`` with ``sensor.velocity = "measured"``."""
        velocity = "measured" if sensor is None else sensor.velocity
        return self.measures == "state" or (self.measures == "plant" and velocity == "measured")

    def resolved_kind(self, default: str, sensor: SensorConfig | None = None, loop_delay: int = 0) -> str:
        """``"none"`` or ``"kalman"``: ``kind``, with ``"auto"`` resolved to ``"kalman"`` when the
        ``sensor`` is not the ideal one (:attr:`SensorConfig.ideal`: encoder-only, quantised,
        its own noise, delayed or dropping samples) or the loop has a delay (``loop_delay``
        periods), else to the controller's ``default``."""
        if self.kind != "auto":
            return self.kind
        if (sensor is not None and not sensor.ideal) or loop_delay > 0:
            return "kalman"
        return default

    def for_sensor(self, noise_variance: float) -> EstimatorConfig:
        """This config with ``measurement_variance = "plant"`` resolved to the sensor's
        ``noise_variance`` (rad^2); a numeric setting is kept."""
        if self.measurement_variance != "plant":
            return self
        return self.model_copy(update={"measurement_variance": float(noise_variance)})


class JointKalmanFilter:
    """Steady-state Kalman filters, one per joint, on the measured state [q, v] (2n,), or on
    the measured position alone (``design.position_only``; module docstring).

    ``gain`` (2, 2) on the state, (2, 1) on the position alone: the same for every joint (same
    model and variances); ``covariance``: the steady-state prior Sigma. :meth:`update` returns
    the filtered state (2n,). ``design``: what the filter is for (default: the state measured
    with ``config.measurement_variance`` on q and v, no delay).
    """

    def __init__(self, n_joints: int, period: float, config: EstimatorConfig, design: FilterDesign | None = None):
        if design is None:
            if config.measurement_variance == "plant":
                raise ConfigError(
                    "estimator.measurement_variance = 'plant' needs the plant's noise variance: resolve it with "
                    "EstimatorConfig.for_sensor(noise_variance), or give a variance 0 <= x <= 10 (rad^2)"
                )
            variance = float(config.measurement_variance)
            design = FilterDesign(False, variance, variance, 0 if config.delay == "plant" else int(config.delay))
        self.n = n_joints
        self.period = float(period)
        self.config = config
        self.design = design
        self.position_only = design.position_only
        self.delay = int(design.delay)
        self._skip_repeated = config.repeated == "skip"
        acceleration = config.acceleration_variance  # an explicit setting wins
        if acceleration is None:
            acceleration = design.acceleration_variance
        if acceleration is None:
            acceleration = derived_acceleration_variance(design.position_only, design.position_variance, period)
        self.acceleration_variance = float(acceleration)
        same = design.position_variance == design.velocity_variance
        variance = float(design.position_variance)
        self._exact = not design.position_only and same and variance == 0.0  # L = I: the measurement, bit for bit
        if self._exact:  # the prior is the process noise alone
            self.covariance = covariance_prediction(np.zeros((2, 2)), period, self.acceleration_variance)
            self.gain = np.eye(2)
        elif not design.position_only and same:  # the paper's sensor: one variance on q and v
            self.covariance = steady_state_covariance(period, variance, self.acceleration_variance)
            self._measurement, self._noise = np.eye(2), variance * np.eye(2)
            self.gain = kalman_correction(self.covariance, self._measurement, self._noise)[0]
        else:
            if design.position_only:
                measurement = np.array([[1.0, 0.0]])
                noise = np.array([[max(design.position_variance, VARIANCE_FLOOR)]])
            else:
                measurement = np.eye(2)
                noise = np.diag([max(design.position_variance, VARIANCE_FLOOR),
                                 max(design.velocity_variance, VARIANCE_FLOOR)])  # fmt: skip
            self.covariance = filter_covariance(period, measurement, noise, self.acceleration_variance)
            self.gain = kalman_correction(self.covariance, measurement, noise)[0]
            self._measurement, self._noise = measurement, noise
        self.reset()

    @property
    def posterior_covariance(self) -> np.ndarray:
        """``(I - L C) Sigma`` (2, 2): the steady-state covariance of the estimate's error after a
        correction, per joint (rad^2, rad^2/s, (rad/s)^2); zero on an exact sensor."""
        if self._exact:
            return np.zeros((2, 2))
        return kalman_correction(self.covariance, self._measurement, self._noise)[1]

    def reset(self) -> None:
        """Forget the estimate: the next measurement is taken as it is."""
        self._q: np.ndarray | None = None
        self._v: np.ndarray | None = None
        self._last: np.ndarray | None = None
        self.skipped = 0
        self._prior: np.ndarray | None = None  # None: the steady state (covariance, gain)
        self._posterior: np.ndarray | None = None  # set after a bridged sample, until the next predict

    def predict(self, acceleration: np.ndarray) -> None:
        """Advance the estimate by one period under the commanded ``acceleration`` (n,) rad/s^2."""
        if self._q is None:
            return
        if self._posterior is not None:  # bridging lost samples: the covariance grows
            self._prior = covariance_prediction(self._posterior, self.period, self.acceleration_variance)
            self._posterior = None
        period = self.period
        self._q, self._v = double_integrator_step(self._q, self._v, acceleration, period)

    def update(self, y: np.ndarray) -> np.ndarray:
        """Correct with the measurement ``y = [q, v]`` (2n,; v unused when ``position_only``);
        return the estimate (2n,). A repeat of the previous measurement is skipped
        (``estimator.repeated``): the prediction is returned."""
        n = self.n
        q_meas, v_meas = y[:n], y[n:]
        if self._q is None and self.position_only:
            self._q, self._v = q_meas.copy(), np.zeros(n)
            self._last = np.array(y, dtype=float)
        elif self._skip_repeated and self._last is not None and np.array_equal(y, self._last):
            self.skipped += 1  # a lost sample the sensor repeated: keep the prediction
            if not self._exact:
                self._posterior = self.covariance if self._prior is None else self._prior
        elif self._q is None or self._exact:
            self._q, self._v = q_meas.copy(), v_meas.copy()
            if self._skip_repeated:
                self._last = np.array(y, dtype=float)
        elif self.position_only:
            self._last = np.array(y, dtype=float)
            gain = self._gain_now()
            dq = q_meas - self._q
            self._q = self._q + gain[0, 0] * dq
            self._v = self._v + gain[1, 0] * dq
        else:
            self._last = np.array(y, dtype=float)
            dq, dv = q_meas - self._q, v_meas - self._v
            gain = self._gain_now()
            self._q = self._q + gain[0, 0] * dq + gain[0, 1] * dv
            self._v = self._v + gain[1, 0] * dq + gain[1, 1] * dv
        return np.concatenate([self._q, self._v])

    def _gain_now(self) -> np.ndarray:
        """The gain of this correction: the steady one, or after bridged samples the one of the
        grown prior ``P`` (``P C^T (C P C^T + R)^-1``: the lost samples' model error is
        corrected by the gap it built up over, not by one period's), until it is back within
        1e-9 of the steady gain."""
        prior, self._prior = self._prior, None
        if prior is None:
            return self.gain
        gain, posterior = kalman_correction(prior, self._measurement, self._noise)
        if np.allclose(gain, self.gain, rtol=1e-9, atol=0.0):
            return self.gain
        self._posterior = posterior
        return gain

    @property
    def estimate(self) -> np.ndarray | None:
        """The current estimate [q, v] (2n,), or None before the first measurement."""
        return None if self._q is None else np.concatenate([self._q, self._v])


class FilteredController:
    """Any controller behind a :class:`JointKalmanFilter` (see the module docstring).

    Same interface as the controller it wraps; ``name`` is the wrapped one's with ``+KF``.
    ``timings["estimator"]`` (s) is the filter's share of each step. With a loop delay of d
    periods (``kalman.delay``) the wrapped controller is given the filtered state predicted d
    periods ahead (:meth:`predicted`).
    """

    def __init__(
        self,
        controller: Controller,
        kalman: JointKalmanFilter,
        nominal: NominalModel,
        drives: ActuatorConfig | None = None,
    ):
        self.controller = controller
        self.kalman = kalman
        self.nominal = nominal
        self.name = f"{controller.name}+KF"
        self.control_period = controller.control_period
        self.delay = kalman.delay
        self.sensor_delay = kalman.design.sensor_delay
        self._steps = 0
        self._bridged = False
        self._filtered: np.ndarray | None = None
        self._next: np.ndarray | None = None
        self._accelerations: deque[np.ndarray] = deque(maxlen=self.delay + 1)
        self._torques: deque[np.ndarray] = deque(maxlen=self.delay + 1)
        lagging = drives is not None and (drives.rate_limit is not None or drives.bandwidth is not None)
        self.drives = drives if lagging or (drives is not None and drives.torque_limit is not None) else None
        self._drives: Actuator | None = None
        self._commands: deque[np.ndarray] = deque()
        self._corrections: deque[np.ndarray] = deque(maxlen=self.delay + 1)
        self.reset_drives()

    def reset_drives(self) -> None:
        """A fresh copy of the drives' model (``drives``: their clip, lag and rate limit)."""
        if self.drives is not None:
            n = self.kalman.n
            self._drives = Actuator(self.drives, n, self.kalman.period)
            self._commands = deque(maxlen=self.delay - self.sensor_delay + 1)
        self._corrections.clear()

    def _drive_correction(self, state: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """The acceleration (n,) the drives add this step to the command acting now: the drives'
        model given ``tau`` (n,) N m, its output against the command it answers (the one of
        ``actuator.delay`` steps ago, none before), through the dry M(q) at ``state`` (2n,).
        Zero without a drives' model."""
        n = self.kalman.n
        if self._drives is None:
            return np.zeros(n)
        applied = self._drives.apply(tau)
        self._commands.append(tau)
        nominal = self._commands[0] if len(self._commands) == self._commands.maxlen else np.zeros(n)
        difference = applied - nominal
        if not np.any(difference):
            return np.zeros(n)
        return fixed_order.spd_solve(self.nominal.mass_matrix(state[:n]), difference)

    def reset(self) -> None:
        self.controller.reset()
        self.kalman.reset()
        self._filtered = None
        self._next = None
        self._accelerations.clear()
        self._torques.clear()
        self.reset_drives()
        self._steps = 0
        self._bridged = False

    def _unforced(self, state: np.ndarray) -> np.ndarray:
        """The dry model's acceleration (n,) at ``state`` with no torque: before the first
        commands arrive, the drives apply none."""
        n = self.kalman.n
        return self.nominal.forward_dynamics(state[:n], state[n:], np.zeros(n))

    def predicted(self, filtered: np.ndarray) -> np.ndarray:
        """The filtered state (2n,) stepped on the double integrator, under the commanded
        accelerations still in flight, to the step this step's command acts at (``filtered``
        itself when there is no delay).

        At step k the filtered state is of step m = max(k - d_s, 0) (d_s: the sensor's delay;
        the first sample is held until then) and the command acts from step k + d_a (d_a = d -
        d_s: the drives' delay): ``min(k, d_s) + d_a`` steps, the acceleration of step j being
        the command of step j - d_a, none (the dry model unforced) while j < d_a. Once k >= d_s
        that is d steps under the last d commands."""
        d = self.delay
        if d == 0:
            return filtered
        n, period = self.kalman.n, self.period_
        q, v = filtered[:n].copy(), filtered[n:].copy()
        steps = min(self._steps, self.sensor_delay) + d - self.sensor_delay
        flight = list(self._accelerations)[-steps:] if self._accelerations and steps > 0 else []
        missing = steps - len(flight)
        past = min(self._steps, self.sensor_delay)  # steps already acted: the drives' output is known
        for k in range(steps):
            if k < missing:
                acceleration = self._unforced(np.concatenate([q, v]))
            else:
                acceleration = flight[k - missing]
            if k < past and past - k <= len(self._corrections):
                acceleration = acceleration + self._corrections[k - past]
            q, v = double_integrator_step(q, v, acceleration, period)
        return np.concatenate([q, v])

    @property
    def period_(self) -> float:
        return self.kalman.period

    def compute(self, t: float, y: np.ndarray, reference: Reference) -> ControlOutput:
        start = time.perf_counter()
        filtered = self._next if self._next is not None else self.kalman.update(np.asarray(y, dtype=float))
        self._next = None
        state = self.predicted(filtered)
        tell_drive_limits(self.controller, self._drives)  # the drives' rate limit, if any
        elapsed = time.perf_counter() - start
        out = self.controller.compute(t, state, reference)
        start = time.perf_counter()
        n = self.kalman.n
        if out.acceleration is not None:
            acceleration = np.asarray(out.acceleration, dtype=float)
        else:
            acceleration = self.nominal.forward_dynamics(state[:n], state[n:], out.tau)
        correction = self._drive_correction(state, np.asarray(out.tau, dtype=float))
        if self.delay == 0:
            self.kalman.predict(acceleration + correction if self._drives is not None else acceleration)
        else:
            self._accelerations.append(acceleration)
            self._torques.append(np.asarray(out.tau, dtype=float))
            self._corrections.append(correction)
            full = len(self._accelerations) == self.delay + 1
            if self._steps >= self.sensor_delay:  # before: the first sample is held, the filter waits at t = 0
                acting = self._accelerations[0] if full else self._unforced(filtered)
                lag = self._corrections[-(self.sensor_delay + 1)] if self._drives is not None else 0.0
                self.kalman.predict(acting + lag)
        self._steps += 1
        self._filtered = filtered
        out.timings["estimator"] = elapsed + time.perf_counter() - start
        out.timings["total"] = out.timings.get("total", 0.0) + out.timings["estimator"]
        return out

    def observe(self, t: float, y: np.ndarray, u: np.ndarray, y_next: np.ndarray) -> None:
        """Filter ``y_next`` (it is the next step's measurement too) and pass the filtered
        transition to the wrapped controller, with the torque that acted during it (with a
        loop delay of d periods: the command of d steps ago; none before the first arrives).
        A transition into or out of a lost sample the filter bridged is not passed on."""
        skipped = self.kalman.skipped
        filtered_next = self.kalman.update(np.asarray(y_next, dtype=float))
        self._next = filtered_next
        held = self._steps <= self.sensor_delay  # the first sample, held until the sensor's delay has passed
        bridged, self._bridged = self._bridged, self.kalman.skipped > skipped and not held
        if bridged or self._bridged:  # a lost sample bridged by the prediction: nothing to learn from
            return
        previous = self._filtered if self._filtered is not None else np.asarray(y, dtype=float)
        if self.delay == 0:
            self.controller.observe(t, previous, u, filtered_next)
        elif len(self._torques) == self.delay + 1:
            self.controller.observe(t - self.delay * self.period_, previous, self._torques[0], filtered_next)
