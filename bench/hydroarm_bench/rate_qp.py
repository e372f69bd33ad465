"""Section ``planner``, part ``rate``: the rate-limited horizon QP, structured solver against DAQP.

With the drives' rate limit (``actuator.rate_limit`` = :data:`RATE` N m/s) every ID-MPC solves its
horizon QP with the rate rows (:class:`~hydroarm.control.idmpc_limits.HorizonQP`, 50 steps on the
paper arm: 300 moves, 600 rows). Here IDMPC, GP-IDMPC and PI-IDMPC run the paper scenario with
that limit once with each solver of those solves (``idmpc_limits.RATE_SOLVER``), in the same
process, after a warm-up run: the whole control step (compute + observe) in this thread's CPU time,
median / p99 / max, its ratio DAQP over structured, and each run's mean E_p (the two must agree to
rounding: the same QPs solved to the same working sets). Quick (CI): IDMPC alone, 1 s.
"""

from __future__ import annotations

import numpy as np

from hydroarm_bench.loop import TimedController, paper_experiment
from hydroarm_bench.stats import stats_ms

RATE = 1000.0
"""The drives' rate limit (N m/s) of the runs: the campaign's world."""
RATE_SOLVERS = ("daqp", "structured")
CONTROLLERS = ("IDMPC", "GP-IDMPC", "PI-IDMPC")


def _rate_qps(controller) -> list:
    """The HorizonQPs that solve with rate rows inside ``controller`` (wrappers unwrapped)."""
    while hasattr(controller, "controller") or hasattr(controller, "inner"):
        controller = getattr(controller, "controller", None) or controller.inner
    inner = getattr(controller, "mpc", controller)
    found = [getattr(inner, "rate_qp", None), getattr(controller, "planner", None)]
    return [qp for qp in found if qp is not None]


def _run(name: str, solver: str, duration: float) -> dict:
    """One run of ``name`` with ``solver`` for the rate-limited solves: step statistics, E_p, counts."""
    from hydroarm.control import idmpc_limits
    from hydroarm.sim.runner import tracking_metrics

    default = idmpc_limits.RATE_SOLVER
    idmpc_limits.RATE_SOLVER = solver
    try:
        experiment = paper_experiment(name, duration, {"actuator.rate_limit": RATE})
        timed = TimedController(experiment.controller)
        experiment.controller = timed
        traj = experiment.run(0)
    finally:
        idmpc_limits.RATE_SOLVER = default
    qps = _rate_qps(timed.inner)
    return {
        "step": stats_ms(timed.cpu_s),
        "Ep_mean": float(np.mean(tracking_metrics(traj)["Ep"])),
        "diverged": bool(traj.diverged),
        "rate_solves": int(sum(qp.rate_solves for qp in qps)),
        "daqp_fallbacks": int(sum(qp.fallbacks for qp in qps)),
    }


def bench_rate_qp(quick: bool) -> dict:
    """The part (module docstring): per controller and solver a run's row, and the ratios."""
    duration = 1.0 if quick else 10.0
    out: dict = {"rate_limit_N_m_per_s": RATE, "duration_s": duration, "clock": "thread CPU", "controllers": {}}
    for name in CONTROLLERS[:1] if quick else CONTROLLERS:
        _run(name, "structured", 0.2)  # warm-up: the compiled kernels' caches
        rows = {solver: _run(name, solver, duration) for solver in RATE_SOLVERS}
        dense, fast = rows["daqp"]["step"], rows["structured"]["step"]
        rows["step_ratio_daqp_over_structured"] = {key: dense[key] / fast[key] for key in ("median", "p99", "max")}
        rows["Ep_relative_difference"] = abs(rows["structured"]["Ep_mean"] / rows["daqp"]["Ep_mean"] - 1.0)
        out["controllers"][name] = rows
    return out


def render_rate_qp(section: dict | None) -> list[str]:
    """bench.md lines of the part (nothing when it did not run)."""
    if not section:
        return []
    lines = [
        f"The rate-limited horizon QP (`actuator.rate_limit = {section['rate_limit_N_m_per_s']:.0f}`, 300 moves, "
        f"600 rows): structured solver against DAQP, {section['duration_s']:.0f} s runs, the whole step in "
        "this thread's CPU time, ms:\n",
        "| controller | rate solver | median | p99 | max | rate solves | DAQP fallbacks | mean E_p |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, rows in section["controllers"].items():
        for solver in RATE_SOLVERS:
            row, s = rows[solver], rows[solver]["step"]
            lines.append(
                f"| {name} | {solver} | {s['median']:.2f} | {s['p99']:.2f} | {s['max']:.2f} | {row['rate_solves']} | "
                f"{row['daqp_fallbacks']} | {row['Ep_mean']:.6g} |"
            )
    lines.append("")
    for name, rows in section["controllers"].items():
        ratio = rows["step_ratio_daqp_over_structured"]
        lines.append(
            f"- {name}: DAQP / structured, median {ratio['median']:.2f}x, p99 {ratio['p99']:.2f}x, "
            f"max {ratio['max']:.2f}x; E_p differs by {rows['Ep_relative_difference']:.1e} (relative)."
        )
    return [*lines, ""]
