"""Section ``planner``: PI-IDMPC's step with its planner (the flagship candidate), and the plan
solver against DAQP side by side.

- ``step``: PI-IDMPC's whole step (compute + observe, the planner included) on the paper scenario,
  over ``runs`` 10 s runs (>= 10^4 steps in full mode) after a warm-up run (numba caches, first
  allocations: its first step is reported apart, ``warmup_first_step_ms``), once with each of the
  planner's QP solvers (``pi_idmpc.planner_solver``) in the same process; the steps that replanned
  are also given apart (``replan_steps``). Targets of issue 32: median <= 0.3 ms, p99 <= 1 ms,
  max <= 5 ms.
- ``solver``: the planner's own QPs, recorded in one run, solved again by DAQP and by the
  structured solver (:mod:`hydroarm.control.plan_qp`) from the same warm starts: per-solve
  median / p99 / max, their ratios (DAQP over structured: > 1 is faster), and the largest
  difference of the plans (relative to the largest move).
"""

from __future__ import annotations

import time

import numpy as np

from hydroarm_bench.loop import TimedController, paper_experiment
from hydroarm_bench.stats import stats_ms

NAME = "PI-IDMPC"
SOLVERS = ("structured", "daqp")
TARGETS_MS = {"median": 0.3, "p99": 1.0, "max": 5.0}
DURATION_S = 10.0


def _planner_controller(controller):
    """The PI-IDMPC inside a wrapper (a state filter's ``controller``), or itself."""
    while not hasattr(controller, "planner") and hasattr(controller, "controller"):
        controller = controller.controller
    return controller


def _one_run(solver: str, seed: int, duration: float = DURATION_S):
    """(step seconds (compute + observe), replanned (bool per step), experiment's controller)."""
    experiment = paper_experiment(NAME, duration, {"pi_idmpc.planner_solver": solver})
    pi = _planner_controller(experiment.controller)
    replanned: list[bool] = []
    attempts = [0]
    inner_replan = pi._replan

    def counted_replan(*args):
        attempts[0] += 1
        return inner_replan(*args)

    pi._replan = counted_replan

    def hook(_controller, _t, _y, _out):
        replanned.append(attempts[0] > 0)
        attempts[0] = 0

    timed = TimedController(experiment.controller, hook)
    experiment.controller = timed
    traj = experiment.run(seed)
    steps = len(timed.observe_s)
    total = np.asarray(traj.timings["total"][:steps], dtype=float) + np.asarray(timed.observe_s)
    return total, np.asarray(replanned[:steps], dtype=bool), pi


def bench_planner_step(quick: bool) -> dict:
    """The flagship candidate's step statistics per planner solver (module docstring)."""
    runs = 2 if quick else 11  # 11 x 999 observed steps: >= 10^4
    warm, _, _ = _one_run("structured", 0, 0.3)
    out = {"controller": NAME, "runs": runs, "duration_s": DURATION_S, "warmup_first_step_ms": 1e3 * float(warm[0])}
    for solver in SOLVERS:
        _one_run(solver, 0, 0.3)  # this solver's own caches
        steps, replans = [], []
        fallbacks = 0
        for seed in range(runs):
            total, replanned, pi = _one_run(solver, seed)
            steps.append(total)
            replans.append(replanned)
            fallbacks += pi.planner.fallbacks
        total = np.concatenate(steps)
        replanned = np.concatenate(replans)
        row = {
            "step": stats_ms(total),
            "replan_steps": stats_ms(total[replanned]),
            "other_steps": stats_ms(total[~replanned]),
            "replans": int(replanned.sum()),
            "daqp_fallbacks": int(fallbacks),
        }
        row["meets"] = {key: row["step"][key] <= limit for key, limit in TARGETS_MS.items()}
        out[solver] = row
    out["targets_ms"] = dict(TARGETS_MS)
    fast, dense = out["structured"]["replan_steps"], out["daqp"]["replan_steps"]
    out["replan_ratio_daqp_over_structured"] = {key: dense[key] / fast[key] for key in ("median", "p99", "max")}
    return out


def record_plan_problems(duration: float = DURATION_S) -> tuple[object, list]:
    """The planner's QPs of one paper run (DAQP's path): ``(planner, [(gradient, rows, upper,
    lower, lam_in)])`` with the warm start each solve was given."""
    experiment = paper_experiment(NAME, duration, {"pi_idmpc.planner_solver": "daqp"})
    planner = _planner_controller(experiment.controller).planner
    problems = []
    inner = planner._solve_qp

    def recording(gradient, rows, upper, lower, lam=None):
        problems.append(
            (gradient.copy(), rows.copy(), upper.copy(), lower.copy(), None if lam is None else np.array(lam))
        )
        return inner(gradient, rows, upper, lower, lam)

    planner._solve_qp = recording
    experiment.run(0)
    return planner, problems


def bench_plan_solver(quick: bool) -> dict:
    """The planner's recorded QPs by DAQP and by the structured solver (module docstring)."""
    from hydroarm.control.idmpc_limits import HorizonQP
    from hydroarm.control.plan_qp import joint_factors

    planner, problems = record_plan_problems()
    repeat = 1 if quick else 5
    factors = {"structured": joint_factors(planner.hessian, planner.n), "daqp": None}
    planner.fallbacks = 0

    def solve(name, *problem):
        planner._factors = factors[name]  # the same problem data, the solver chosen as HorizonQP does
        return HorizonQP._solve_qp(planner, *problem)

    seconds = {name: [] for name in SOLVERS}
    plans = {name: [] for name in SOLVERS}
    for gradient, rows, upper, lower, lam in problems:
        for name in SOLVERS:
            solve(name, gradient, rows, upper, lower, lam)  # once untimed: caches
            for _ in range(repeat):
                start = time.perf_counter_ns()
                moves, multipliers, ok = solve(name, gradient, rows, upper, lower, lam)
                seconds[name].append((time.perf_counter_ns() - start) * 1e-9)
            plans[name].append((np.asarray(moves), np.sign(multipliers), ok))
    deviation, same_sets = 0.0, 0
    for (mine, sign_mine, _), (ref, sign_ref, _) in zip(plans["structured"], plans["daqp"], strict=True):
        deviation = max(deviation, float(np.abs(mine - ref).max() / max(1.0, np.abs(ref).max())))
        same_sets += bool(np.array_equal(sign_mine, sign_ref))
    out = {
        "problems": len(problems),
        "size": {"variables": planner.horizon * planner.n, "rows": planner.horizon * planner.n},
        "repeat": repeat,
        **{name: stats_ms(values) for name, values in seconds.items()},
        "max_relative_plan_difference": deviation,
        "same_active_set": same_sets,
        "structured_fallbacks": planner.fallbacks // (repeat + 1),
    }
    out["ratio_daqp_over_structured"] = {
        key: out["daqp"][key] / out["structured"][key] for key in ("median", "p99", "max")
    }
    return out


def bench_planner(quick: bool) -> dict:
    """The section: ``{"step": ..., "solver": ...}``."""
    return {"step": bench_planner_step(quick), "solver": bench_plan_solver(quick)}


def render_planner(section: dict) -> str:
    """The section of bench.md."""
    step, solver = section["step"], section["solver"]
    lines = [
        "\n## PI-IDMPC's step with its planner, and the plan solver against DAQP\n",
        f"{step['runs']} runs of {step['duration_s']:.0f} s on the paper scenario; the whole step "
        "(compute + observe, the planner included), ms:\n",
        "| planner solver | steps | median | p99 | max | replans | replan steps median / p99 / max |",
        "|---|---|---|---|---|---|---|",
    ]
    for name in SOLVERS:
        row = step[name]
        s, r = row["step"], row["replan_steps"]
        lines.append(
            f"| {name} | {s['n']} | {s['median']:.3f} | {s['p99']:.3f} | {s['max']:.3f} | {row['replans']} | "
            f"{r['median']:.2f} / {r['p99']:.2f} / {r['max']:.2f} |"
        )
    lines += [
        "",
        f"Targets: median <= {TARGETS_MS['median']} ms, p99 <= {TARGETS_MS['p99']} ms, max <= {TARGETS_MS['max']} ms "
        f"(met with the structured solver: {step['structured']['meets']}). First step of the warm-up run: "
        f"{step['warmup_first_step_ms']:.1f} ms.\n",
        f"The planner's {solver['problems']} QPs of one run ({solver['size']['variables']} moves, "
        f"{solver['size']['rows']} torque rows), ms per solve:\n",
        "| solver | median | p99 | max |",
        "|---|---|---|---|",
    ]
    for name in SOLVERS:
        row = solver[name]
        lines.append(f"| {name} | {row['median']:.3f} | {row['p99']:.3f} | {row['max']:.3f} |")
    ratio = solver["ratio_daqp_over_structured"]
    lines.append(
        f"\nDAQP / structured: median {ratio['median']:.1f}x, p99 {ratio['p99']:.1f}x, max {ratio['max']:.1f}x; "
        f"largest plan difference {solver['max_relative_plan_difference']:.1e} (relative), same active set in "
        f"{solver['same_active_set']} of {solver['problems']}.\n"
    )
    return "\n".join(lines)
