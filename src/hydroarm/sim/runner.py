"""The closed loop: plant + controller + reference -> a typed trajectory record.

One control step k (period T): the plant's true state x_k is measured as
y_k (seeded noise), the controller returns u_k, the plant integrates to
x_{k+1} under u_k held constant, y_{k+1} is measured and the controller
observes (y_k, u_k, y_{k+1}). The plant's sensor and drives
(:mod:`hydroarm.model.real_loop.sensing`: quantisation, encoder-only velocity, delays, dropout, torque
rate and bandwidth limits) sit in between: y_k is what the sensor delivers, the plant
integrates under the torque the drives apply (``Trajectory.u``; the command is
``extra["u_command"]`` when the drives are not ideal), and the controller observes its own
command u_k.

Faults are caught where they happen and counted, never hidden
(:data:`hydroarm.control.interface.FAULT_EVENTS`; ``Trajectory.meta["faults"]``):

* a non-finite measurement is replaced by the last valid one (before any valid
  one: the known initial state x0), event ``measurement_held``; a step whose
  start or end measurement was held is not passed to ``observe`` (a learning
  controller must not learn from it);
* the controllers recover from their own faults (GP jitter, QP fallbacks) and
  report them as ``ControlOutput.events``;
* a controller that raises anyway, or returns a non-finite torque, stops the
  run cleanly (``meta["stopped"] = "controller_error"``, the message in
  ``meta["error"]``);
* a plant that blows up (non-finite state or a joint speed beyond
  :data:`DIVERGENCE_SPEED`) stops the run cleanly (``meta["stopped"] =
  "diverged"``).

Any plant of the protocol :class:`hydroarm.sim.plant_protocol.Plant` runs here: the fixed-base arm
and the vehicle with its arm alike.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from hydroarm.control.interface import FAULT_EVENTS, Controller, Reference
from hydroarm.sim.files import atomic_file
from hydroarm.sim.loop import Loop, LoopStep
from hydroarm.sim.plant_protocol import Plant

DIVERGENCE_SPEED = 1e3  # rad/s: beyond this the run is declared diverged


@dataclass
class Trajectory:
    """Everything a closed-loop run produced, one row per control step (K rows).

    ``t`` (K,) s; ``x`` (K, 2n) true state at t_k; ``y`` (K, 2n) measured;
    ``u`` (K, n) applied torque (N m); ``q_ref``, ``v_ref`` (K, n) reference;
    ``disturbance`` (K, n) true generalised disturbance averaged over the step
    (N m); ``disturbance_estimate`` / ``disturbance_var`` (K, n) what the
    controller estimated (NaN if it has no estimator); ``timings`` per phase
    (K,) s; ``status`` (K,) solver/fallback status; ``terminal_violation``
    (K,); ``events`` (K,) the fault events of each step, comma-separated
    ("" if none); ``meta``: settings and outcome (JSON-serialisable), with
    ``faults`` (event -> count over the run), ``stopped`` (None,
    ``"diverged"`` or ``"controller_error"``), ``error`` and ``final_state`` (the
    plant's whole true state after the last step, a list); ``extra``: further
    per-step arrays (K, ...), saved only when present: what the plant records of its
    state beyond the joints (:meth:`~hydroarm.sim.plant_protocol.Plant.state_record`; on a
    vehicle ``base_pose`` (K, 7), ``base_velocity`` (K, 6), ``thrust`` (K, n_thr)) and what
    the controller reports beside its torque (``ControlOutput.record``; the station
    keeper's ``thrust_command``, ``wrench``, ``vehicle_disturbance_estimate``, ``saturated``).
    """

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    q_ref: np.ndarray
    v_ref: np.ndarray
    disturbance: np.ndarray
    disturbance_estimate: np.ndarray
    disturbance_var: np.ndarray
    terminal_violation: np.ndarray
    status: np.ndarray
    events: np.ndarray
    timings: dict[str, np.ndarray] = field(default_factory=dict)
    meta: dict = field(default_factory=dict)
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def n_joints(self) -> int:
        return int(self.u.shape[1])

    @property
    def q(self) -> np.ndarray:
        return self.x[:, : self.n_joints]

    @property
    def v(self) -> np.ndarray:
        return self.x[:, self.n_joints :]

    @property
    def diverged(self) -> bool:
        return bool(self.meta.get("diverged", False))

    def save(self, path: str | Path) -> Path:
        """Write a compressed ``.npz`` (atomically: temp file, then rename)."""
        path = Path(path)
        arrays = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in ("timings", "meta", "extra")}
        arrays["status"] = np.asarray(self.status, dtype=str)
        arrays["events"] = np.asarray(self.events, dtype=str)
        for key, value in self.timings.items():
            arrays[f"timing__{key}"] = value
        for key, value in self.extra.items():
            arrays[f"extra__{key}"] = value
        arrays["meta_json"] = np.asarray(json.dumps(self.meta))
        with atomic_file(path) as handle:
            np.savez_compressed(handle, **arrays)
        return path

    @classmethod
    def load(cls, path: str | Path) -> Trajectory:
        """Read a trajectory written by :meth:`save`."""
        with np.load(Path(path), allow_pickle=False) as archive:
            data = {key: archive[key] for key in archive.files}
        timings = {key.removeprefix("timing__"): data.pop(key) for key in list(data) if key.startswith("timing__")}
        extra = {key.removeprefix("extra__"): data.pop(key) for key in list(data) if key.startswith("extra__")}
        meta = json.loads(str(data.pop("meta_json")))
        return cls(**data, timings=timings, meta=meta, extra=extra)


class _Recorder:
    """The rows of a run of ``steps`` control steps on ``n`` joints, filled step by step, and the
    run's fault counts; :meth:`trajectory` cuts them to the steps used."""

    def __init__(self, steps: int, n: int, period: float, commands: bool):
        widths = {"x": 2 * n, "y": 2 * n, "u": n, "q_ref": n, "v_ref": n}
        widths |= {"disturbance": n, "disturbance_estimate": n, "disturbance_var": n}
        self.rows = {name: np.full((steps, width), np.nan) for name, width in widths.items()}
        self.steps, self.t = steps, np.arange(steps) * period
        self.violation = np.zeros(steps)
        self.status = np.full(steps, "", dtype=object)
        self.events = np.full(steps, "", dtype=object)
        self.timings: dict[str, np.ndarray] = {}
        self.extra: dict[str, np.ndarray] = {}
        self.faults = dict.fromkeys(FAULT_EVENTS, 0)
        self.commands = np.full((steps, n), np.nan) if commands else None

    def record(self, k: int, values: dict[str, np.ndarray]) -> None:
        """Per-step arrays beyond the joints (``Trajectory.extra``), allocated on first sight."""
        for key, value in values.items():
            value = np.asarray(value)
            if key not in self.extra:
                self.extra[key] = np.zeros((self.steps, *value.shape), dtype=value.dtype)
            self.extra[key][k] = value

    def step(self, k: int, plant: Plant, y: np.ndarray, tau: np.ndarray, out, step: LoopStep, ref) -> None:
        """Step k's row: true and measured state, applied torque, the reference ``ref`` = (q_r, v_r)
        (n,) each, disturbance true and estimated, what the controller reported (``out``: its
        :class:`ControlOutput`)."""
        n, rows = plant.n, self.rows
        rows["x"][k], rows["y"][k], rows["u"][k] = plant.joint_state(step.x), plant.joint_state(y), step.applied[:n]
        if self.commands is not None:
            self.commands[k] = tau[:n]
        self.record(k, plant.state_record(step.x))
        self.record(k, out.record)
        rows["q_ref"][k], rows["v_ref"][k] = ref
        rows["disturbance"][k] = step.info.disturbance
        if out.disturbance_mean is not None:
            rows["disturbance_estimate"][k] = out.disturbance_mean
        if out.disturbance_var is not None:
            rows["disturbance_var"][k] = out.disturbance_var
        self.violation[k], self.status[k] = out.terminal_violation, out.status
        for key, value in out.timings.items():
            self.timings.setdefault(key, np.full(self.steps, np.nan))[k] = value

    def count(self, k: int, names: list[str]) -> None:
        """Step k's fault events: counted, and listed in its row."""
        for name in names:
            self.faults[name] = self.faults.get(name, 0) + 1
        self.events[k] = ",".join(filter(None, (self.events[k], *names)))

    def trajectory(self, used: int, meta: dict) -> Trajectory:
        cut = slice(0, used)
        extra = {key: value[cut] for key, value in self.extra.items()}
        if self.commands is not None:
            extra["u_command"] = self.commands[cut]
        return Trajectory(
            t=self.t[cut],
            **{name: value[cut] for name, value in self.rows.items()},
            terminal_violation=self.violation[cut],
            status=np.asarray(self.status[cut], dtype=str),
            events=np.asarray(self.events[cut], dtype=str),
            timings={key: value[cut] for key, value in self.timings.items()},
            meta=meta,
            extra=extra,
        )


def _controller_step(controller: Controller, t: float, y: np.ndarray, reference: Reference, m: int):
    """``(out, tau, None)`` of the controller at (t, y), or ``(None, None, message)`` when it raised
    or returned a torque that is not m finite numbers (the runner then stops cleanly)."""
    try:
        out = controller.compute(t, y, reference)
        tau = np.asarray(out.tau, dtype=float)
        if tau.shape != (m,) or not np.all(np.isfinite(tau)):
            raise ValueError(f"{controller.name} returned a torque that is not finite with shape ({m},): {tau}")
    except Exception as exc:  # noqa: BLE001 - the last guard: stop cleanly, record why
        return None, None, f"{type(exc).__name__}: {exc}"
    return out, tau, None


def _observe(controller: Controller, t: float, y: np.ndarray, tau: np.ndarray, y_next: np.ndarray) -> str | None:
    """The controller observes the transition; the error message if it raised (else None)."""
    try:
        controller.observe(t, y, tau, y_next)
    except Exception as exc:  # noqa: BLE001 - as in compute
        return f"{type(exc).__name__}: {exc}"
    return None


def _diverged(plant: Plant, x_next: np.ndarray) -> bool:
    """A non-finite state or a joint faster than :data:`DIVERGENCE_SPEED`."""
    speeds = np.abs(plant.joint_state(x_next)[plant.n :])
    return not np.all(np.isfinite(x_next)) or np.max(speeds, initial=0.0) > DIVERGENCE_SPEED


def run_closed_loop(
    plant: Plant,
    controller: Controller,
    reference: Reference,
    duration: float,
    seed: int = 0,
    x0: np.ndarray | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Trajectory:
    """Simulate ``controller`` on ``plant`` tracking ``reference`` for ``duration`` s.

    ``seed`` drives the measurement noise (the only random thing here);
    ``x0`` (``plant.state_size``,) defaults to rest at q = 0 (the paper's start; a fixed-base
    plant only); ``progress(k, K)`` is called after every step. The loop's plant, sensor and
    drives are :class:`~hydroarm.sim.loop.Loop`'s. Returns a :class:`Trajectory`; faults are
    handled and counted as the module docstring says. No exception from the
    controller or the plant's numbers escapes (bad arguments still raise).
    """
    period, size = controller.control_period, plant.state_size
    steps = int(round(duration / period))
    x = np.zeros(size) if x0 is None else np.asarray(x0, dtype=float).copy()
    if x.shape != (size,) or not np.all(np.isfinite(x)):
        raise ValueError(f"x0 must be finite with shape ({size},); got {x}")
    controller.reset()
    loop = Loop(plant, period)
    y, y_valid = loop.reset(x, np.random.default_rng(seed), seed), loop.y_valid
    rec = _Recorder(steps, plant.n, period, commands=not loop.ideal_drives)
    pending: list[str] = [] if y_valid else ["measurement_held"]
    stopped, error, used, stop_time, final = None, None, steps, None, x  # final: the last state reached
    for k in range(steps):
        t = rec.t[k]
        # sampled before the controller runs, as the controller samples it too: measured 5 us
        # (10 %) of SMC's step when sampled after (the ufuncs cold; bench_side_by_side.py)
        q_r, v_r, _ = reference.sample(t)
        out, tau, error = _controller_step(controller, t, y, reference, plant.n_inputs)
        if error is not None:
            stopped, used, stop_time = "controller_error", k, float(t)
            rec.faults["controller_error"] += 1
            break
        step = loop.step(t, tau)
        final = step.x_next
        rec.step(k, plant, y, tau, out, step, (q_r, v_r))
        pending.extend(out.events)
        if _diverged(plant, step.x_next):
            pending.append("diverged")
            stopped, used, stop_time = "diverged", k + 1, float(t)
        rec.count(k, pending)
        if stopped is not None:
            break
        y_next, next_valid = loop.measure_next()
        pending = [] if next_valid else ["measurement_held"]
        if y_valid and next_valid:
            error = _observe(controller, t, y, tau, y_next)
            if error is not None:
                stopped, used, stop_time = "controller_error", k + 1, float(t)
                rec.count(k, ["controller_error"])
                break
        y, y_valid = y_next, next_valid
        if progress is not None:
            progress(k + 1, steps)
    meta = {
        "controller": controller.name, "seed": seed, "duration": duration, "control_period": period,
        "steps": used, "diverged": stopped == "diverged",
        "diverged_at_s": stop_time if stopped == "diverged" else None,
        "stopped": stopped, "stopped_at_s": stop_time, "error": error, "faults": rec.faults,
        "final_state": np.asarray(final, dtype=float).tolist(),
    }  # fmt: skip
    if loop.sensor_counts() is not None:
        meta["sensor"] = loop.sensor_counts()
    return rec.trajectory(used, meta)


def fault_counts(traj: Trajectory) -> dict[str, int]:
    """The run's fault events counted over the run (``traj.meta["faults"]``: event -> count;
    events listed in :data:`hydroarm.control.interface.FAULT_EVENTS`); {} from a runner that did not
    count them."""
    return {str(name): int(count) for name, count in (traj.meta.get("faults") or {}).items()}


def stop_reason(traj: Trajectory) -> str | None:
    """Why the run ended early (``traj.meta["stopped"]``: ``"diverged"``,
    ``"controller_error"``, ...), or None if it ran to the end."""
    stopped = traj.meta.get("stopped")
    if stopped is None and traj.diverged:
        return "diverged"
    return None if stopped is None else str(stopped)


def tracking_metrics(traj: Trajectory, steady_after: float = 2.0, band: float = 0.05) -> dict:
    """paper reading, section 4 metrics, per joint, on the true q.

    ``Ep``: mean over control samples of (q_r - q)^2 (rad^2) — Tables 1-2;
    ``Ep_steady``: the same over t > ``steady_after`` s; ``rms``/``max`` error
    (rad); ``torque_rms`` (N m); ``time_to_band``: first time |e| < ``band`` rad
    and stays there (s; NaN if never).
    """
    error = traj.q_ref - traj.q
    steady = traj.t > steady_after
    inside = np.abs(error) < band
    settle = []
    for j in range(error.shape[1]):
        outside = np.flatnonzero(~inside[:, j])
        if outside.size == 0:
            settle.append(0.0)
        elif outside[-1] + 1 < len(traj.t):
            settle.append(float(traj.t[outside[-1] + 1]))
        else:
            settle.append(math.nan)
    return {
        "Ep": np.mean(error**2, axis=0).tolist(),
        "Ep_steady": np.mean(error[steady] ** 2, axis=0).tolist() if steady.any() else [math.nan] * error.shape[1],
        "rms": np.sqrt(np.mean(error**2, axis=0)).tolist(),
        "max": np.max(np.abs(error), axis=0).tolist(),
        "torque_rms": np.sqrt(np.mean(traj.u**2, axis=0)).tolist(),
        "time_to_band": settle,
        "diverged": traj.diverged,
    }
