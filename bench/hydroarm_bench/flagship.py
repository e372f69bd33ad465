"""Section ``flagship``: the step of the controller ``--controller flagship`` resolves to, in the
loops a user will run it in, over >= 10^4 steps, beside its GP-free twin IDMPC in the same run.

The step is everything the control process does per period: compute and observe of the whole
controller chain the runner builds (the state filter and the friction feed-forward where the loop
has them, the GP, the horizon QP where the torque limits bind), in wall time
(``time.perf_counter``) and in this thread's CPU time (``time.thread_time``: without the time other
processes held the core; on a shared machine the wall time's tail is mostly the latter). Cases
(:data:`CASES`): the paper task; the paper arm with the UR5's torque limits (the QP binds on
about a fifth of the steps); and the issue's real loop (a 16-bit encoder measuring position only,
one period of sensor delay, the published friction). Issue 32's bars
(:data:`~hydroarm_bench.stats.STEP_BARS_MS`):
median <= 0.3 ms, p99 <= 1 ms, max <= 5 ms. Each row runs :data:`RUNS` x 10 s (seeds 0, 1, ...)
after a 0.3 s warm-up run of its own (numba caches, first allocations), the flagship's and IDMPC's
runs alternating, unpaced: the step does
not wait on anything beside the loop, so pacing would change only the caches' warmth.
"""

from __future__ import annotations

import numpy as np

from hydroarm.control.registry import ALIASES
from hydroarm_bench.loop import TimedController, paper_experiment
from hydroarm_bench.stats import meets_bars, stats_ms

FLAGSHIP = ALIASES["flagship"]
PEER = "IDMPC"
DURATION_S = 10.0
RUNS = 11
"""10 s runs per row: 11 x 1000 steps >= 10^4."""

CASES: dict[str, dict] = {
    "paper": {},
    "paper, UR5 limits": {"torque_limit": [150.0, 150.0, 150.0, 28.0, 28.0, 28.0]},
    "paper, the issue's real loop": {
        "sensor.velocity": "differenced",
        "sensor.resolution": 9.5874e-05,
        "sensor.delay": 1,
        "friction.scale": 1.0,
    },
}


def _rows(names: tuple[str, ...], overrides: dict, runs: int, duration: float) -> dict:
    """Each controller of ``names`` in one case: its step's wall and CPU statistics (ms) over
    ``runs`` runs. The controllers' runs alternate (seed by seed), so that a change of the shared
    machine's speed during the case falls on all of them alike and their ratio holds (on
    2026-12-05, with one controller's runs after the other's, IDMPC's median step on the paper
    task was 0.18 ms in one row and 0.08-0.09 ms in rows minutes before and after it, with the
    same code, in CPU time as in wall time: the shared machine's speed changes)."""
    wall: dict[str, list] = {name: [] for name in names}
    cpu: dict[str, list] = {name: [] for name in names}
    for seed in range(-1, runs):  # -1: the warm-up runs
        for name in names:
            experiment = paper_experiment(name, 0.3 if seed < 0 else duration, overrides)
            timed = TimedController(experiment.controller)
            experiment.controller = timed
            experiment.run(max(seed, 0))
            if seed >= 0:
                steps = len(timed.observe_s)
                wall[name].append(np.asarray(timed.wall_s[:steps]))
                cpu[name].append(np.asarray(timed.cpu_s[:steps]))
    rows = {}
    for name in names:
        row = {"step": stats_ms(np.concatenate(wall[name])), "step_cpu": stats_ms(np.concatenate(cpu[name]))}
        row["meets"] = meets_bars(row["step"])
        row["meets_cpu"] = meets_bars(row["step_cpu"])
        rows[name] = row
    return rows


def bench_flagship(quick: bool) -> dict:
    """Per case of :data:`CASES`: the flagship's row and IDMPC's, and the ratio of their median
    steps (flagship over IDMPC). Quick mode (CI): one 1 s run of the paper task, shape only."""
    runs, duration = (1, 1.0) if quick else (RUNS, DURATION_S)
    cases = {"paper": CASES["paper"]} if quick else CASES
    out: dict = {"flagship": FLAGSHIP, "peer": PEER, "runs": runs, "duration_s": duration, "cases": {}}
    for case, overrides in cases.items():
        rows = _rows((FLAGSHIP, PEER), overrides, runs, duration)
        rows["median_ratio"] = rows[FLAGSHIP]["step"]["median"] / rows[PEER]["step"]["median"]
        out["cases"][case] = rows
    return out


def render_flagship(section: dict) -> str:
    """The section as Markdown: one line per case and controller, wall and CPU time."""
    lines = [
        "",
        f"## The flagship's step ({section['flagship']}), beside {section['peer']}",
        "",
        f"{section['runs']} runs of {section['duration_s']:.0f} s per row; compute + observe of the whole controller "
        "chain, ms, median / p99 / max (n steps); bars: median <= 0.3, p99 <= 1, max <= 5 ms.",
        "",
        "| case | controller | step (wall) | step (CPU) | n | meets (wall) | flagship / peer (median) |",
        "|---|---|---|---|---|---|---|",
    ]
    for case, rows in section["cases"].items():
        for name in (section["flagship"], section["peer"]):
            wall, cpu = rows[name]["step"], rows[name]["step_cpu"]
            ratio = f"{rows['median_ratio']:.2f}" if name == section["flagship"] else ""
            meets = "yes" if all(rows[name]["meets"].values()) else "no"
            lines.append(
                f"| {case} | {name} | {wall['median']:.3f} / {wall['p99']:.3f} / {wall['max']:.2f} | "
                f"{cpu['median']:.3f} / {cpu['p99']:.3f} / {cpu['max']:.2f} | {wall['n']} | {meets} | {ratio} |"
            )
    return "\n".join(lines) + "\n"
