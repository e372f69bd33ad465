"""bench.json's step times of two checkouts side by side: each checkout's own bench sections in its
own process, alternating between the checkouts round by round so that a load change on a shared
machine hits both alike. Writes each row's statistics per checkout and round, and the ratio
new / old of the medians over the rounds.

The rows: ``control`` (section 1 of bench.json, ``bench_control_steps``: every controller's 10 s
paper run, its whole step), ``plant`` (the paper arm's plant step, the reference path and its
NumPy twin: ``bench_plant``), ``uvms`` (the vehicle + arm plant step, compiled and reference, and
the real-time factor: ``bench_uvms``), ``env`` (one arm env's steps per second, alpha5:
``bench_envs``, quick) and ``cpu`` (per controller of section 1, 10 s paper run, seed 0: the
control step, compute + observe, and the whole loop's step, plant and runner included, in this
thread's CPU time, which a loaded machine's preemptions do not inflate as they do wall times).

    python scripts/bench_side_by_side.py --old /path/to/old/checkout --new . --rounds 2 \\
        --out bench/results/control_step_side_by_side.json
    python scripts/bench_side_by_side.py --old OLD --new . --sections control plant uvms env \\
        --out bench/results/step_side_by_side.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
from datetime import date
from pathlib import Path

import numpy as np

CHILD = """
import json, sys, time
import numpy as np
from hydroarm_bench.control_steps import PHASES, bench_control_steps
from hydroarm_bench.loop import paper_experiment
sections, rows = sys.argv[1:], {}


class CPUTimed:
    def __init__(self, inner):
        self.inner, self.name, self.control_period = inner, inner.name, inner.control_period
        self.cpu_ns, self.last = [], 0
    def reset(self):
        self.inner.reset()
    def compute(self, t, y, reference):
        start = time.thread_time_ns()
        out = self.inner.compute(t, y, reference)
        self.last = time.thread_time_ns() - start
        return out
    def observe(self, t, y, u, y_next):
        start = time.thread_time_ns()
        self.inner.observe(t, y, u, y_next)
        self.cpu_ns.append(self.last + time.thread_time_ns() - start)


def stats(ns):
    ms = np.asarray(ns, dtype=float) * 1e-6
    return {"median": float(np.median(ms)), "p99": float(np.percentile(ms, 99)), "max": float(ms.max())}


if "cpu" in sections:
    for name in PHASES:
        paper_experiment(name, 0.3).run(0)  # warm-up: JIT caches
        experiment = paper_experiment(name, 10.0)
        timed = CPUTimed(experiment.controller)
        experiment.controller = timed
        start = time.thread_time_ns()
        traj = experiment.run(0)
        whole = time.thread_time_ns() - start
        rows[f"{name}: control step, thread CPU"] = stats(timed.cpu_ns)
        steps = len(traj.t) - 1
        rows[f"{name}: whole loop step, thread CPU"] = {"median": whole * 1e-6 / steps, "steps": steps}
if "control" in sections or "plant" in sections:
    breakdown, _, recorded = bench_control_steps(quick=False)
if "control" in sections:
    rows.update({name: phases["total"] for name, phases in breakdown.items()})
if "plant" in sections:
    from hydroarm_bench.plant import bench_plant
    plant = bench_plant(recorded, False)
    rows["plant step (paper arm)"] = plant["plant_step_ms"]
    rows["plant step, NumPy twin (paper arm)"] = plant["plant_step_reference_ms"]
if "uvms" in sections:
    from hydroarm_bench.uvms import bench_uvms
    uvms = bench_uvms(False)
    for name in ("compiled", "reference"):
        row = uvms[name]
        rows[f"vehicle step, {name}"] = {"median": row["median_step_ms"], "p90": row["p90_step_ms"],
                                         "real_time_factor": row["real_time_factor"]}
if "env" in sections:
    from hydroarm_bench.envs import bench_envs
    env = bench_envs(True)
    rows["arm env step (alpha5)"] = {"median": 1e3 / env["single_steps_per_s"]}
json.dump(rows, sys.stdout)
"""
SECTIONS = ("control", "plant", "uvms", "env", "cpu")


def measure(checkout: Path, sections: list[str]) -> dict:
    """One round: each row's step statistics (ms) in a fresh process of ``checkout``."""
    env = {**os.environ, "PYTHONPATH": f"{checkout / 'src'}{os.pathsep}{checkout / 'bench'}"}
    env.update(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    command = [sys.executable, "-c", CHILD, *sections]
    out = subprocess.run(command, env=env, cwd=checkout, capture_output=True, text=True)
    if out.returncode != 0:
        sys.exit(f"{checkout}: the bench failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--old", type=Path, required=True, help="the checkout measured as 'old'")
    parser.add_argument("--new", type=Path, required=True, help="the checkout measured as 'new'")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--sections", nargs="+", choices=SECTIONS, default=["control"])
    args = parser.parse_args()
    rounds: dict[str, list[dict]] = {"old": [], "new": []}
    load = [os.getloadavg()]
    for k in range(args.rounds):
        for label in ("old", "new") if k % 2 == 0 else ("new", "old"):
            rounds[label].append(measure(getattr(args, label).resolve(), args.sections))
            print(f"round {k + 1}: {label} done", flush=True)
        load.append(os.getloadavg())
    ratios = {}
    for name in rounds["new"][0]:
        old = np.median([r[name]["median"] for r in rounds["old"]])
        new = np.median([r[name]["median"] for r in rounds["new"]])
        ratios[name] = {"old_median_ms": old, "new_median_ms": new, "new_over_old": new / old}
        print(f"{name}: median {old:.4f} -> {new:.4f} ms ({new / old:.2f}x)")
    commits = {
        label: subprocess.run(["git", "rev-parse", "HEAD"], cwd=getattr(args, label), capture_output=True,
                              text=True).stdout.strip()
        for label in ("old", "new")
    }  # fmt: skip
    payload = {
        "what": "step times per checkout and round (ms): "
        + ", ".join(args.sections)
        + " (control: the whole control step, observe + compute, 10 s paper run per controller)",
        "date": date.today().isoformat(),
        "machine": {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine()},
        "load_average_between_rounds": load,
        "commits": commits,
        "rounds": rounds,
        "median_over_rounds": ratios,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(payload, indent=1) + "\n")


if __name__ == "__main__":
    main()
