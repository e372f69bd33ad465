"""The profile section: where a closed-loop step of the GP-MPC spends its time (cProfile)."""

from __future__ import annotations

import cProfile
import pstats
from pathlib import Path

from hydroarm.sim.experiment import with_overrides
from hydroarm_bench.loop import paper_experiment


def profile_closed_loop(duration: float = 3.0, top: int = 15) -> dict:
    """cProfile of the GP-MPC closed loop (controller + true plant): the functions with the
    largest self time, per control step. Profiling slows Python calls down, so the shares
    (not the absolute times) are what to read."""
    experiment = paper_experiment("GP-MPC", 0.2)
    experiment.run(0)  # warm-up (the same controller and plant: the run resets them)
    experiment.config = with_overrides(experiment.config, {"duration": float(duration)})
    profiler = cProfile.Profile()
    profiler.enable()
    experiment.run(0)
    profiler.disable()
    stats = pstats.Stats(profiler)
    steps = int(round(duration / experiment.control_period))
    total = sum(row[2] for row in stats.stats.values())
    rows = []
    for (filename, line, function), (_, calls, self_time, cumulative, _) in stats.stats.items():
        rows.append(
            {
                "function": f"{Path(filename).name}:{line}({function})",
                "calls_per_step": calls / steps,
                "self_us_per_step": self_time / steps * 1e6,
                "self_share": self_time / total if total > 0 else None,
                "cumulative_us_per_step": cumulative / steps * 1e6,
            }
        )
    rows.sort(key=lambda row: row["self_us_per_step"], reverse=True)
    return {
        "what": f"cProfile, GP-MPC on the true plant, {steps} steps; self time per control step",
        "profiled_us_per_step": total / steps * 1e6,
        "top": rows[:top],
    }
