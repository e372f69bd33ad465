"""PI-IDMPC's planner beside the loop (``pi_idmpc.plan_latency`` L > 0): the plan of step k is solved
at step k - L from the state predicted for step k, in the control step (``plan_worker = "inline"``)
or by a forked worker process (``"process"``) whose answer step k takes: the same run either way,
since a job's inputs are its step's, not the time it takes.

:class:`LatentPlanner` holds the schedule (which step launches a plan, which plan a step follows)
and the worker; the plans themselves are the controller's
(:meth:`hydroarm.control.pi_idmpc.PhysicsInformedIDMPC._replan`). :func:`_serve_plans` is the
worker process's loop.
"""

from __future__ import annotations

import multiprocessing
import time
from collections import deque
from typing import Any

import numpy as np

from hydroarm.control.interface import Reference
from hydroarm.model.dynamics import fixed_order


class LatentPlanner:
    """The plans of a :class:`~hydroarm.control.pi_idmpc.PhysicsInformedIDMPC` solved ``plan_latency``
    steps ahead (module docstring). ``controller``: the one whose plans these are (its ``config``,
    ``mpc``, ``model``, ``_replan``). Attributes: ``worker`` ((process, connection) of
    ``plan_worker = "process"``, or None) and the last step's solve times (s) ``replan_time``,
    ``replan_cpu``, ``wait_time`` (:meth:`timings`)."""

    def __init__(self, controller: Any):  # a PhysicsInformedIDMPC (not imported: it imports this module)
        self.controller = controller
        self.config = controller.config
        self.worker = None  # (process, connection) of plan_worker = "process"
        self._worker_reference = None

    def reset(self) -> None:
        """Forget the run's plans and restart the worker (it forks a copy of the controller as it
        is now: call this last in the controller's reset)."""
        self._step = 0  # control steps this run (plan_latency's clock)
        self._pending: deque[tuple[int, tuple | None]] = deque()  # (the step a plan starts at, plan or None)
        self._launched_at: int | None = None  # the step the newest plan launched starts at
        self._chain = False  # plans are being launched (auto: until one has no active torque row)
        self._in_flight: deque[int] = deque()  # the steps of the plans the worker is solving
        self._history: deque[tuple[int, tuple | None]] = deque(maxlen=self.config.plan_latency + 1)
        self.replan_time = self.replan_cpu = self.wait_time = 0.0
        self.close()  # a worker's copy holds the run that ends here
        if self.controller.planner is not None and self.config.plan_worker == "process":
            self._start_worker()

    def take(self, plan: tuple | None, plan_step: int) -> tuple[tuple | None, int]:
        """The plan this step follows and its step in it, from the one followed so far: the plan
        solved ``plan_latency`` steps ago for this step (blocking only while the worker is late), or
        the last one within ``planner_hold`` steps, or None. ``"auto"``: a plan with no active
        torque row (or refused) ends the chain of launches."""
        k = self._step
        self.replan_time = self.wait_time = self.replan_cpu = 0.0
        if self._in_flight and self._in_flight[0] == k:
            self._in_flight.popleft()
            self._receive()  # the job launched L steps ago
        if self._pending and self._pending[0][0] == k:
            plan, plan_step = self._pending.popleft()[1], 0
            if self.config.planner == "auto" and (plan is None or not plan[5]):
                self._chain = False
        elif plan is not None:
            plan_step += 1
            if plan_step >= self.config.planner_hold:
                plan = None  # no newer plan: the chain stopped (auto) or its last plan was refused
        return plan, plan_step

    def launch(self, t: float, y: np.ndarray, reference: Reference, torque: np.ndarray, fits: bool) -> None:
        """After step k's torque: launch the plan of step k + L (:meth:`plan_job`) if one is
        due (the newest launched covers k + L within ``planner_hold`` no more) and wanted
        (``"always"``; ``"auto"``: the chain runs, or the IDMPC's own move of this step does not fit
        the limits, ``fits`` False). It is solved here (``plan_worker = "inline"``) or handed to
        the worker process (``"process"``), and step k + L takes it. The job's inputs are the
        step's (state, torque (n,), the water model's estimate and the remainder's
        of now), so the run is the same either way."""
        k = self._step
        self._step += 1
        target, last = k + self.config.plan_latency, self._launched_at
        if last is not None and target < last + self.config.planner_hold:
            return  # the newest plan launched still covers step k + L
        if self.config.planner == "auto" and not self._chain and fits:
            return  # the limits do not bind: the IDMPC's own plan
        shift = target - last if (self._chain and last is not None) else None  # warm from the newest, or cold
        self._chain, self._launched_at = True, target
        if self.config.plan_worker == "inline":
            start = time.perf_counter()
            self._pending.append(self.plan_job(k, t, y, reference, torque, shift))
            self.replan_time = time.perf_counter() - start
            return
        if self.worker is None:
            self._start_worker()
        sent = None if reference is self._worker_reference else reference  # pickled once per reference
        self._worker_reference = reference
        controller = self.controller
        job = (k, t, np.asarray(y, dtype=float), np.asarray(torque, dtype=float), shift, controller.model.theta,
               controller._rest)  # fmt: skip
        self.worker[1].send((*job, sent))
        self._in_flight.append(target)

    def timings(self) -> dict[str, float]:
        """This step's solve (s): inline, within the step (``replan``); with the worker, its own time
        on the job answered this step (``replan`` wall, ``replan_cpu``) and what the step waited for
        it (``wait``, within the step's ``total``)."""
        timings = {"replan": self.replan_time}
        if self.worker is not None:
            timings["wait"] = self.wait_time
            timings["replan_cpu"] = self.replan_cpu
        return timings

    def _receive(self) -> None:
        """The worker's answer to the oldest job: its plan, its counts and its time."""
        start = time.perf_counter()
        try:
            answer = self.worker[1].recv()
        except EOFError:
            answer = ("error", "it ended")
        self.wait_time = time.perf_counter() - start
        if answer[0] == "error":
            self.close()
            raise RuntimeError(f"PI-IDMPC's planner worker process failed: {answer[1]}")
        launched, plans, rejected, seconds = answer
        self._pending.append(launched)
        self.controller.plans += plans
        self.controller.rejected += rejected
        self.replan_time, self.replan_cpu = seconds  # the worker's own time on this solve, wall and CPU

    def _start_worker(self) -> None:
        """Fork the worker: a copy of the controller (the plans launched so far included) that
        answers jobs in order (:func:`_serve_plans`); at :meth:`reset`, before the loop runs."""
        self.close()
        warm_kernels(self.controller)
        context = multiprocessing.get_context("fork")
        mine, theirs = context.Pipe()
        self._worker_reference = None
        process = context.Process(target=_serve_plans, args=(self, theirs), daemon=True)
        process.start()
        theirs.close()
        self.worker = (process, mine)

    def close(self) -> None:
        """Stop the worker process, if one runs (``plan_worker = "process"``)."""
        worker, self.worker = self.worker, None
        if worker is not None:
            process, connection = worker
            try:
                connection.send(None)
            except OSError:
                pass
            connection.close()
            process.join(timeout=5.0)
            if process.is_alive():
                process.terminate()

    def plan_job(self, k, t, y, reference, torque, shift) -> tuple[int, tuple | None]:
        """Step k's job: ``(k + L, plan or None)``, the plan of step k + L (L = ``plan_latency``)
        from the state predicted for it (:meth:`predicted_state`: this step's torque ``torque``
        (n,) N m, then those of the plans already launched for the steps between), warm-started
        from the newest plan launched, ``shift`` steps before this one (None: cold). Its result
        depends on its inputs only, not on when it ends."""
        controller = self.controller
        latency = self.config.plan_latency
        y_hat = self.predicted_state(k, t, y, reference, torque)
        t_hat = t + latency * controller.control_period
        idmpc = controller.mpc.planned_acceleration(t_hat, y_hat, reference, remember=False)
        warm = None
        if shift is not None and self._history and self._history[-1][1] is not None:
            warm = (self._history[-1][1][3], self._history[-1][1][4], shift)
        plan = controller._replan(t_hat, y_hat, reference, idmpc, warm)
        self._history.append((k + latency, plan))
        return k + latency, plan

    def predicted_state(self, k, t, y, reference, torque) -> np.ndarray:
        """The state (2n,) step k + L will measure, from step k's state y (2n,) and torque (n,)
        N m: the model (the dry arm, the water model's terms and the remainder's estimate of
        now) under each period's torque held (:func:`model_period`, ``plan_prediction_steps`` RK4
        steps a period); the torque of a step between
        is its predicted move's, held within the limits (:meth:`_predicted_torque`)."""
        controller = self.controller
        n, period = controller.n, controller.control_period
        q, v = y[:n].copy(), y[n:].copy()
        tau = np.asarray(torque, dtype=float)
        for j in range(1, self.config.plan_latency + 1):
            q, v = model_period(controller, q, v, tau, period, self.config.plan_prediction_steps)
            if j < self.config.plan_latency:
                tau = self._predicted_torque(k + j, t + j * period, q, v, reference)
        return np.concatenate([q, v])

    def _predicted_torque(self, step, t, q, v, reference) -> np.ndarray:
        """The torque (n,) N m a later step ``step`` will command at the predicted state (q, v): the
        move of the newest plan launched for a step at or before it, within its hold, or the
        IDMPC's own move, held within the limits on the model
        (:meth:`PhysicsInformedIDMPC._held`)."""
        controller = self.controller
        move = None
        for start, plan in reversed(self._history):
            if start <= step:
                if plan is not None and step - start < self.config.planner_hold:
                    move = controller._plan_acceleration(plan, step - start, q, v)
                break
        if move is None:
            move = controller.mpc.planned_acceleration(t, np.concatenate([q, v]), reference, remember=False)
        mass, bias = model_terms(controller, q, v)
        return controller._held(mass, bias, move)[0]


def model_terms(controller: Any, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(M + M_A (n, n), h - w (n,))`` of ``controller``'s model (a PhysicsInformedIDMPC's) at
    (q, v): the dry arm, the water model's terms (its added mass joins the inertia) and the
    remainder's estimate of now, as its step forms them (:meth:`PhysicsInformedIDMPC.water_terms`)."""
    w_free, added_mass = controller.water_terms(q, v)
    return controller.mpc.dynamics_terms(q, v, w_free, added_mass)


def model_period(controller: Any, q, v, tau, period: float, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """``(q, v)`` (n,) each one ``period`` (s) on from (q, v) under the torque ``tau`` (n,) N m held:
    ``steps`` RK4 steps (``pi_idmpc.plan_prediction_steps``) of the model's forward dynamics
    (:func:`model_terms`, 4 evaluations a step; a fixed-order Cholesky, no LAPACK: its last bits do
    not follow the BLAS kernel).

    Measured on the paper task's start-up (2026-12-04): the double integrator at the step's realised
    acceleration (the prediction before) missed the measured state one period ahead by up to
    32 rad/s (the wrist at 220 rad/s, its drag changing within the period). 10 steps (1 ms at the
    paper's 10 ms, the plant's own inner step; the default) cost 1.9 ms a period on the paper arm, 2
    steps 0.4 ms, with the same mean E_p on the paper task to 1e-6 (0.025636) and 0.080829 against
    0.081199 with the UR5's limits."""

    def acceleration(q_i, v_i):
        mass, bias = model_terms(controller, q_i, v_i)
        return fixed_order.cholesky_solve(np.ascontiguousarray(mass), tau - bias)[0]

    h = period / steps
    for _ in range(steps):
        a1 = acceleration(q, v)
        a2 = acceleration(q + 0.5 * h * v, v + 0.5 * h * a1)
        v2 = v + 0.5 * h * a1
        a3 = acceleration(q + 0.5 * h * v2, v + 0.5 * h * a2)
        v3 = v + 0.5 * h * a2
        a4 = acceleration(q + h * v3, v + h * a3)
        v4 = v + h * a3
        q = q + h / 6.0 * (v + 2.0 * v2 + 2.0 * v3 + v4)
        v = v + h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
    return q, v


class _Still:
    """A reference holding every joint at 0 rad (the warm-up's, :func:`warm_kernels`)."""

    vectorised = True

    def __init__(self, n: int):
        self.n = n

    def sample(self, t):
        times = np.atleast_1d(np.asarray(t, dtype=float))
        zeros = np.zeros((times.shape[0], self.n))
        return zeros, zeros, zeros


_WARMED: set[tuple] = set()
"""The planners whose kernels this process has run (:func:`warm_kernels`)."""


def warm_kernels(pi_idmpc: Any) -> None:
    """Run a plan's every kernel once in this process, before a worker is forked from it, on a twin
    of ``pi_idmpc`` (a PhysicsInformedIDMPC: the same arm and settings, solved inline; the
    controller itself is not touched): a forked worker inherits what its parent ran, and without
    this each worker loaded the planner's compiled kernels in its first plan (measured on the paper
    task, 2026-12-04: 43-83 ms of CPU time in the first plan of every run, then 4-14 ms). Once per
    process and kind of planner."""
    config = pi_idmpc.config
    key = (type(pi_idmpc), pi_idmpc.n, config.planner_horizon, config.planner_solver, config.plan_latency)
    if key in _WARMED:
        return
    _WARMED.add(key)
    inline = config.model_copy(update={"plan_worker": "inline"})
    twin = type(pi_idmpc)(pi_idmpc.arm, pi_idmpc.mpc.config, pi_idmpc.model.config, pi_idmpc.control_period, inline)
    n = pi_idmpc.n
    y = np.concatenate([np.full(n, 1.0), np.full(n, 5.0)])  # far off the still reference: the limits bind
    torque = np.zeros(n)
    twin.latent.plan_job(0, 0.0, y, _Still(n), torque, None)  # cold
    twin.latent.plan_job(1, pi_idmpc.control_period, y, _Still(n), torque, 1)  # warm from it


def _serve_plans(planner: LatentPlanner, connection) -> None:  # pragma: no cover - a child
    """The worker process of ``plan_worker = "process"``: for each job of the control loop (in
    order) the water model's and the remainder's estimate of its step, then
    :meth:`LatentPlanner.plan_job`; answers ``(launched, plans, rejected, (wall s, CPU s))``."""
    controller = planner.controller
    reference = None
    while True:
        try:
            job = connection.recv()
        except EOFError:
            return
        if job is None:
            return
        k, t, y, torque, shift, theta, rest, sent = job
        reference = sent if sent is not None else reference
        controller.model.theta, controller._rest = theta, rest
        plans, rejected = controller.plans, controller.rejected
        start, start_cpu = time.perf_counter(), time.process_time()
        try:
            launched = planner.plan_job(k, t, y, reference, torque, shift)
        except Exception as error:  # the control loop raises it, with its cause
            connection.send(("error", f"{type(error).__name__}: {error}"))
            return
        seconds = (time.perf_counter() - start, time.process_time() - start_cpu)
        connection.send((launched, controller.plans - plans, controller.rejected - rejected, seconds))
