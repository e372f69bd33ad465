"""The real loop around the true plant: what the sensor delivers and what the drives apply.

A :class:`Sensor` turns the true state x_k = [q, v] (2n,) into the measurement y_k the
controller sees, once per control period T, in this order:

1. noise: q + N(0, sigma_q^2), and in ``velocity = "measured"`` mode v + N(0, sigma_v^2)
   (``sensor.position_noise`` / ``velocity_noise``; null = ``plant.noise_variance``, the
   paper's one variance on both);
2. quantisation: the position is rounded to the encoder's count grid,
   ``resolution * round(q / resolution)`` (rad; 0 = continuous);
3. encoder-only sensing (``velocity = "differenced"``): the velocity is the backward difference
   of the quantised positions, ``(q_k - q_{k-1}) / T`` (0 at the first sample), and v is not
   measured at all;
4. delay: the controller gets the sample taken ``delay`` periods earlier (the first sample
   until then);
5. dropout: with probability ``dropout`` a period's sample does not arrive and the previous
   delivered measurement repeats (never the first).

The true state is never touched. The noise comes from the run's generator (the run seed); the
dropout draws from a generator of its own seeded by the same run seed, so switching dropout on
changes no noise sample. With every setting at its default the measurement is exactly
:meth:`~hydroarm.model.arm.plant.UnderwaterPlant.measure`'s (the same draws, the same numbers).

An :class:`Actuator` turns the commanded torque u_k (n,) into the applied torque, held for
the period (the drive updates at the control rate): ``delay`` periods late (0 N m until the
first command arrives), clipped to ``torque_limit``, then a first-order lag of bandwidth f
(Hz), exact for a held input, ``a_k = a_{k-1} + (1 - exp(-2 pi f T)) (u - a_{k-1})``, and the
rate limit ``|a_k - a_{k-1}| <= rate_limit T`` (N m/s); a_{-1} = 0. Per joint: one value or
one per joint; null = no such limit.
"""

from __future__ import annotations

from collections import deque
from typing import Annotated, Literal

import numpy as np
import pydantic

from hydroarm.config import FrozenModel, per_joint

DROPOUT_STREAM = 0x5E7502
"""Mixed with the run seed to seed the dropout draws (``default_rng([seed, DROPOUT_STREAM])``)."""

Variance = Annotated[float, pydantic.Field(ge=0.0, le=10.0)]
PositiveLimit = Annotated[float, pydantic.Field(gt=0.0, le=1e9)]


class SensorConfig(FrozenModel):
    """What the controller's measurement is made of (module docstring); ideal by default."""

    velocity: Literal["measured", "differenced"] = pydantic.Field(
        "measured",
        description="measured: q and v are both sensed; differenced: encoder-only, v = (q_k - q_{k-1}) / T",
    )
    resolution: float = pydantic.Field(
        0.0, ge=0.0, le=float(np.pi), description="encoder quantum, rad per count; 0 = continuous (rad)"
    )
    position_noise: Variance | None = pydantic.Field(
        None, description="variance of the noise on q; null = plant.noise_variance (rad^2)"
    )
    velocity_noise: Variance | None = pydantic.Field(
        None, description="variance of the noise on a measured v; null = plant.noise_variance ((rad/s)^2)"
    )
    delay: int = pydantic.Field(
        0, ge=0, le=1000, description="the measurement arrives this many control periods late (periods)"
    )
    dropout: float = pydantic.Field(
        0.0, ge=0.0, lt=1.0, description="probability that a period's sample is lost and the previous repeats (-)"
    )

    @property
    def ideal(self) -> bool:
        return (
            self.velocity == "measured"
            and self.resolution == 0.0
            and self.position_noise is None
            and self.velocity_noise is None
            and self.delay == 0
            and self.dropout == 0.0
        )

    def variances(self, noise_variance: float) -> tuple[float, float]:
        """``(sigma_q^2, sigma_v^2)`` of the added noise given ``plant.noise_variance``."""
        q = noise_variance if self.position_noise is None else self.position_noise
        v = noise_variance if self.velocity_noise is None else self.velocity_noise
        return float(q), float(v)

    def position_variance(self, noise_variance: float) -> float:
        """The variance of the delivered position's error (rad^2): the noise plus the uniform
        quantisation error's ``resolution^2 / 12``."""
        return self.variances(noise_variance)[0] + self.resolution**2 / 12.0


class ActuatorConfig(FrozenModel):
    """What the drives do to the commanded torque (module docstring); ideal by default."""

    delay: int = pydantic.Field(
        0, ge=0, le=1000, description="the command is applied this many control periods late (periods)"
    )
    torque_limit: PositiveLimit | list[PositiveLimit] | None = pydantic.Field(
        None, description="the drives clip |tau_i| to this, per joint; null = no clipping in the plant (N m)"
    )
    rate_limit: PositiveLimit | list[PositiveLimit] | None = pydantic.Field(
        None, description="largest |d tau / dt| the drives deliver, per joint; null = unlimited (N m/s)"
    )
    bandwidth: PositiveLimit | list[PositiveLimit] | None = pydantic.Field(
        None, description="first-order lag of the drives, per joint; null = none (Hz)"
    )

    @property
    def ideal(self) -> bool:
        return self.delay == 0 and self.torque_limit is None and self.rate_limit is None and self.bandwidth is None


class Sensor:
    """One run's sensor (stateful; module docstring). ``sample(x)`` once per period."""

    def __init__(
        self, config: SensorConfig, n: int, period: float, noise_variance: float, rng: np.random.Generator, seed: int
    ):
        self.config = config
        self.n = n
        self.period = float(period)
        self.noise_variance = float(noise_variance)
        self.rng = rng
        self.position_sd, self.velocity_sd = (float(np.sqrt(s)) for s in config.variances(noise_variance))
        self.dropout_rng = np.random.default_rng([int(seed), DROPOUT_STREAM])
        self.dropped = 0
        self.samples = 0
        self._previous_q: np.ndarray | None = None
        self._queue: deque[np.ndarray] = deque(maxlen=config.delay + 1)
        self._delivered: np.ndarray | None = None

    def _fresh(self, x: np.ndarray) -> np.ndarray:
        n, config = self.n, self.config
        if config.velocity == "measured" and config.position_noise is None and config.velocity_noise is None:
            if self.noise_variance == 0.0:  # the paper's sensor, draw for draw
                y = np.array(x, dtype=float)
            else:
                y = x + self.rng.normal(0.0, np.sqrt(self.noise_variance), size=x.shape)
        else:
            q = np.array(x[:n], dtype=float)
            if self.position_sd > 0.0:
                q = q + self.rng.normal(0.0, self.position_sd, size=n)
            if config.velocity == "measured":
                v = np.array(x[n:], dtype=float)
                if self.velocity_sd > 0.0:
                    v = v + self.rng.normal(0.0, self.velocity_sd, size=n)
            else:
                v = np.zeros(n)
            y = np.concatenate([q, v])
        if config.resolution > 0.0:
            y[:n] = config.resolution * np.round(y[:n] / config.resolution)
        if config.velocity == "differenced":
            q = y[:n]
            if self._previous_q is not None:
                y[n:] = (q - self._previous_q) / self.period
            self._previous_q = q.copy()
        return y

    def sample(self, x: np.ndarray) -> np.ndarray:
        """The measurement (2n,) delivered this period from the true state x (2n,)."""
        self._queue.append(self._fresh(x))
        delivered = self._queue[0]
        if self._delivered is not None and self.config.dropout > 0.0:
            if self.dropout_rng.random() < self.config.dropout:
                delivered = self._delivered
                self.dropped += 1
        self.samples += 1
        self._delivered = delivered
        return delivered.copy() if delivered is not None else delivered


class Actuator:
    """One run's drives (stateful; module docstring). ``apply(u)`` once per period."""

    def __init__(self, config: ActuatorConfig, n: int, period: float):
        self.config = config
        self.n = n
        self.period = float(period)
        limit = config.torque_limit
        self.torque_limit = None if limit is None else per_joint(limit, n, "actuator.torque_limit")
        rate = config.rate_limit
        self.max_step = None if rate is None else per_joint(rate, n, "actuator.rate_limit") * self.period
        bandwidth = config.bandwidth
        self.lag = (
            None
            if bandwidth is None
            else 1.0 - np.exp(-2.0 * np.pi * per_joint(bandwidth, n, "actuator.bandwidth") * self.period)
        )
        self._queue: deque[np.ndarray] = deque([np.zeros(n)] * config.delay, maxlen=config.delay + 1)
        self._applied = np.zeros(n)

    def apply(self, u: np.ndarray) -> np.ndarray:
        """The torque (n,) the plant gets this period for the command u (n,) N m."""
        self._queue.append(np.asarray(u, dtype=float))
        target = self._queue.popleft() if self.config.delay > 0 else self._queue.pop()
        self._applied = self._output(self._applied, target)
        return self._applied.copy()

    def _output(self, previous: np.ndarray, target: np.ndarray) -> np.ndarray:
        """The output (n,) N m of one period that follows the output ``previous`` with the command
        ``target`` arriving (clip, lag, rate limit: module docstring)."""
        if self.torque_limit is not None:
            target = np.clip(target, -self.torque_limit, self.torque_limit)
        applied = target
        if self.lag is not None:
            applied = previous + self.lag * (applied - previous)
        if self.max_step is not None:
            applied = previous + np.clip(applied - previous, -self.max_step, self.max_step)
        return np.array(applied, dtype=float)

    def pending_output(self) -> np.ndarray:
        """The output (n,) N m the drives give in the period before the next command acts: their
        output now with the ``delay`` commands already on their way passed through first (the
        output now without a delay). A command within ``rate_limit T`` of it is not slowed by the
        rate limit (nor by the lag, which moves less than its target)."""
        output = self._applied
        for target in self._queue:  # the commands in flight, oldest first (delay of them)
            output = self._output(output, target)
        return output.copy()
