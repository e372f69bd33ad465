"""The one closed loop's blocks: plant, sensor and drives, with the controller's slot outside.

python-control's ``interconnect`` is the model: blocks joined by named signals. One control
step k of period T:

```
 x_k ──sensor──> y_k ──(controller: the runner's, a Gymnasium agent, a ROS 2 node)──> u_k
  ▲                                                                                   │
  └──── plant.step(t_k, x_k, a_k, T) <──── a_k = drives(u_k) <─────────────────────────┘
```

Signals: ``x`` the plant's true state (``plant.state_size``,), ``y`` the measurement the
controller sees (what the plant's sensor delivers: :mod:`hydroarm.model.real_loop.sensing`; the plant's own
:meth:`~hydroarm.sim.plant_protocol.Plant.measure` when the sensor is ideal), ``u`` the command, ``a``
the torque the drives apply and hold for the period (``u`` itself when the drives are ideal).

:class:`Loop` owns the sensor and drives of one run (fresh on every :meth:`Loop.reset`), the
held last valid measurement (a non-finite sample is replaced by it and reported, so that a
learning controller can skip the step) and the true state. The runner
(:func:`hydroarm.sim.runner.run_closed_loop`) and the Gymnasium arm env
(:class:`hydroarm.envs.underwater_arm.UnderwaterArmEnv`) both run it, so every sensor and drive
setting reaches both. The controller is not a block here: the runner fills the slot, the env
leaves it to the agent, and each keeps its own fault handling.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hydroarm.sim.plant_protocol import Plant


@dataclass(frozen=True)
class LoopStep:
    """One control step's signals: the state the step started from ``x`` and ended at ``x_next``
    (``plant.state_size``,), the torque the drives applied ``applied`` (``plant.n_inputs``,) N m,
    and the plant's step record ``info`` (its ``disturbance`` (n,) N m)."""

    x: np.ndarray
    x_next: np.ndarray
    applied: np.ndarray
    info: Any


class Loop:
    """Plant, sensor and drives of one closed loop of control period ``period`` (s).

    ``reset(x0, rng, seed)`` starts a run: fresh sensor and drives (the plant's
    :meth:`~hydroarm.sim.plant_protocol.Plant.new_sensor` / ``new_actuator``: None when ideal), the true
    state ``x0``, the first measurement. ``step(t, command)`` applies the command through the
    drives and integrates the plant one period; ``measure_next()`` then moves the loop to the new
    state and measures it. The split lets the runner stop on a diverged state before the sensor
    draws again (the draws, and so the numbers, stay those of one sequence).
    """

    def __init__(self, plant: Plant, period: float):
        self.plant = plant
        self.period = float(period)
        self.sensor = None
        self.actuator = None
        self.rng: np.random.Generator | None = None
        self.x = np.zeros(plant.state_size)
        self.y = self.x.copy()
        self.y_valid = True
        self._last_valid = self.x.copy()
        self._pending: LoopStep | None = None

    def reset(self, x0: np.ndarray, rng: np.random.Generator, seed: int) -> np.ndarray:
        """Start a run at the true state ``x0`` with the measurement noise drawn from ``rng`` and
        the sensor's dropout seeded by ``seed``; returns the first measurement y_0 (a copy)."""
        self.rng = rng
        self.sensor = self.plant.new_sensor(self.period, rng, seed)
        self.actuator = self.plant.new_actuator(self.period)
        self.x = np.asarray(x0, dtype=float).copy()
        self._last_valid = self.x.copy()  # before any valid measurement: the known initial state
        self._pending = None
        self.y, self.y_valid = self._measure(self.x)
        return self.y.copy()

    @property
    def ideal_drives(self) -> bool:
        """True when the torque acts as commanded, at once (no drive model)."""
        return self.actuator is None

    def _measure(self, state: np.ndarray) -> tuple[np.ndarray, bool]:
        measured = self.plant.measure(state, self.rng) if self.sensor is None else self.sensor.sample(state)
        if np.all(np.isfinite(measured)):
            self._last_valid = measured
            return measured, True
        return self._last_valid.copy(), False

    def step(self, t: float, command: np.ndarray) -> LoopStep:
        """Apply ``command`` (``plant.n_inputs``,) N m through the drives at time ``t`` (s) and
        integrate the plant one period from the current state. The loop's state moves only at
        :meth:`measure_next`."""
        applied = command if self.actuator is None else self.actuator.apply(command)
        x_next, info = self.plant.step(t, self.x, applied, self.period)
        self._pending = LoopStep(self.x, x_next, applied, info)
        return self._pending

    def measure_next(self) -> tuple[np.ndarray, bool]:
        """Move to the state the last :meth:`step` reached and measure it: ``(y, valid)``,
        ``valid`` False when the sample was not finite and the last valid one is held."""
        if self._pending is None:
            raise RuntimeError("Loop.measure_next() needs a step() first")
        self.x = self._pending.x_next
        self._pending = None
        self.y, self.y_valid = self._measure(self.x)
        return self.y, self.y_valid

    def sensor_counts(self) -> dict[str, int] | None:
        """The sensor's samples and dropped samples so far; None for the ideal sensor."""
        if self.sensor is None:
            return None
        return {"samples": self.sensor.samples, "dropped": self.sensor.dropped}
