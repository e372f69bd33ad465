"""Section 2a: the MPC's QP in do-mpc (CasADi + IPOPT) and cvxpy (OSQP, Clarabel).

The problems are snapshots of the MPC's own closed loop (horizon, weights, limits, the
linearisations A_k, B_k, c_k, terminal P and initial error of each step). Every peer's
first torque is checked against ours; its time is compared with our whole control step
(``speedup_full_step``) and with our condensing + DAQP on the same data
(``speedup_qp_only``). A peer that is not installed gives ``available: false`` and a reason.
"""

from __future__ import annotations

import contextlib
import io
import time
import warnings

import numpy as np

from hydroarm_bench.stats import FULL_SAMPLES, TARGETS, missing, ratio, stats_ms


def our_qp(mpc, snapshot) -> tuple[np.ndarray, float]:
    """Condense + DAQP on a snapshot: (first torque, seconds)."""
    from hydroarm.control.mpc import DaqpBoxSolver, condense

    solver = DaqpBoxSolver()
    start = time.perf_counter_ns()
    qp = condense(snapshot["A"], snapshot["B"], snapshot["c"], mpc._q_diag, mpc._r_diag, snapshot["P"], snapshot["e0"])
    u_ref = snapshot["u_ref"].ravel()
    limit = mpc._limit_stacked
    result = solver.solve(qp.H, qp.g, -limit - u_ref, limit - u_ref, None)
    elapsed = (time.perf_counter_ns() - start) * 1e-9
    n = mpc.n
    return np.clip(snapshot["u_ref"][0] + result.x[:n], -mpc.torque_limit, mpc.torque_limit), elapsed


class CvxpyMPC:
    """The same linear terminal MPC in cvxpy, in the sparse (states + inputs) form a user writes.

    Variables e_0..e_N (nx), du_0..du_{N-1} (nu); parameters A_k, B_k, c_k, e_0,
    the box ``-u_max - u_r,k <= du_k <= u_max - u_r,k`` and ``L`` with ``P = L L'``
    (so the problem is DPP and cvxpy canonicalises it once).
    """

    def __init__(self, horizon: int, q_diag: np.ndarray, r_diag: np.ndarray, limit: np.ndarray):
        import cvxpy as cp

        nx, nu = q_diag.size, r_diag.size
        self.cp = cp
        self.nu = nu
        self.A = [cp.Parameter((nx, nx)) for _ in range(horizon)]
        self.B = [cp.Parameter((nx, nu)) for _ in range(horizon)]
        self.c = [cp.Parameter(nx) for _ in range(horizon)]
        self.e0 = cp.Parameter(nx)
        self.low = cp.Parameter((horizon, nu))
        self.high = cp.Parameter((horizon, nu))
        self.L = cp.Parameter((nx, nx))
        self.limit = limit
        e = cp.Variable((horizon + 1, nx))
        du = cp.Variable((horizon, nu))
        self.du = du
        constraints = [e[0] == self.e0, du >= self.low, du <= self.high]
        cost = 0
        for k in range(horizon):
            constraints.append(e[k + 1] == self.A[k] @ e[k] + self.B[k] @ du[k] + self.c[k])
            cost += cp.sum(cp.multiply(q_diag, cp.square(e[k]))) + cp.sum(cp.multiply(r_diag, cp.square(du[k])))
        cost += cp.sum_squares(self.L.T @ e[horizon])
        self.problem = cp.Problem(cp.Minimize(cost), constraints)

    def solve(self, snapshot, solver: str) -> np.ndarray:
        cp = self.cp
        for k in range(len(self.A)):
            self.A[k].value = snapshot["A"][k]
            self.B[k].value = snapshot["B"][k]
            self.c[k].value = snapshot["c"][k]
        self.e0.value = snapshot["e0"]
        self.low.value = -self.limit - snapshot["u_ref"]
        self.high.value = self.limit - snapshot["u_ref"]
        P = 0.5 * (snapshot["P"] + snapshot["P"].T)
        self.L.value = np.linalg.cholesky(P)
        if solver == "OSQP":
            self.problem.solve(
                solver=cp.OSQP, warm_start=True, eps_abs=1e-9, eps_rel=1e-9, max_iter=200000, polishing=True
            )
        else:
            self.problem.solve(solver=cp.CLARABEL, tol_gap_abs=1e-10, tol_gap_rel=1e-10, tol_feas=1e-10)
        if self.problem.status not in ("optimal", "optimal_inaccurate"):
            raise RuntimeError(f"cvxpy {solver}: {self.problem.status}")
        u0 = snapshot["u_ref"][0] + self.du.value[0]
        return np.clip(u0, -self.limit, self.limit)


class DoMPC:
    """The same linear terminal MPC in do-mpc (discrete model, CasADi + IPOPT).

    State: the error e (nx); input: the torque u (nu) with constant bounds +-u_max;
    time-varying parameters per stage: A_k, B_k, c_k, u_r,k and the terminal P:
    ``e_{k+1} = A_k e_k + B_k (u_k - u_r,k) + c_k``, stage cost
    ``e'Qe + (u - u_r)'R(u - u_r)``, terminal cost ``e_N' P e_N``.
    """

    def __init__(self, horizon: int, period: float, q_diag: np.ndarray, r_diag: np.ndarray, limit: np.ndarray):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import casadi
            import do_mpc

        nx, nu = q_diag.size, r_diag.size
        model = do_mpc.model.Model("discrete", "SX")
        e = model.set_variable("_x", "e", shape=(nx, 1))
        u = model.set_variable("_u", "u", shape=(nu, 1))
        A = model.set_variable("_tvp", "A", shape=(nx, nx))
        B = model.set_variable("_tvp", "B", shape=(nx, nu))
        c = model.set_variable("_tvp", "c", shape=(nx, 1))
        u_ref = model.set_variable("_tvp", "u_ref", shape=(nu, 1))
        P = model.set_variable("_tvp", "P", shape=(nx, nx))
        model.set_rhs("e", A @ e + B @ (u - u_ref) + c)
        model.setup()
        mpc = do_mpc.controller.MPC(model)
        mpc.settings.n_horizon = horizon
        mpc.settings.t_step = period
        mpc.settings.store_full_solution = False
        mpc.settings.supress_ipopt_output()
        mpc.settings.nlpsol_opts.update({"ipopt.tol": 1e-10})
        du = u - u_ref
        lterm = e.T @ casadi.diag(q_diag) @ e + du.T @ casadi.diag(r_diag) @ du
        mpc.set_objective(lterm=lterm, mterm=e.T @ P @ e)
        mpc.bounds["lower", "_u", "u"] = -limit
        mpc.bounds["upper", "_u", "u"] = limit
        self.template = mpc.get_tvp_template()
        self.horizon = horizon
        mpc.set_tvp_fun(lambda t_now: self.template)
        with contextlib.redirect_stdout(io.StringIO()):
            mpc.setup()
        self.mpc = mpc
        self.started = False

    def solve(self, snapshot) -> np.ndarray:
        template = self.template
        for k in range(self.horizon + 1):
            j = min(k, self.horizon - 1)
            template["_tvp", k, "A"] = snapshot["A"][j]
            template["_tvp", k, "B"] = snapshot["B"][j]
            template["_tvp", k, "c"] = snapshot["c"][j]
            template["_tvp", k, "u_ref"] = snapshot["u_ref"][j]
            template["_tvp", k, "P"] = snapshot["P"]
        e0 = snapshot["e0"].reshape(-1, 1)
        with contextlib.redirect_stdout(io.StringIO()):
            if not self.started:
                self.mpc.x0 = e0
                self.mpc.set_initial_guess()
                self.started = True
            u0 = self.mpc.make_step(e0)
        status = self.mpc.solver_stats.get("return_status", "")
        if status not in ("Solve_Succeeded", "Solved_To_Acceptable_Level"):
            raise RuntimeError(f"do-mpc/IPOPT: {status}")
        return np.asarray(u0, dtype=float).ravel()


PEERS = {
    "do_mpc_ipopt": ("do_mpc", "casadi"),
    "cvxpy_osqp": ("cvxpy", "osqp"),
    "cvxpy_clarabel": ("cvxpy", "clarabel"),
}


def _peer_solver(label: str, mpc):
    """The peer's ``solve(snapshot) -> first torque``."""
    if label == "do_mpc_ipopt":
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # casadi's notices about NumPy on symbols
            peer = DoMPC(mpc.horizon, mpc.control_period, mpc._q_diag, mpc._r_diag, mpc.torque_limit)
        return peer.solve
    peer = CvxpyMPC(mpc.horizon, mpc._q_diag, mpc._r_diag, mpc.torque_limit)
    solver = "OSQP" if label == "cvxpy_osqp" else "CLARABEL"
    return lambda snapshot: peer.solve(snapshot, solver)


def bench_mpc_peers(recorded: dict, mpc_step: dict, quick: bool) -> dict:
    """Our MPC (full step and QP part) vs do-mpc and cvxpy on the same snapshots."""
    snapshots = [s for s in recorded["MPC"]["snapshots"] if s["status"] == "ok"]
    mpc = recorded["MPC"]["controller"]
    count = 10 if quick else FULL_SAMPLES
    chosen = [snapshots[i] for i in np.linspace(0, len(snapshots) - 1, min(count, len(snapshots))).astype(int)]
    ours_tau, ours_qp = [], []
    for _ in range(2):  # first pass warms caches
        ours_tau, ours_qp = [], []
        for snapshot in chosen:
            tau, seconds = our_qp(mpc, snapshot)
            ours_tau.append(tau)
            ours_qp.append(seconds)
    # our QP's first torque is the controller's (the snapshot's) torque
    own_check = max(float(np.abs(t - s["tau"]).max()) for t, s in zip(ours_tau, chosen))
    report = {
        "problem": {
            "horizon": mpc.horizon,
            "control_period_s": mpc.control_period,
            "q_diag": mpc._q_diag.tolist(),
            "r_diag": mpc._r_diag.tolist(),
            "torque_limit_nm": mpc.torque_limit.tolist(),
            "problems": len(chosen),
            "source": "states, linearisations and terminal P of the MPC's own closed loop on the paper task",
        },
        "ours_step_ms": mpc_step,
        "ours_qp_ms": stats_ms(ours_qp),
        "ours_qp_vs_controller_torque_max_abs_diff_nm": own_check,
        "peers": {},
    }
    for label, modules in PEERS.items():
        reason = missing(*modules)
        if reason is not None:
            report["peers"][label] = {"available": False, "reason": reason}
            continue
        try:
            solve = _peer_solver(label, mpc)
            solve(chosen[0])  # warm-up (canonicalisation, JIT, set-up)
            seconds, worst = [], 0.0
            for snapshot, tau in zip(chosen, ours_tau):
                start = time.perf_counter_ns()
                u0 = solve(snapshot)
                seconds.append((time.perf_counter_ns() - start) * 1e-9)
                worst = max(worst, float(np.abs(u0 - tau).max()))
            timing = stats_ms(seconds)
            report["peers"][label] = {
                "available": True,
                "step_ms": timing,
                "first_torque_max_abs_diff_nm": worst,
                "agrees_to_1e-4_nm": worst <= TARGETS["torque_agreement_nm"],
                "speedup_full_step": ratio(timing["median"], mpc_step["median"]),
                "speedup_qp_only": ratio(timing["median"], report["ours_qp_ms"]["median"]),
            }
        except Exception as error:  # a broken peer must not stop the suite
            report["peers"][label] = {"available": False, "reason": f"failed: {error!r}"}
    return report
