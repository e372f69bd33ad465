"""The plant protocol: what the one runner (:func:`hydroarm.sim.runner.run_closed_loop`) needs
of a true plant.

Three plants follow it: the fixed-base arm (:class:`hydroarm.model.arm.plant.UnderwaterPlant`,
x = [q, v], u = tau) and the vehicle with its arm, exact and compiled
(:class:`hydroarm.model.vehicle.plant.UVMSPlant`, :class:`hydroarm.model.vehicle.fast.FastUVMSPlant`:
x = [q (7 + n), v (6 + n), thrust (n_thr)], u = [tau_arm, thrust command]). The runner
records the joints of every plant the same way (``Trajectory.x``, ``y``, ``u`` hold the arm's
[q, v] and torques) and whatever else a plant's state holds as ``Trajectory.extra`` arrays.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class StepResult(Protocol):
    """What a plant step reports beside the new state: ``disturbance`` (n,) N m, the arm's
    generalised force beyond the dry model over the step (NaN where the plant cannot separate
    it)."""

    disturbance: np.ndarray


@runtime_checkable
class Plant(Protocol):
    """A true plant: ``n`` tracked joints, ``n_inputs`` inputs, states of ``state_size``.

    * ``step(t, x, u, dt) -> (x_next, info)``: integrate over ``dt`` s from state ``x`` under
      the input ``u`` (n_inputs,) held constant; ``info`` a :class:`StepResult`;
    * ``measure(x, rng) -> y``: what the sensors give of ``x`` (seeded by ``rng``);
    * ``new_sensor(period, rng, seed)``, ``new_actuator(period)``: a run's own sensor (its
      ``sample(x)`` replaces ``measure``: delays, dropout, quantisation) and drives (their
      ``apply(tau)`` gives the torque that acts), or None for the ideal ones;
    * ``joint_state(x) -> (2n,)``: the arm's [q, v] of a state;
    * ``state_record(x) -> {name: array}``: what else of a state a trajectory keeps.
    """

    n: int
    n_inputs: int
    state_size: int

    def step(self, t: float, x: np.ndarray, u: np.ndarray, dt: float) -> tuple[np.ndarray, StepResult]: ...

    def measure(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray: ...

    def new_sensor(self, period: float, rng: np.random.Generator, seed: int) -> Any | None: ...

    def new_actuator(self, period: float) -> Any | None: ...

    def joint_state(self, x: np.ndarray) -> np.ndarray: ...

    def state_record(self, x: np.ndarray) -> dict[str, np.ndarray]: ...
