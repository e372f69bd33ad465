"""Box-constrained QP solvers behind one protocol: ``min 1/2 x'Hx + g'x  s.t.  lb <= x <= ub``.

Every backend implements :class:`BoxQPSolver`: a ``name`` and
``solve(H, g, lb, ub, x0=None) -> QPResult`` with H (m, m) symmetric positive definite,
g, lb, ub (m,) and an optional warm start x0 (m,) (a backend without warm start ignores it).
A backend keeps what it sets up between calls (OSQP: the solver, set up once and updated
per call; DAQP: its empty general-constraint data), rebuilt when the problem size changes.

Each backend reads its solver's own status codes into one :class:`QPResult` status
(:data:`QP_STATUSES`), and refuses crossed bounds (``lb_i > ub_i``) before its solver runs.
:func:`solve_terminal_qp` adds the MPC's quadratic terminal constraint as a second-order
cone, solved by Clarabel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import daqp
import numpy as np

from hydroarm.config import ConfigError

if TYPE_CHECKING:
    from hydroarm.control.mpc.condense import CondensedQP

SOLVERS = ("daqp", "osqp", "quadprog", "clarabel")
"""The backends of :func:`make_box_qp_solver`, by name."""

QP_STATUSES = ("solved", "iteration_limit", "infeasible", "failed")
"""What a box-QP solve ended with, read from each solver's own status codes."""


@dataclass(frozen=True)
class QPResult:
    """``x`` (m,) or None; ``status``, one of :data:`QP_STATUSES` (``"solved"``: the solver
    reported an optimal solution); ``message``: the solver's own words, for people."""

    x: np.ndarray | None
    status: str
    message: str

    def __post_init__(self) -> None:
        if self.status not in QP_STATUSES:
            raise ValueError(f"status = {self.status!r}: must be one of {', '.join(QP_STATUSES)}")

    @property
    def ok(self) -> bool:
        return self.status == "solved"


@runtime_checkable
class BoxQPSolver(Protocol):
    """A box-QP backend: ``solve(H, g, lb, ub, x0)`` minimises ``1/2 x'Hx + g'x`` subject to
    ``lb <= x <= ub``.

    H (m, m) symmetric positive definite, g, lb, ub (m,); x0 (m,) or None: a warm start
    (ignored by backends without one). The outcome is the returned :class:`QPResult`
    (crossed bounds give ``"infeasible"``); an exception of the underlying library may
    still propagate (``LinearMPC`` counts it as a failed solve).
    """

    name: str

    def solve(
        self, H: np.ndarray, g: np.ndarray, lb: np.ndarray, ub: np.ndarray, x0: np.ndarray | None = None
    ) -> QPResult: ...


def _crossed_bounds(lb: np.ndarray, ub: np.ndarray) -> QPResult | None:
    """An ``"infeasible"`` result if some ``lb_i > ub_i`` (checked before any solver runs:
    OSQP's update would refuse such data silently and return the previous solution)."""
    if (lb <= ub).all():  # every step of the MPC: the cheap test first
        return None
    i = int(np.flatnonzero(~(lb <= ub))[0])
    return QPResult(None, "infeasible", f"lb[{i}] = {lb[i]:g} > ub[{i}] = {ub[i]:g}")


_DAQP_STATUS = {1: "solved", -4: "iteration_limit", -1: "infeasible"}
"""DAQP exit flags (1 optimal, -1 primal infeasible, -4 iteration limit); others: failed."""


class DaqpBoxSolver(BoxQPSolver):
    """DAQP (dense dual active set); simple bounds; warm start from ``x0`` (its active set).

    At most ``iteration_factor * m`` active-set iterations (an active set changes
    one constraint per iteration; an ill-conditioned H, e.g. r = 1e-6 with
    N = 50, can otherwise cycle up to DAQP's default 10^4 iterations).
    """

    name = "daqp"

    def __init__(self, iteration_factor: int = 10) -> None:
        self.iteration_factor = iteration_factor
        self._empty: np.ndarray | None = None
        self._sense: np.ndarray | None = None

    def solve(self, H, g, lb, ub, x0=None) -> QPResult:
        crossed = _crossed_bounds(lb, ub)
        if crossed is not None:
            return crossed
        m = g.shape[0]
        if self._empty is None or self._empty.shape[1] != m:
            self._empty = np.zeros((0, m))
            self._sense = np.zeros(m, dtype=np.int32)
        x, _, flag, info = daqp.solve(
            H, g, self._empty, ub, lb, self._sense, primal_start=x0,
            iter_limit=self.iteration_factor * m,
        )  # fmt: skip
        message = f"daqp exitflag {flag}, {info['iterations']} iterations"
        return QPResult(np.asarray(x), _DAQP_STATUS.get(int(flag), "failed"), message)


class OsqpBoxSolver(BoxQPSolver):
    """OSQP (sparse ADMM), set up once and updated per call, warm-started from ``x0``.

    Tight tolerances (``tolerance`` for eps_abs and eps_rel). No polishing by
    default: OSQP 1.1 prints a line on stdout at every polish that finds no
    active set, whatever ``verbose`` says.
    """

    name = "osqp"

    def __init__(self, tolerance: float = 1e-10, max_iterations: int = 50000, polishing: bool = False) -> None:
        self.tolerance = tolerance
        self.max_iterations = max_iterations
        self.polishing = polishing
        self._solver = None
        self._size = -1

    def solve(self, H, g, lb, ub, x0=None) -> QPResult:
        import osqp
        import scipy.sparse as sp

        crossed = _crossed_bounds(lb, ub)
        if crossed is not None:
            return crossed
        m = g.shape[0]
        if self._solver is None or self._size != m:
            rows, cols = np.triu_indices(m)
            order = np.lexsort((rows, cols))  # CSC order: by column, then row
            self._rows, self._cols, self._size = rows[order], cols[order], m
            indptr = np.concatenate([[0], np.cumsum(np.arange(1, m + 1))])
            hessian = sp.csc_matrix((H[self._rows, self._cols], self._rows, indptr), shape=(m, m))
            solver = osqp.OSQP()
            solver.setup(
                hessian, g, sp.identity(m, format="csc"), lb, ub, verbose=False,
                eps_abs=self.tolerance, eps_rel=self.tolerance, max_iter=self.max_iterations,
                polishing=self.polishing, warm_starting=True,
            )  # fmt: skip
            self._solver = solver
        else:
            self._solver.update(Px=H[self._rows, self._cols], q=g, l=lb, u=ub)
        if x0 is not None:
            self._solver.warm_start(x=x0)
        result = self._solver.solve(raise_error=False)
        return QPResult(np.asarray(result.x), _osqp_status(result.info.status_val), f"osqp {result.info.status}")


def _osqp_status(value: int) -> str:
    """Our status of an OSQP ``status_val`` (its ``SolverStatus`` constants)."""
    import osqp

    codes = osqp.SolverStatus
    if value == codes.OSQP_SOLVED:
        return "solved"
    if value in (codes.OSQP_MAX_ITER_REACHED, codes.OSQP_TIME_LIMIT_REACHED):
        return "iteration_limit"
    if value in (codes.OSQP_PRIMAL_INFEASIBLE, codes.OSQP_PRIMAL_INFEASIBLE_INACCURATE):
        return "infeasible"
    return "failed"


class QuadprogBoxSolver(BoxQPSolver):
    """quadprog (Goldfarb-Idnani dual active set, dense); no warm start."""

    name = "quadprog"

    def solve(self, H, g, lb, ub, x0=None) -> QPResult:
        import quadprog

        crossed = _crossed_bounds(lb, ub)
        if crossed is not None:
            return crossed
        m = g.shape[0]
        constraints = np.hstack([np.eye(m), -np.eye(m)])
        try:
            x = quadprog.solve_qp(H, -g, constraints, np.concatenate([lb, -ub]), 0)[0]
        except ValueError as error:  # quadprog reports only by exception text
            status = "infeasible" if "inconsistent" in str(error) else "failed"
            return QPResult(None, status, f"quadprog {error}")
        return QPResult(np.asarray(x), "solved", "quadprog optimal")


class ClarabelBoxSolver(BoxQPSolver):
    """Clarabel (interior point, conic) on the box QP; a fresh solver per call."""

    name = "clarabel"

    def solve(self, H, g, lb, ub, x0=None) -> QPResult:
        import clarabel
        import scipy.sparse as sp

        crossed = _crossed_bounds(lb, ub)
        if crossed is not None:
            return crossed
        m = g.shape[0]
        eye = sp.identity(m, format="csc")
        constraints = sp.vstack([eye, -eye], format="csc")
        solver = clarabel.DefaultSolver(
            sp.triu(sp.csc_matrix(H), format="csc"), g, constraints,
            np.concatenate([ub, -lb]), [clarabel.NonnegativeConeT(2 * m)], _clarabel_settings(),
        )  # fmt: skip
        solution = solver.solve()
        return QPResult(np.asarray(solution.x), _clarabel_status(solution), f"clarabel {solution.status}")


def _clarabel_settings():
    import clarabel

    settings = clarabel.DefaultSettings()
    settings.verbose = False
    settings.tol_gap_abs = settings.tol_gap_rel = settings.tol_feas = 1e-8
    settings.max_threads = 1
    return settings


def _clarabel_status(solution) -> str:
    """Our status of a Clarabel solution: solved also to its reduced accuracy
    (AlmostSolved: Clarabel's ``reduced_tol_*`` settings, gap 5e-5 by default)."""
    import clarabel

    codes = clarabel.SolverStatus
    if solution.status in (codes.Solved, codes.AlmostSolved):
        return "solved"
    if solution.status in (codes.MaxIterations, codes.MaxTime):
        return "iteration_limit"
    if solution.status in (codes.PrimalInfeasible, codes.AlmostPrimalInfeasible):
        return "infeasible"
    return "failed"


def make_box_qp_solver(name: str) -> BoxQPSolver:
    """A fresh box-QP solver by name (one of :data:`SOLVERS`); :class:`ConfigError` otherwise."""
    solvers = {
        "daqp": DaqpBoxSolver,
        "osqp": OsqpBoxSolver,
        "quadprog": QuadprogBoxSolver,
        "clarabel": ClarabelBoxSolver,
    }
    if name not in solvers:
        raise ConfigError(f"solver = {name!r}: must be one of {', '.join(SOLVERS)}")
    return solvers[name]()


def solve_terminal_qp(
    qp: CondensedQP,
    lb: np.ndarray,
    ub: np.ndarray,
    P: np.ndarray,
    alpha: float,
    slack_penalty: float | None,
) -> tuple[QPResult, float]:
    """The box QP plus the terminal set ``e_N' P e_N <= alpha (+ s)``, by Clarabel.

    Hard (``slack_penalty`` None): variables dU. Soft: variables [dU, s], s >= 0,
    cost + ``slack_penalty * s``. The quadratic constraint is the second-order
    cone ``||(alpha + s - 1, 2 L' e_N)|| <= alpha + s + 1`` with ``P = L L'``.
    Returns ``(QPResult over dU, slack)`` (slack 0 for the hard problem).
    """
    import clarabel
    import scipy.sparse as sp

    m = qp.g.shape[0]
    soft = slack_penalty is not None
    size = m + (1 if soft else 0)
    eigval, eigvec = np.linalg.eigh(0.5 * (P + P.T))
    root_t = np.sqrt(np.clip(eigval, 0.0, None))[:, None] * eigvec.T  # L' with L L' = P
    nx = P.shape[0]
    hessian = np.zeros((size, size))
    hessian[:m, :m] = qp.H
    linear = np.zeros(size)
    linear[:m] = qp.g
    box = np.zeros((2 * m + (1 if soft else 0), size))
    box[:m, :m] = np.eye(m)
    box[m : 2 * m, :m] = -np.eye(m)
    box_rhs = np.concatenate([ub, -lb, [0.0] if soft else []])
    if soft:
        linear[m] = slack_penalty
        box[2 * m, m] = -1.0
    # ||u||^2 <= z (u = L' e_N, z = alpha + s) as the second-order cone
    # ||(2 u / sqrt(g), z / g - 1)|| <= z / g + 1, scaled by g ~ the size of z so
    # that the cone is well conditioned when z >> 1 (start-up: z ~ 1e5).
    free = root_t @ qp.terminal_free
    scale = max(alpha, float(free @ free))
    cone = np.zeros((nx + 2, size))
    cone_rhs = np.empty(nx + 2)
    cone_rhs[0], cone_rhs[1] = alpha / scale + 1.0, alpha / scale - 1.0
    if soft:
        cone[0, m] = cone[1, m] = -1.0 / scale
    cone[2:, :m] = -2.0 / math.sqrt(scale) * root_t @ qp.terminal_map
    cone_rhs[2:] = 2.0 / math.sqrt(scale) * free
    solver = clarabel.DefaultSolver(
        sp.triu(sp.csc_matrix(hessian), format="csc"), linear,
        sp.csc_matrix(np.vstack([box, cone])), np.concatenate([box_rhs, cone_rhs]),
        [clarabel.NonnegativeConeT(box.shape[0]), clarabel.SecondOrderConeT(nx + 2)],
        _clarabel_settings(),
    )  # fmt: skip
    solution = solver.solve()
    status = _clarabel_status(solution)
    x = np.asarray(solution.x)
    slack = float(max(x[m], 0.0)) if soft and status == "solved" else 0.0
    return QPResult(x[:m], status, f"clarabel {solution.status}"), slack
