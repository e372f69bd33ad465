"""The paper scenario, built by :func:`hydroarm.sim.experiment.build_experiment`.

Every section of the suite takes its plant, controller and reference from here, so the
benchmark runs exactly what ``hydroarm run`` runs (the default ``ExperimentConfig``:
the paper arm, the paper task from its start, the true underwater plant).
"""

from __future__ import annotations

import time
from typing import Any

from hydroarm.sim.experiment import Experiment, ExperimentConfig, build_experiment, with_overrides


def paper_config(duration: float = 10.0, overrides: dict[str, Any] | None = None) -> ExperimentConfig:
    """The default settings (the paper scenario) over ``duration`` s, with dotted-key overrides."""
    config = ExperimentConfig(duration=float(duration))
    return with_overrides(config, overrides) if overrides else config


def paper_experiment(controller: str, duration: float = 10.0, overrides: dict[str, Any] | None = None) -> Experiment:
    """``controller`` on the paper scenario (:func:`build_experiment` of :func:`paper_config`)."""
    return build_experiment(paper_config(duration, overrides), controller)


class TimedController:
    """Wraps a controller so that ``observe`` is timed too (compute times itself);
    ``on_compute(controller, t, y, out)`` is called after every ``compute``. ``cpu_s``: each
    step's compute + observe in this thread's CPU time (``time.thread_time_ns``: the time the
    step ran, without the time other processes held the core; on a loaded machine the wall
    time's tail is mostly the latter); ``wall_s``: the same in wall time. ``paced``: each compute
    starts no earlier than its tick (the first compute's time + k control periods), as in a loop
    driven by a real arm's clock: what runs beside the loop (a planner's worker process) gets the
    wall time it would have; the simulation otherwise runs the loop many times faster than real
    time."""

    def __init__(self, controller, on_compute=None, paced: bool = False) -> None:
        self.inner = controller
        self.name = controller.name
        self.control_period = controller.control_period
        self.observe_s: list[float] = []
        self.cpu_s: list[float] = []
        self.wall_s: list[float] = []
        self.on_compute = on_compute
        self.paced = paced
        self._first_tick: float | None = None

    def reset(self) -> None:
        self.inner.reset()
        self.observe_s.clear()
        self.cpu_s.clear()
        self.wall_s.clear()
        self._first_tick = None

    def _wait_for_tick(self) -> None:
        """Sleep until this step's tick (``paced``; a late step starts at once)."""
        now = time.perf_counter()
        if self._first_tick is None:
            self._first_tick = now
            return
        delay = self._first_tick + len(self.cpu_s) * self.control_period - now
        if delay > 0:
            time.sleep(delay)

    def compute(self, t, y, reference):
        if self.paced:
            self._wait_for_tick()
        cpu, wall = time.thread_time_ns(), time.perf_counter_ns()
        out = self.inner.compute(t, y, reference)
        self.cpu_s.append((time.thread_time_ns() - cpu) * 1e-9)
        self.wall_s.append((time.perf_counter_ns() - wall) * 1e-9)
        if self.on_compute is not None:
            self.on_compute(self.inner, t, y, out)
        return out

    def observe(self, t, y, u, y_next) -> None:
        cpu = time.thread_time_ns()
        start = time.perf_counter_ns()
        self.inner.observe(t, y, u, y_next)
        self.observe_s.append((time.perf_counter_ns() - start) * 1e-9)
        if self.cpu_s:
            self.cpu_s[-1] += (time.thread_time_ns() - cpu) * 1e-9
            self.wall_s[-1] += self.observe_s[-1]


def closed_loop(name: str, duration: float, seed: int = 0, on_compute=None):
    """(trajectory, observe times (s), wall time (s), controller) of one run on the true plant."""
    experiment = paper_experiment(name, duration)
    timed = TimedController(experiment.controller, on_compute)
    experiment.controller = timed
    start = time.perf_counter()
    traj = experiment.run(seed)
    wall = time.perf_counter() - start
    return traj, list(timed.observe_s), wall, timed.inner
