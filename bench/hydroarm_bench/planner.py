"""Section ``planner``: PI-IDMPC's step with its planner (the flagship candidate), and the plan
solver against DAQP side by side.

- ``step``: PI-IDMPC's whole step (compute + observe, the planner included) on the paper scenario,
  over ``runs`` 10 s runs (>= 10^4 steps in full mode) after a warm-up run (numba caches, first
  allocations: its first step is reported apart, ``warmup_first_step_ms``), once with each of the
  planner's QP solvers (``pi_idmpc.planner_solver``) in the same process; the steps that replanned
  are also given apart (``replan_steps``). Targets of issue 32: median <= 0.3 ms, p99 <= 1 ms,
  max <= 5 ms.
- ``beside``: the planner beside the loop (``pi_idmpc.plan_latency`` = :data:`LATENCY`,
  ``plan_worker = "process"``): the control step (compute + observe in the control process; it
  waits only when the worker is late), in a loop paced at the control period (each step starts
  at its tick, as on an arm: the worker gets the wall time it would have; quick mode unpaced),
  in wall and CPU time, and the worker's own time per plan against its budget of L periods.
- ``solver``: the planner's own QPs, recorded in one run, solved again by DAQP and by the
  structured solver (:mod:`hydroarm.control.plan_qp`) from the same warm starts: per-solve
  median / p99 / max, their ratios (DAQP over structured: > 1 is faster), and the largest
  difference of the plans (relative to the largest move).
- ``rate``: the rate-limited horizon QP of IDMPC, GP-IDMPC and PI-IDMPC, structured solver
  against DAQP (:mod:`hydroarm_bench.rate_qp`).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from hydroarm_bench.loop import TimedController, paper_experiment
from hydroarm_bench.rate_qp import bench_rate_qp, render_rate_qp
from hydroarm_bench.stats import STEP_BARS_MS, meets_bars, stats_ms

NAME = "PI-IDMPC"
SOLVERS = ("structured", "daqp")
DURATION_S = 10.0
QUICK_DURATION_S = 2.0
"""The runs' length in quick mode (CI: the report's shape, not its statistics): 200 steps a run."""


def _run_length(quick: bool) -> float:
    """Each timed run's length (s): :data:`QUICK_DURATION_S` in quick mode, else :data:`DURATION_S`."""
    return QUICK_DURATION_S if quick else DURATION_S


ARMS = {
    "ur5": "ur5",
    "alpha5": "alpha5",
    "iiwa14": str(Path(__file__).resolve().parents[2] / "examples" / "urdf" / "iiwa14.hydro.toml"),
}
"""The other arms of the full suite's step rows (one 10 s run each per solver)."""


def _planner_controller(controller):
    """The PI-IDMPC inside a wrapper (a state filter's ``controller``), or itself."""
    while not hasattr(controller, "planner") and hasattr(controller, "controller"):
        controller = controller.controller
    return controller


PHASES = ("rollout", "linearise", "qp")
"""The replan's parts timed apart: the IDMPC's closed loop on the model (``_rollout``), the
linearisations along the plan (``linearised_rows``: RNEA derivatives, the water along the plan,
the rows) and the QP solves (``_solve_qp``)."""


def _timed(owner, name: str, clock: dict, counts: dict, key: str) -> None:
    """Replace ``owner.name`` by a wrapper adding its seconds to ``clock[key]`` and 1 to ``counts[key]``."""
    inner = getattr(owner, name)

    def wrapper(*args, **kwargs):
        start = time.perf_counter_ns()
        try:
            return inner(*args, **kwargs)
        finally:
            clock[key] += (time.perf_counter_ns() - start) * 1e-9
            counts[key] += 1

    setattr(owner, name, wrapper)


def _one_run(solver: str, seed: int, duration: float = DURATION_S, overrides: dict | None = None):
    """(step seconds (compute + observe), replanned (bool per step), phase seconds per step
    ({phase: (steps,)}, and ``cpu``: the step in CPU time), phase calls per step, the
    experiment's PI-IDMPC)."""
    experiment = paper_experiment(NAME, duration, {"pi_idmpc.planner_solver": solver, **(overrides or {})})
    pi = _planner_controller(experiment.controller)
    clock = dict.fromkeys(("replan", *PHASES), 0.0)
    counts = dict.fromkeys(("replan", *PHASES), 0)
    _timed(pi, "_replan", clock, counts, "replan")
    _timed(pi, "_rollout", clock, counts, "rollout")
    _timed(pi.planner, "linearised_rows", clock, counts, "linearise")
    _timed(pi.planner, "_solve_qp", clock, counts, "qp")
    phases = {key: [] for key in clock}
    calls = {key: [] for key in counts}

    def hook(_controller, _t, _y, _out):
        for key in clock:
            phases[key].append(clock[key])
            calls[key].append(counts[key])
            clock[key], counts[key] = 0.0, 0

    timed = TimedController(experiment.controller, hook)
    experiment.controller = timed
    traj = experiment.run(seed)
    steps = len(timed.observe_s)
    total = np.asarray(traj.timings["total"][:steps], dtype=float) + np.asarray(timed.observe_s)
    phases = {key: np.asarray(value[:steps]) for key, value in phases.items()}
    calls = {key: np.asarray(value[:steps]) for key, value in calls.items()}
    phases["cpu"] = np.asarray(timed.cpu_s[:steps])  # the step's compute + observe in CPU time
    return total, calls["replan"] > 0, phases, calls, pi


def _replan_breakdown(total, replanned, phases, calls) -> dict:
    """Where a replan step's time goes: per phase its time per replan step (stats) and share of
    the replan steps' summed time, and its calls per replan step (mean, max)."""
    spent = total[replanned].sum()
    out = {}
    for key in PHASES:
        seconds, count = phases[key][replanned], calls[key][replanned]
        out[key] = {
            **stats_ms(seconds),
            "share": float(seconds.sum() / spent) if spent > 0 else None,
            "calls_mean": float(count.mean()) if count.size else None,
            "calls_max": int(count.max()) if count.size else None,
        }
    rest = total[replanned] - sum(phases[key][replanned] for key in PHASES)
    out["rest"] = {**stats_ms(rest), "share": float(rest.sum() / spent) if spent > 0 else None}
    return out


def bench_planner_step(quick: bool) -> dict:
    """The flagship candidate's step statistics per planner solver (module docstring)."""
    runs = 1 if quick else 11  # 11 x 999 observed steps: >= 10^4; quick (CI): shape only
    warm = _one_run("structured", 0, 0.3)[0]
    duration = _run_length(quick)
    out = {"controller": NAME, "runs": runs, "duration_s": duration, "warmup_first_step_ms": 1e3 * float(warm[0])}
    for solver in SOLVERS:
        _one_run(solver, 0, 0.3)  # this solver's own caches
        results = [_one_run(solver, seed, duration) for seed in range(runs)]
        total = np.concatenate([r[0] for r in results])
        replanned = np.concatenate([r[1] for r in results])
        phases = {key: np.concatenate([r[2][key] for r in results]) for key in results[0][2]}
        calls = {key: np.concatenate([r[3][key] for r in results]) for key in results[0][3]}
        row = {
            "step": stats_ms(total),
            "replan_steps": stats_ms(total[replanned]),
            "other_steps": stats_ms(total[~replanned]),
            "replans": int(replanned.sum()),
            "daqp_fallbacks": int(sum(r[4].planner.fallbacks for r in results)),
            "replan_breakdown": _replan_breakdown(total, replanned, phases, calls),
            "step_cpu": stats_ms(phases["cpu"]),
            "replan_steps_cpu": stats_ms(phases["cpu"][replanned]),
        }
        row["meets"] = meets_bars(row["step"])
        out[solver] = row
    out["targets_ms"] = dict(STEP_BARS_MS)
    fast, dense = out["structured"]["replan_steps"], out["daqp"]["replan_steps"]
    out["replan_ratio_daqp_over_structured"] = {key: dense[key] / fast[key] for key in ("median", "p99", "max")}
    fast, dense = out["structured"]["step"], out["daqp"]["step"]
    out["step_ratio_daqp_over_structured"] = {key: dense[key] / fast[key] for key in ("median", "p99", "max")}
    if not quick:
        out["arms"] = bench_planner_arms()
    return out


LATENCY = 1
"""The plan latency (periods) of the ``beside`` rows: the one that keeps the planner's accuracy since
the plan's start state is predicted by the model under the torque held (docs/controllers.md, "The
planner beside the loop"; it was 2 with the double integrator's prediction)."""


BUDGETED = {
    "pi_idmpc.planner_solver": "structured",
    "pi_idmpc.planner_budget": 120,
    "pi_idmpc.planner_iterations": 2,
    "pi_idmpc.plan_prediction_steps": 2,
}
"""The plan's cost bounded (the ``beside`` rows' third configuration): 120 active-set iterations a
plan over 2 SQP steps, the prediction in 2 RK4 steps a period (wk/ot, 2026-12-04: both clean targets
kept, paper 0.025699, UR5 limits 0.079868; docs/controllers.md)."""

BESIDE_ROWS = {
    "daqp": {"pi_idmpc.planner_solver": "daqp"},
    "structured": {"pi_idmpc.planner_solver": "structured"},
    "structured, budget 120": BUDGETED,
}
"""The ``beside`` rows' configurations of the planner (label -> settings)."""


def bench_planner_beside(quick: bool) -> dict:
    """PI-IDMPC with its planner beside the loop (module docstring, ``beside``): per case (the
    paper scenario, and the paper arm with the UR5's torque limits) and planner configuration
    (:data:`BESIDE_ROWS`), ``step`` (wall, compute + observe in the control process),
    ``step_cpu``, ``waited`` (steps that waited > 0.1 ms for the worker), ``plan`` / ``plan_cpu``
    (the worker's own time per plan) and ``plans_over_budget``. Quick mode (CI): one unpaced run,
    the paper scenario only."""
    runs = 1 if quick else PACED_RUNS
    cases = {"paper": {}, "paper, UR5 limits": {"torque_limit": [150.0, 150.0, 150.0, 28.0, 28.0, 28.0]}}
    if quick:
        cases.pop("paper, UR5 limits")
    duration = _run_length(quick)
    out: dict = {"latency_periods": LATENCY, "runs": runs, "duration_s": duration, "cases": {}}
    for case, overrides in cases.items():
        out["cases"][case] = {}
        for label, planner in BESIDE_ROWS.items():
            settings = {"pi_idmpc.plan_latency": LATENCY, "pi_idmpc.plan_worker": "process", **overrides, **planner}
            out["cases"][case][label] = _beside_row(settings, runs, not quick, duration)
    return out


PACED_RUNS = 3
"""10 s runs per ``beside`` row in full mode: paced, each takes 10 s of wall time."""


def _beside_row(settings: dict, runs: int, paced: bool = True, duration: float = DURATION_S) -> dict:
    """One row of :func:`bench_planner_beside`: ``runs`` runs of ``duration`` s after a 0.3 s warm-up run,
    paced at the control period or not (:class:`~hydroarm_bench.loop.TimedController`)."""
    step, cpu, wait, plan, plan_cpu = [], [], [], [], []
    for seed in range(-1, runs):  # -1: the warm-up run
        experiment = paper_experiment(NAME, 0.3 if seed < 0 else duration, settings)
        timed = TimedController(experiment.controller, paced=paced and seed >= 0)
        experiment.controller = timed
        traj = experiment.run(max(seed, 0))
        _planner_controller(timed.inner).close()
        if seed < 0:
            continue
        steps = len(timed.observe_s)
        timings = {key: np.asarray(value[:steps], dtype=float) for key, value in traj.timings.items()}
        step.append(timings["total"] + np.asarray(timed.observe_s))
        cpu.append(np.asarray(timed.cpu_s[:steps]))
        wait.append(timings["wait"])
        solved = timings["replan"] > 0
        plan.append(timings["replan"][solved])
        plan_cpu.append(timings["replan_cpu"][solved])
    plan_all, budget = np.concatenate(plan), LATENCY * experiment.config.control_period
    row = {
        "step": stats_ms(np.concatenate(step)),
        "step_cpu": stats_ms(np.concatenate(cpu)),
        "waited": int((np.concatenate(wait) > 1e-4).sum()),
        "plan": stats_ms(plan_all),
        "plan_cpu": stats_ms(np.concatenate(plan_cpu)),
        "plans_over_budget": int((plan_all > budget).sum()),
        "paced": paced,
    }
    row["meets"] = meets_bars(row["step"])
    row["meets_cpu"] = meets_bars(row["step_cpu"])
    return row


def bench_planner_arms() -> dict:
    """PI-IDMPC's whole step on the other arms (:data:`ARMS`), one 10 s run per solver each
    (after a 0.3 s warm-up run): ``{arm: {solver: {"step", "replan_steps", "replans", "meets"}}}``."""
    out: dict = {}
    for name, arm in ARMS.items():
        out[name] = {}
        for solver in SOLVERS:
            _one_run(solver, 0, 0.3, {"arm": arm})
            total, replanned, phases, _, _ = _one_run(solver, 0, DURATION_S, {"arm": arm})
            step = stats_ms(total)
            out[name][solver] = {
                "step": step,
                "replan_steps": stats_ms(total[replanned]),
                "step_cpu": stats_ms(phases["cpu"]),
                "replans": int(replanned.sum()),
                "meets": meets_bars(step),
            }
    return out


def record_plan_problems(duration: float = DURATION_S) -> tuple[object, list]:
    """The planner's QPs of one paper run (DAQP's path): ``(planner, [(gradient, rows, upper,
    lower, lam_in)])`` with the warm start each solve was given."""
    experiment = paper_experiment(NAME, duration, {"pi_idmpc.planner_solver": "daqp"})
    planner = _planner_controller(experiment.controller).planner
    problems = []
    inner = planner._solve_qp

    def recording(gradient, rows, upper, lower, lam=None, limit=None):
        problems.append(
            (gradient.copy(), rows.copy(), upper.copy(), lower.copy(), None if lam is None else np.array(lam))
        )
        return inner(gradient, rows, upper, lower, lam, limit=limit)

    planner._solve_qp = recording
    experiment.run(0)
    return planner, problems


def bench_plan_solver(quick: bool) -> dict:
    """The planner's recorded QPs by DAQP and by the structured solver (module docstring)."""
    from hydroarm.control.idmpc_limits import HorizonQP
    from hydroarm.control.plan_qp import joint_factors

    planner, problems = record_plan_problems(_run_length(quick))
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
    """The section: ``{"step": ..., "beside": ..., "solver": ..., "rate": ...}`` (``rate``:
    :mod:`hydroarm_bench.rate_qp`)."""
    step, beside = bench_planner_step(quick), bench_planner_beside(quick)
    return {"step": step, "beside": beside, "solver": bench_plan_solver(quick), "rate": bench_rate_qp(quick)}


def _render_breakdown(breakdown: dict) -> list[str]:
    """bench.md lines: where the structured solver's replan steps spend their time."""
    lines = [
        "Where a replan step's time goes (structured solver), ms per replan step:\n",
        "| part | median | p99 | max | share | calls per replan (mean / max) |",
        "|---|---|---|---|---|---|",
    ]
    for key, row in breakdown.items():
        if row["n"] == 0:
            continue
        calls = f"{row['calls_mean']:.1f} / {row['calls_max']}" if "calls_mean" in row else ""
        times = f"{row['median']:.2f} | {row['p99']:.2f} | {row['max']:.2f}"
        lines.append(f"| {key} | {times} | {100 * row['share']:.0f} % | {calls} |")
    return [*lines, ""]


def _render_cpu(step: dict) -> list[str]:
    """bench.md lines: the step in CPU time (what the wall time's tail owes to the machine's load)."""
    lines = ["The same steps in this thread's CPU time (the load's preemptions left out), ms:\n"]
    lines += ["| planner solver | median | p99 | max | replan steps median / p99 / max |", "|---|---|---|---|---|"]
    for name in SOLVERS:
        s, r = step[name].get("step_cpu"), step[name].get("replan_steps_cpu")
        if s is None or s["n"] == 0:
            return []
        replan = f"{r['median']:.2f} / {r['p99']:.2f} / {r['max']:.2f}" if r["n"] else "-"
        lines.append(f"| {name} | {s['median']:.3f} | {s['p99']:.3f} | {s['max']:.3f} | {replan} |")
    return [*lines, ""]


def _render_arms(arms: dict) -> list[str]:
    """bench.md lines: the step on the other arms."""
    if not arms:
        return []
    lines = [
        "The other arms, one 10 s run each, ms (whole step; replan steps):\n",
        "| arm | solver | steps | median | p99 | max | replans | replan median / max | CPU time median / p99 / max |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for arm, rows in arms.items():
        for solver, row in rows.items():
            s, r = row["step"], row["replan_steps"]
            replan = f"{r['median']:.2f} / {r['max']:.2f}" if r["n"] else "-"
            c = row["step_cpu"]
            lines.append(
                f"| {arm} | {solver} | {s['n']} | {s['median']:.3f} | {s['p99']:.3f} | {s['max']:.3f} | "
                f"{row['replans']} | {replan} | {c['median']:.3f} / {c['p99']:.3f} / {c['max']:.3f} |"
            )
    return [*lines, ""]


def _render_beside(beside: dict | None) -> list[str]:
    """bench.md lines: the planner beside the loop."""
    if not beside:
        return []
    latency = beside["latency_periods"]
    rows = [row for case in beside["cases"].values() for row in case.values()]
    paced = "paced at the control period" if all(row.get("paced") for row in rows) else "not paced (quick)"
    lines = [
        f'The planner beside the loop (`pi_idmpc.plan_latency = {latency}`, `plan_worker = "process"`), '
        f"{beside['runs']} runs of {beside['duration_s']:.0f} s per case, {paced}: the control step (compute + "
        "observe in the control process, waiting only for a late worker) in wall and CPU time, and the worker's own "
        f"time per plan against its budget of {latency} periods, ms:\n",
        "| case | solver | steps | median | p99 | max | CPU median / p99 / max | steps that waited | plans | "
        "plan median / p99 / max | plan CPU median / p99 / max | plans over budget |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for case, rows in beside["cases"].items():
        for solver, row in rows.items():
            s, c, p, pc = row["step"], row["step_cpu"], row["plan"], row["plan_cpu"]
            plans = "-" if p["n"] == 0 else f"{p['median']:.2f} / {p['p99']:.2f} / {p['max']:.2f}"
            plans_cpu = "-" if pc["n"] == 0 else f"{pc['median']:.2f} / {pc['p99']:.2f} / {pc['max']:.2f}"
            lines.append(
                f"| {case} | {solver} | {s['n']} | {s['median']:.3f} | {s['p99']:.3f} | {s['max']:.3f} | "
                f"{c['median']:.3f} / {c['p99']:.3f} / {c['max']:.3f} | {row['waited']} | {p['n']} | "
                f"{plans} | {plans_cpu} | {row['plans_over_budget']} |"
            )
    return [*lines, ""]


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
        "Targets: " + ", ".join(f"{key} <= {limit} ms" for key, limit in STEP_BARS_MS.items()) + " "
        "(with the structured solver: "
        + ", ".join(f"{key} {'met' if met else 'missed'}" for key, met in step["structured"]["meets"].items())
        + "). First step of the warm-up run: "
        f"{step['warmup_first_step_ms']:.1f} ms. DAQP / structured, whole step: "
        + ", ".join(f"{key} {value:.2f}x" for key, value in step["step_ratio_daqp_over_structured"].items())
        + ".\n",
        *_render_cpu(step),
        *_render_breakdown(step["structured"]["replan_breakdown"]),
        *_render_arms(step.get("arms", {})),
        *_render_beside(section.get("beside")),
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
    lines += render_rate_qp(section.get("rate"))
    return "\n".join(lines)
