"""Which QP solver for the MPC, and what one MPC step costs, measured on the paper task.

1. Runs ``LinearMPC`` (DAQP) in closed loop on the paper task (underwater
   plant from rest at q = 0, or the dry nominal model) and records every
   condensed QP ``(H, g, lb, ub, warm start)`` and the per-phase step timings.
2. Solves that same sequence with every solver of ``hydroarm.control.mpc`` (DAQP warm
   and cold, OSQP warm-started with eps 1e-9 and polishing, quadprog, Clarabel),
   after one warm-up pass, timing each solve with ``time.perf_counter_ns``;
   reports median / p90 / p99 / max (us), failures, and the largest difference
   from DAQP's solution (max-norm, N m) and objective (relative).
3. Times the terminal-weight Riccati solve (doubling vs. scipy's DARE) and the
   condensing (compiled vs. its NumPy twin) on the linearisations of the task.

BLAS runs on one thread (environment variables before NumPy is imported, and
threadpoolctl). The load average is printed: other processes on the machine
inflate every number.

Usage::

    python bench/mpc_solvers.py [--duration 10] [--plant underwater|nominal]
                                [--horizon 10] [--r 0.1] [--torque-limit 500] [--period 0.01]
                                [--json results.json]
"""

from __future__ import annotations

import os

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import scipy.linalg  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

import hydroarm  # noqa: E402
from hydroarm.control.mpc import (  # noqa: E402
    LinearMPC,
    MPCConfig,
    condense,
    condense_numpy,
    make_box_qp_solver,
    solve_riccati,
)
from hydroarm.model.arm.plant import UnderwaterPlant  # noqa: E402
from hydroarm.model.dynamics.nominal import NominalModel  # noqa: E402
from hydroarm.model.task.references import paper_reference  # noqa: E402


def percentiles(samples_ns) -> dict[str, float]:
    """median / p90 / p99 / max of nanosecond samples, in microseconds."""
    values = np.asarray(samples_ns, dtype=float) / 1e3
    return {
        "median_us": float(np.median(values)),
        "p90_us": float(np.percentile(values, 90)),
        "p99_us": float(np.percentile(values, 99)),
        "max_us": float(values.max()),
        "count": int(values.size),
    }


def record(arm, plant, duration: float, config: MPCConfig, period: float):
    """Closed loop from rest at q = 0 with control period ``period`` (s): the QP sequence
    and the step timings."""
    reference = paper_reference()
    mpc = LinearMPC(arm, config, period)
    solver = mpc._solver
    original = solver.solve
    qps = []

    def recording(H, g, lb, ub, x0=None):
        qps.append((H.copy(), g.copy(), lb.copy(), ub.copy(), None if x0 is None else x0.copy()))
        return original(H, g, lb, ub, x0)

    solver.solve = recording
    x = np.zeros(2 * arm.n_joints)
    timings: dict[str, list[float]] = {}
    statuses: dict[str, int] = {}
    errors = []
    for k in range(int(round(duration / period))):
        t = k * period
        out = mpc.compute(t, x, reference)
        for key, value in out.timings.items():
            timings.setdefault(key, []).append(value * 1e9)
        statuses[out.status] = statuses.get(out.status, 0) + 1
        x, _ = plant.step(t, x, out.tau, period)
        errors.append(x[: arm.n_joints] - reference.sample(t + period)[0])
    solver.solve = original
    e_p = np.mean(np.square(errors), axis=0)
    return qps, timings, statuses, e_p, mpc


def objective(H, g, x) -> float:
    return float(0.5 * x @ H @ x + g @ x)


def time_solvers(qps, names) -> dict[str, dict]:
    """Every solver on the recorded sequence: one warm-up pass, then one timed pass."""
    daqp_solutions = []
    daqp = make_box_qp_solver("daqp")
    for H, g, lb, ub, x0 in qps:
        daqp_solutions.append(daqp.solve(H, g, lb, ub, x0).x)
    results = {}
    for label, name, warm in names:
        solver = make_box_qp_solver(name)
        for H, g, lb, ub, x0 in qps:  # warm-up pass (also fills caches, JIT, set-up)
            solver.solve(H, g, lb, ub, x0 if warm else None)
        samples, failures, worst_x, worst_f, messages = [], 0, 0.0, 0.0, set()
        for (H, g, lb, ub, x0), x_daqp in zip(qps, daqp_solutions):
            start = time.perf_counter_ns()
            result = solver.solve(H, g, lb, ub, x0 if warm else None)
            samples.append(time.perf_counter_ns() - start)
            if not result.ok:
                failures += 1
                messages.add(result.message)
                continue
            worst_x = max(worst_x, float(np.abs(result.x - x_daqp).max()))
            f_daqp = objective(H, g, x_daqp)
            worst_f = max(worst_f, abs(objective(H, g, result.x) - f_daqp) / max(1.0, abs(f_daqp)))
        results[label] = {
            **percentiles(samples),
            "failures": failures,
            "failure_messages": sorted(messages),
            "max_abs_diff_from_daqp": worst_x,
            "max_rel_objective_diff": worst_f,
        }
    return results


def time_riccati_and_condensing(arm, config: MPCConfig, period: float, steps: int) -> dict[str, dict]:
    """Doubling vs. scipy DARE on the task's linearisations, and the condensing alone."""
    reference = paper_reference()
    horizon = config.horizon
    mpc = LinearMPC(arm, config, period)
    nominal = NominalModel(arm)
    points = []
    for k in range(steps + horizon + 1):
        q, v, a = reference.sample(k * period)
        tau = arm.inverse_dynamics(q, v, a)
        a_mat, b_mat, x_next = nominal.linearise(q, v, tau, period, "euler")
        points.append((a_mat, b_mat, x_next, np.concatenate([q, v])))
    solve_riccati(points[0][0], points[0][1], mpc.Q, mpc.R)  # JIT / cache load
    doubling, scipy_dare, iterations, worst = [], [], [], 0.0
    for a_mat, b_mat, _, _ in points[:steps]:
        start = time.perf_counter_ns()
        solution = solve_riccati(a_mat, b_mat, mpc.Q, mpc.R)
        doubling.append(time.perf_counter_ns() - start)
        start = time.perf_counter_ns()
        exact = scipy.linalg.solve_discrete_are(a_mat, b_mat, mpc.Q, mpc.R)
        scipy_dare.append(time.perf_counter_ns() - start)
        iterations.append(solution.iterations)
        worst = max(worst, float(np.abs(solution.P - exact).max() / np.abs(exact).max()))
    q_diag, r_diag = np.diag(mpc.Q).copy(), np.diag(mpc.R).copy()
    condensing, condensing_numpy = [], []
    for k in range(steps):
        window = points[k : k + horizon + 1]
        A = np.stack([p[0] for p in window[:horizon]])
        B = np.stack([p[1] for p in window[:horizon]])
        c = np.stack([p[2] for p in window[:horizon]]) - np.stack([p[3] for p in window[1:]])
        start = time.perf_counter_ns()
        condense(A, B, c, q_diag, r_diag, mpc.Q * 50.0, np.full(2 * arm.n_joints, 0.01))
        condensing.append(time.perf_counter_ns() - start)
        start = time.perf_counter_ns()
        condense_numpy(A, B, c, q_diag, r_diag, mpc.Q * 50.0, np.full(2 * arm.n_joints, 0.01))
        condensing_numpy.append(time.perf_counter_ns() - start)
    return {
        "riccati_doubling": {
            **percentiles(doubling),
            "mean_iterations": float(np.mean(iterations)),
            "max_rel_diff_from_scipy": worst,
        },
        "riccati_scipy_dare": percentiles(scipy_dare),
        "condense": percentiles(condensing),
        "condense_numpy": percentiles(condensing_numpy),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--duration", type=float, default=10.0, help="s of the paper task")
    parser.add_argument("--plant", choices=["underwater", "nominal"], default="underwater")
    parser.add_argument("--horizon", type=int, default=10)
    parser.add_argument("--r", type=float, default=0.1, help="R weight")
    parser.add_argument("--torque-limit", type=float, default=None, help="N m (default: the arm's)")
    parser.add_argument("--period", type=float, default=0.01, help="control period T (s)")
    parser.add_argument("--json", help="also write the results to this file")
    args = parser.parse_args()
    threadpool_limits(1)
    load_start = os.getloadavg()
    arm = hydroarm.load_arm("paper")
    plant = UnderwaterPlant(arm) if args.plant == "underwater" else NominalModel(arm)
    config = MPCConfig(horizon=args.horizon, r=args.r, torque_limit=args.torque_limit)
    LinearMPC(arm, config, args.period).compute(0.0, np.zeros(12), paper_reference())  # JIT / cache load

    qps, step_timings, statuses, e_p, _ = record(arm, plant, args.duration, config, args.period)
    active = [
        int(np.sum(np.isclose(x, lb, atol=1e-9) | np.isclose(x, ub, atol=1e-9)))
        for x, (_, _, lb, ub, _) in zip([make_box_qp_solver("daqp").solve(*qp[:4]).x for qp in qps], qps)
    ]
    solvers = time_solvers(
        qps,
        [
            ("daqp (warm)", "daqp", True),
            ("daqp (cold)", "daqp", False),
            ("osqp (warm, eps 1e-10)", "osqp", True),
            ("quadprog", "quadprog", False),
            ("clarabel", "clarabel", False),
        ],
    )
    parts = time_riccati_and_condensing(arm, config, args.period, min(len(qps), 600))
    results = {
        "setup": {
            "plant": args.plant,
            "duration_s": args.duration,
            "horizon": args.horizon,
            "period_s": args.period,
            "r": args.r,
            "torque_limit": args.torque_limit,
            "qp_variables": int(qps[0][1].size),
            "qps": len(qps),
            "qps_with_active_bounds": int(np.sum(np.array(active) > 0)),
            "mean_active_bounds": float(np.mean(active)),
            "statuses": statuses,
            "E_p_per_joint_rad2": [float(v) for v in e_p],
            "load_average_start": load_start,
            "load_average_end": os.getloadavg(),
        },
        "mpc_step": {key: percentiles(values) for key, values in step_timings.items()},
        "solvers": solvers,
        **parts,
    }
    print(f"setup: {json.dumps(results['setup'])}")
    print("\nMPC step (closed loop, DAQP), us:")
    for key, row in results["mpc_step"].items():
        print(f"  {key:12s} median {row['median_us']:8.1f}  p90 {row['p90_us']:8.1f}  p99 {row['p99_us']:8.1f}")
    print("\nQP solvers on the same sequence, us:")
    for key, row in solvers.items():
        print(
            f"  {key:30s} median {row['median_us']:8.1f}  p90 {row['p90_us']:8.1f}  p99 {row['p99_us']:8.1f}"
            f"  max {row['max_us']:8.1f}  fail {row['failures']}  |x - x_daqp| {row['max_abs_diff_from_daqp']:.1e}"
            f"  rel obj {row['max_rel_objective_diff']:.1e}  {' '.join(row['failure_messages'])}"
        )
    print("\nParts, us:")
    for key in ("riccati_doubling", "riccati_scipy_dare", "condense", "condense_numpy"):
        row = results[key]
        extra = {k: v for k, v in row.items() if not k.endswith("_us") and k != "count"}
        print(
            f"  {key:20s} median {row['median_us']:8.1f}  p90 {row['p90_us']:8.1f}  p99 {row['p99_us']:8.1f}  {extra}"
        )
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(results, handle, indent=2)


if __name__ == "__main__":
    main()
