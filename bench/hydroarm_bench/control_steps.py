"""Section 1 (per-phase control-step statistics) and section 4 (throughput) of bench.json.

Each controller runs the 10 s paper scenario on the true plant (after a short warm-up
run, so JIT compilation and first allocations are excluded). The controllers time their
own phases; :class:`~hydroarm_bench.loop.TimedController` adds ``observe``. The MPC's first
run also records the QPs it solved (for the peers of section 2).
"""

from __future__ import annotations

import numpy as np

from hydroarm_bench.loop import closed_loop
from hydroarm_bench.stats import stats_ms

PHASES = {
    "PI-IDMPC": None,  # its phases as it reports them (plus observe: the learning, compute, total)
    "GP-IDMPC": None,  # its phases as it reports them (plus observe, compute, total)
    "GP-MPC": ("observe", "gp", "linearise", "riccati", "qp_update", "qp_solve", "compute", "total"),
    "MPC": ("linearise", "riccati", "qp_update", "qp_solve", "compute", "total"),
    "SMC": ("compute", "total"),
}
"""The controllers timed and their phases (``timings`` keys of their control outputs)."""
DURATION_S = 10.0
QUICK_DURATION_S = 3.0
"""The runs' length in quick mode (CI: the report's shape): 300 steps, the 200 its tests ask and more;
GP-MPC's run stays the whole 10 s scenario, whose wall time is the report's ``paper_scenario_wall_s``."""


def bench_control_steps(quick: bool) -> tuple[dict, dict, dict]:
    """Per-phase step statistics, throughput, and material for the peers (recorded runs)."""
    runs = 1 if quick else 2
    breakdown, throughput, recorded = {}, {}, {}
    for name in PHASES:
        duration = QUICK_DURATION_S if quick and name != "GP-MPC" else DURATION_S
        warm, *_ = closed_loop(name, 0.3)  # warm-up: JIT caches, Riccati compile, first allocations
        keys = PHASES[name] or ("observe", *sorted(set(warm.timings) - {"total"}), "compute", "total")
        phases: dict[str, list[float]] = {key: [] for key in keys}
        walls = []
        for seed in range(runs):
            snapshots = []
            hook = None
            if name == "MPC" and seed == 0:
                hook = mpc_snapshot_hook(snapshots)
            traj, observe_s, wall, controller = closed_loop(name, duration, seed, hook)
            walls.append(wall)
            steps = len(observe_s)  # every step but the last is observed: those count
            compute = traj.timings["total"][:steps]
            observe = np.asarray(observe_s)
            for key in keys:
                if key == "compute":
                    values = compute
                elif key == "total":
                    values = compute + observe
                elif key == "observe":
                    values = observe
                else:
                    values = traj.timings[key][:steps]
                phases[key].extend(np.asarray(values, dtype=float).tolist())
            if seed == 0:
                recorded[name] = {"traj": traj, "controller": controller, "snapshots": snapshots}
        breakdown[name] = {key: stats_ms(values) for key, values in phases.items()}
        throughput[name] = {
            "simulated_s": duration,
            "wall_s": float(np.median(walls)),
            "wall_s_runs": walls,
            "simulated_s_per_wall_s": duration / float(np.median(walls)),
            "steps": int(round(duration / controller.control_period)),
        }
    return breakdown, throughput, recorded


def mpc_snapshot_hook(snapshots: list):
    """A compute hook that copies what the MPC's QP was built from, every step."""

    def hook(mpc, t, y, out):
        horizon = mpc.horizon
        snapshots.append(
            {
                "t": float(t),
                "A": mpc._a[:horizon].copy(),
                "B": mpc._b[:horizon].copy(),
                "c": mpc._x_next[:horizon] - mpc._x_ref[1:],
                "e0": np.asarray(y, dtype=float) - mpc._x_ref[0],
                "P": mpc._P.copy(),
                "u_ref": mpc._u_ref[:horizon].copy(),
                "tau": out.tau.copy(),
                "status": out.status,
            }
        )

    return hook
