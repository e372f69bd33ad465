"""Linear time-varying MPC about the reference (paper Section 3.2, eqs. 13-18; paper reading, section 5).

Modules: :mod:`~hydroarm.control.mpc.config` (:class:`MPCConfig`),
:mod:`~hydroarm.control.linear` (the terminal weight),
:mod:`~hydroarm.control.mpc.condense` (the condensed QP),
:mod:`~hydroarm.control.mpc.controller` (:class:`LinearMPC`); the box-QP backends are in
:mod:`hydroarm.control.qp`. The names below are re-exported here.

The method, in the error e = x - x_r of the state x = [q, v] (2n,) and the input
deviation du = u - u_r (n,):

* Nominal model: the dry rigid body plus an optional joint-acceleration
  feed-forward d (n,) (the GP-MPC puts its learned disturbance there):
  ``x' = f(x, u) = [v, ABA(q, v, u) + d]``, discretised with the control period T
  (``LinearMPC``'s ``control_period`` argument) by the second-order Taylor step
  (default) or the paper's explicit Euler step ``x_{k+1} = x_k + T f(x_k, u_k)``
  (``MPCConfig.discretisation``).
* Linearisation at every reference sample j (time j T) by
  :meth:`hydroarm.model.dynamics.nominal.NominalModel.linearise_into` (Pinocchio's analytical
  ABA derivatives; Euler: ``A_j = I + T df/dx``, ``B_j = T df/du``), at
  (x_r,j, u_r,j) with ``u_r,j = RNEA(q_r, v_r, a_r)`` (nominal inverse dynamics).
  The affine term ``c_j = x_next,j - x_r,j+1`` (``x_next,j`` the discrete model's step
  from (x_r,j, u_r,j); Euler: ``x_r,j + T f(x_r,j, u_r,j)``), plus the feed-forward
  ``T [0; d]`` (Taylor: ``[T^2/2 d; T d]``), makes ``e_{j+1} = A_j e_j + B_j du_j + c_j``
  exact to first order. Linearisations depend on the reference only, so they are
  cached by the integer time index ``j = round(t / T)`` in a sliding window of indices
  k .. k + N; as the horizon slides each step computes one new one (a jump in
  t or a new reference object rebuilds the window).
* Cost ``sum_{i<N} e_i' Q e_i + du_i' R du_i + e_N' P e_N``, Q = diag(q_position,
  q_velocity), R = diag(r), P the solution of the discrete algebraic Riccati
  equation (DARE, paper eqs. 16-17) at the horizon-end linearisation (index
  k + N), computed once per index by the structure-preserving doubling
  algorithm (:func:`solve_riccati`: quadratically convergent, history-free,
  compiled by numba; scipy's ``solve_discrete_are`` is the fallback). The first call
  in a fresh environment JIT-compiles it, then it is cached on disk like
  hydroarm.model.water.morison.
* Condensed QP in the stacked moves dU (N n,): ``min 1/2 dU' H dU + g' dU``
  subject to ``-u_max - u_r <= dU <= u_max - u_r`` (:func:`condense`); the QP
  objective equals the MPC cost minus the constant terms. The condensing runs
  compiled (numba, skipping the block-triangular zeros), equal to rounding to its
  NumPy twin :func:`condense_numpy`. Solved by DAQP (dense active set, warm-started
  from the shifted previous plan) by default; OSQP, quadprog and Clarabel are
  selectable (``MPCConfig.solver``; all behind
  :class:`~hydroarm.control.qp.BoxQPSolver`). The measurement behind the default is in
  docs/controllers.md ("The MPC: measured choices") and ``bench/mpc_solvers.py``.
* Terminal set (paper: ``e_N' P e_N <= alpha``) is infeasible at start-up of the
  paper task, so it is off by default. ``terminal_set="soft"`` adds it with a
  slack s >= 0 penalised linearly (``terminal_slack_penalty * s``), a convex
  second-order-cone program solved by Clarabel (exact, no polytope
  approximation) whatever ``solver`` says (clarabel is then required);
  ``"hard"`` tries the hard constraint first and falls back to soft
  (``status="terminal_soft_fallback"``) when Clarabel does not solve it
  (at start-up: primal infeasible). The penalty trades enforcement against
  violence; how the default 300 was chosen is measured in docs/controllers.md
  ("The MPC: measured choices"). Clarabel's reduced-accuracy "AlmostSolved" is
  accepted (the moves are still checked against the box).
* Failures: a solver that does not report an optimal solution (or returns
  non-finite or out-of-bounds moves) triggers, in order, the shifted previous
  plan (``status="qp_failed_shift"``), the saturated LQR law
  ``u = u_r - K e`` (``status="qp_failed_lqr"``) and, if the gain cannot be
  computed, the saturated reference torque (``status="qp_failed_reference"``);
  each failure is a fault event (``ControlOutput.events``). The returned torque is always
  clipped to the limits as a last guard (counted in ``LinearMPC.clip_count``).

Sign convention: ``K = (R + B' P B)^-1 B' P A`` and the LQR move is ``du = -K e``.
Units: SI (rad, rad/s, N m, s).
"""

from hydroarm.control.linear import RiccatiSolution, lqr_gain, riccati_solution, solve_riccati
from hydroarm.control.mpc.condense import CondensedQP, condense, condense_numpy
from hydroarm.control.mpc.config import MPCConfig
from hydroarm.control.mpc.controller import CLIP_TOLERANCE, LinearMPC, qp_failure_event
from hydroarm.control.qp import (
    QP_STATUSES,
    SOLVERS,
    BoxQPSolver,
    ClarabelBoxSolver,
    DaqpBoxSolver,
    OsqpBoxSolver,
    QPResult,
    QuadprogBoxSolver,
    make_box_qp_solver,
    solve_terminal_qp,
)

__all__ = [
    "CLIP_TOLERANCE",
    "QP_STATUSES",
    "SOLVERS",
    "BoxQPSolver",
    "ClarabelBoxSolver",
    "CondensedQP",
    "DaqpBoxSolver",
    "LinearMPC",
    "MPCConfig",
    "OsqpBoxSolver",
    "QPResult",
    "QuadprogBoxSolver",
    "RiccatiSolution",
    "condense",
    "condense_numpy",
    "lqr_gain",
    "make_box_qp_solver",
    "qp_failure_event",
    "riccati_solution",
    "solve_riccati",
    "solve_terminal_qp",
]
