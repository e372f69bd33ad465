"""The controller: :class:`LinearMPC`, its fallbacks and its fault events.

One step of :meth:`LinearMPC.compute`: slide the window of linearisations along the
reference (:meth:`~hydroarm.model.dynamics.nominal.NominalModel.linearise_into`), the terminal
weight P at the horizon end (:func:`~hydroarm.control.linear.riccati_solution`), the
condensed QP (:func:`~hydroarm.control.mpc.condense.condense`) and its torque box, the solve
(a :class:`~hydroarm.control.qp.BoxQPSolver`, or Clarabel with the terminal set), the
fallbacks, the last-guard clip. The package docstring (:mod:`hydroarm.control.mpc`)
describes the method. Units: SI (rad, rad/s, N m, s).
"""

from __future__ import annotations

import time

import numpy as np

from hydroarm.config import ConfigError, per_joint
from hydroarm.control.interface import DEFAULT_CONTROL_PERIOD, ControlOutput, Reference, require_period
from hydroarm.control.linear import lqr_gain, riccati_solution
from hydroarm.control.mpc.condense import CondensedQP, condense
from hydroarm.control.mpc.config import MPCConfig
from hydroarm.control.qp import QPResult, make_box_qp_solver, solve_terminal_qp
from hydroarm.model.arm.description import Arm
from hydroarm.model.dynamics.nominal import NominalModel

CLIP_TOLERANCE = 1e-9
"""Relative excess over the torque limit above which the last-guard clip is counted."""


class LinearMPC:
    """Linear time-varying MPC about the reference, with the controller interface.

    ``LinearMPC(arm, config=None, control_period=DEFAULT_CONTROL_PERIOD)`` (``config`` None: the defaults of
    :class:`MPCConfig`; ``control_period`` T in s, the step of the prediction model and of
    the reference index ``k = round(t / T)``);
    ``compute(t, y, reference, feedforward_acceleration=None, feedforward_torque=None)``
    returns a :class:`~hydroarm.control.interface.ControlOutput` whose ``tau`` (n,) N m
    always satisfies ``|tau_i| <= u_max_i``. ``status`` is ``"ok"``,
    ``"terminal_soft_fallback"`` (hard terminal set infeasible, soft used),
    ``"qp_failed_shift"``, ``"qp_failed_lqr"`` or ``"qp_failed_reference"``; ``terminal_violation`` is
    ``max(e_N' P e_N - alpha, 0)`` of the plan used (the optimal slack; 0 when
    the terminal set is off); ``timings`` (s): ``linearise``, ``riccati``,
    ``qp_update``, ``qp_solve`` (with fallbacks), ``total``.

    Attributes: ``Q`` (2n, 2n), ``R`` (n, n), ``torque_limit`` (n,) N m.
    Counters since ``reset``: ``clip_count`` (last-guard clips that changed
    the torque by more than rounding), ``fallback_count``, ``riccati_scipy_count``;
    ``last_message``: the solver's last status text.
    """

    name = "MPC"

    def __init__(
        self, arm: Arm, config: MPCConfig | None = None, control_period: float = DEFAULT_CONTROL_PERIOD
    ) -> None:
        self.arm = arm
        self.config = config if config is not None else MPCConfig()
        cfg = self.config
        n = arm.n_joints
        self.n = n
        self.horizon = cfg.horizon
        self.control_period = require_period(control_period)
        self.nominal = NominalModel(arm, inner_step=None)  # own workspace
        self._q_diag = np.concatenate(
            [per_joint(cfg.q_position, n, "q_position"), per_joint(cfg.q_velocity, n, "q_velocity")]
        )
        self._r_diag = per_joint(cfg.r, n, "r")
        self.Q = np.diag(self._q_diag)
        self.R = np.diag(self._r_diag)
        self.torque_limit = per_joint(arm.torque_limit, n, "torque_limit")  # the arm's actuators
        self._limit_stacked = np.tile(self.torque_limit, cfg.horizon)
        self._solver = make_box_qp_solver(cfg.solver)
        if cfg.terminal_set != "off":
            try:
                import clarabel  # noqa: F401
            except ImportError:
                raise ConfigError(f"terminal_set = {cfg.terminal_set!r} needs the clarabel package") from None
        # The window of linearisations at reference indices start .. start + N.
        size = cfg.horizon + 1
        self._x_ref = np.zeros((size, 2 * n))
        self._u_ref = np.zeros((size, n))
        self._a = np.zeros((size, 2 * n, 2 * n))
        self._b = np.zeros((size, 2 * n, n))
        self._x_next = np.zeros((size, 2 * n))
        self._a[:, :n, :n] = np.eye(n)  # the constant blocks of every A and B
        self._a[:, :n, n:] = self.control_period * np.eye(n)
        self.reset()

    # --- interface -------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the linearisation window, the terminal weight, the previous plan, the counters."""
        self._start: int | None = None
        self._reference: Reference | None = None
        self._riccati_index: int | None = None
        self._P: np.ndarray | None = None
        self._plan: np.ndarray | None = None  # (N, n) absolute torques of the last solution
        self._plan_index = 0
        self.clip_count = 0
        self.fallback_count = 0
        self.riccati_scipy_count = 0
        self.last_message = ""

    def observe(self, t: float, y: np.ndarray, u: np.ndarray, y_next: np.ndarray) -> None:
        """No-op: plain MPC learns nothing."""

    def compute(
        self,
        t: float,
        y: np.ndarray,
        reference: Reference,
        feedforward_acceleration: np.ndarray | None = None,
        feedforward_torque: np.ndarray | None = None,
    ) -> ControlOutput:
        """Torque for the measured state ``y = [q, v]`` (2n,) at time t (s).

        The horizon starts at reference index ``k = round(t / T)`` (the error is
        taken against ``x_r(k T)``). Two ways to feed a disturbance estimate
        forward (None means zero):

        * ``feedforward_acceleration`` d (n,) rad/s^2 is added to the nominal
          model's joint acceleration at every step of the horizon (the affine
          term; the paper's eq. 14 with d = M^-1 w). The cost still penalises
          the torque that compensates it, as a deviation from the dry u_r.
        * ``feedforward_torque`` w (n,) N m is a generalised force acting with
          the input: the model becomes ``f(x, u + w)``, i.e. the input
          reference shifts to ``u_r - w`` (exact through B_k, which carries
          M^-1 along the reference), so compensating w costs nothing and the
          QP's box still limits the total torque.
        The reference must not change between calls except by passing another
        object (the linearisations are cached by index).
        """
        start = time.perf_counter()
        cfg = self.config
        n, horizon = self.n, self.horizon
        y = np.asarray(y, dtype=float)
        if y.shape != (2 * n,) or not np.all(np.isfinite(y)):
            raise ValueError(f"y must be finite with shape ({2 * n},), got shape {y.shape}: {y}")
        k = int(round(t / self.control_period))
        self._slide(k, reference)  # linearise: slide the window to k .. k + N, computing only the new indices
        u_refs, offsets = self._affine_terms(feedforward_acceleration, feedforward_torque)
        e0 = y - self._x_ref[0]
        t_lin = time.perf_counter()
        P = self._terminal_weight(k)
        t_ric = time.perf_counter()

        # Condensed QP and its box.
        qp = condense(self._a[:horizon], self._b[:horizon], offsets, self._q_diag, self._r_diag, P, e0)
        u_ref_flat = u_refs.ravel()
        lb = -self._limit_stacked - u_ref_flat
        ub = self._limit_stacked - u_ref_flat
        warm = self._shifted_plan(k)
        if warm is not None:
            warm = warm.ravel() - u_ref_flat
        t_upd = time.perf_counter()
        du, status, events = self._solve_step(k, qp, lb, ub, P, warm, u_refs, e0)
        tau = self._last_guard(u_refs[0] + du[:n], events)
        t_sol = time.perf_counter()
        violation = 0.0  # the terminal-set violation (the optimal slack) of the plan used
        if cfg.terminal_set != "off":
            e_n = qp.terminal_error(du)
            violation = max(float(e_n @ P @ e_n) - cfg.terminal_alpha, 0.0)
        end = time.perf_counter()
        timings = {
            "linearise": t_lin - start,
            "riccati": t_ric - t_lin,
            "qp_update": t_upd - t_ric,
            "qp_solve": t_sol - t_upd,
            "total": end - start,
        }
        return ControlOutput(
            tau=tau, status=status, timings=timings, terminal_violation=violation, events=tuple(events)
        )

    # --- the steps of compute ----------------------------------------------------------
    def _affine_terms(
        self, feedforward_acceleration: np.ndarray | None, feedforward_torque: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The horizon's input references (N, n) N m (shifted by ``-w``) and the prediction's
        affine offsets (N, 2n) (with ``d`` added), as :meth:`compute` describes."""
        n, horizon, period = self.n, self.horizon, self.control_period
        u_refs = self._u_ref[:horizon]
        if feedforward_torque is not None:
            w = np.asarray(feedforward_torque, dtype=float)
            if w.shape != (n,) or not np.all(np.isfinite(w)):
                raise ValueError(f"feedforward_torque must be finite with shape ({n},)")
            u_refs = u_refs - w
        offsets = self._x_next[:horizon] - self._x_ref[1:]
        if feedforward_acceleration is not None:
            d = np.asarray(feedforward_acceleration, dtype=float)
            if d.shape != (n,) or not np.all(np.isfinite(d)):
                raise ValueError(f"feedforward_acceleration must be finite with shape ({n},)")
            offsets[:, n:] += period * d
            if self.config.discretisation == "taylor2":  # the extra acceleration also moves the position
                offsets[:, :n] += 0.5 * period**2 * d
        return u_refs, offsets

    def _terminal_weight(self, k: int) -> np.ndarray:
        """P (2n, 2n): the DARE at the horizon-end linearisation, solved once per index."""
        cfg, horizon = self.config, self.horizon
        if self._riccati_index != k + horizon:
            P, _, method = riccati_solution(
                self._a[horizon], self._b[horizon], self.Q, self._r_diag,
                cfg.riccati_tolerance, cfg.riccati_max_iterations,
            )  # fmt: skip
            self.riccati_scipy_count += method != "doubling"
            self._P, self._riccati_index = P, k + horizon
        return self._P

    def _solve_step(
        self, k: int, qp: CondensedQP, lb: np.ndarray, ub: np.ndarray, P: np.ndarray,
        warm: np.ndarray | None, u_refs: np.ndarray, e0: np.ndarray,
    ) -> tuple[np.ndarray, str, list[str]]:  # fmt: skip
        """The QP's moves (N n,), the step's status and its fault events: the solve, the soft
        terminal set if the hard one is infeasible, then the fallbacks."""
        cfg, n, horizon = self.config, self.n, self.horizon
        status = "ok"
        events: list[str] = []
        result = self._solve(qp, lb, ub, P, warm, cfg.terminal_set)
        if cfg.terminal_set == "hard" and not result.ok:
            status = "terminal_soft_fallback"
            events.append("terminal_soft_fallback")
            result = self._solve(qp, lb, ub, P, warm, "soft")
        self.last_message = result.message
        if result.ok and _valid_moves(result.x, lb, ub):
            du = result.x
            self._plan = (u_refs.ravel() + du).reshape(horizon, n)
            self._plan_index = k
        else:
            self.fallback_count += 1
            events.append(qp_failure_event(result))
            du, status = self._fallback(k, u_refs, P, e0)
        return du, status, events

    def _last_guard(self, tau: np.ndarray, events: list[str]) -> np.ndarray:
        """``tau`` clipped to the torque box; a clip beyond rounding (NaN included: then 0) is counted."""
        if not np.all(np.abs(tau) <= self.torque_limit * (1.0 + CLIP_TOLERANCE)):  # NaN included
            self.clip_count += 1
            events.append("torque_clipped")
            tau = np.where(np.isfinite(tau), tau, 0.0)
        return np.clip(tau, -self.torque_limit, self.torque_limit)

    # --- internals -------------------------------------------------------------------
    def _slide(self, k: int, reference: Reference) -> None:
        """Make the window hold the linearisations at indices k .. k + N."""
        size = self.horizon + 1
        shift = None if self._start is None else k - self._start
        if reference is not self._reference or shift is None or not 0 <= shift < size:
            self._reference = reference
            self._riccati_index = None
            new = range(size)
        else:
            for array in (self._x_ref, self._u_ref, self._a, self._b, self._x_next):
                array[: size - shift] = array[shift:]
            new = range(size - shift, size)
        self._start = None  # invalid until every new slot is filled (an exception leaves it so)
        for slot in new:
            q, v, a = reference.sample((k + slot) * self.control_period)
            q = np.asarray(q, dtype=float)
            v = np.asarray(v, dtype=float)
            u_ref = self.nominal.inverse_dynamics(q, v, np.asarray(a, dtype=float))
            self._x_next[slot] = self.nominal.linearise_into(
                q, v, u_ref, self.control_period, self._a[slot], self._b[slot],
                self.config.discretisation, constant_blocks_set=True,
            )  # fmt: skip
            self._x_ref[slot, : self.n] = q
            self._x_ref[slot, self.n :] = v
            self._u_ref[slot] = u_ref
        self._start = k

    def _solve(self, qp: CondensedQP, lb, ub, P, warm, terminal_set: str) -> QPResult:
        """The box QP by the configured solver, or the terminal-set problem by Clarabel."""
        cfg = self.config
        try:
            if terminal_set == "off":
                return self._solver.solve(qp.H, qp.g, lb, ub, warm)
            penalty = None if terminal_set == "hard" else cfg.terminal_slack_penalty
            return solve_terminal_qp(qp, lb, ub, P, cfg.terminal_alpha, penalty)[0]
        except Exception as error:  # a crashing solver is a failed solve
            return QPResult(None, "failed", f"solver raised {error!r}")

    def _shifted_plan(self, k: int) -> np.ndarray | None:
        """The last successful plan (N, n) shifted to start at index k (last move held)."""
        if self._plan is None:
            return None
        shift = k - self._plan_index
        if not 0 <= shift < self.horizon:
            return None
        return np.concatenate([self._plan[shift:], np.repeat(self._plan[-1:], shift, axis=0)])

    def _fallback(self, k: int, u_refs: np.ndarray, P: np.ndarray, e0: np.ndarray):
        """Moves (N n,) and status: the shifted previous plan (``qp_failed_shift``), else the
        saturated LQR law (``qp_failed_lqr``), else, if even the LQR gain cannot be
        computed, the saturated reference torque (``qp_failed_reference``)."""
        plan = self._shifted_plan(k)
        if plan is not None:
            plan = np.clip(plan, -self.torque_limit, self.torque_limit)
            return (plan - u_refs).ravel(), "qp_failed_shift"
        status = "qp_failed_lqr"
        try:
            tau = u_refs[0] - lqr_gain(self._a[0], self._b[0], self.R, P) @ e0
        except (np.linalg.LinAlgError, ValueError):
            tau = np.full(self.n, np.nan)
        if not np.all(np.isfinite(tau)):  # degenerate weights: the reference torque alone
            tau, status = u_refs[0].copy(), "qp_failed_reference"
        tau = np.clip(np.where(np.isfinite(tau), tau, 0.0), -self.torque_limit, self.torque_limit)
        du = np.zeros(u_refs.size)
        du[: self.n] = tau - u_refs[0]
        return du, status


_QP_FAILURE_EVENTS = {
    "solved": "qp_invalid_solution",
    "iteration_limit": "qp_iteration_limit",
    "infeasible": "qp_infeasible",
    "failed": "qp_failed",
}


def qp_failure_event(result: QPResult) -> str:
    """The fault event of a solve that was not used, from ``result.status``:
    ``"qp_iteration_limit"``, ``"qp_infeasible"``, ``"qp_failed"`` (anything else, e.g.
    the solver raised) or ``"qp_invalid_solution"`` (reported solved, but not finite or
    outside the box)."""
    return _QP_FAILURE_EVENTS[result.status]


def _valid_moves(x: np.ndarray | None, lb: np.ndarray, ub: np.ndarray) -> bool:
    """Finite and within the bounds up to 1e-6 of the box width (NaN fails the test)."""
    if x is None or x.shape != lb.shape:
        return False
    excess = np.maximum(lb - x, x - ub) / (1.0 + (ub - lb))
    return bool(excess.max() <= 1e-6)
