"""Ablation of the inverse-dynamics MPC's design choices (the numbers behind idmpc.py's defaults).

Each variant is a controller plus dotted config overrides, run on the 10 s paper task:
"clean" (noise_variance 0, seed 0) and "noisy" (noise_variance 0.001, seeds 1, 2, 3; the mean
over the seeds is reported). Per run: E_p per joint (rad^2), its mean over joints, E_p after
2 s, the largest |tau| / limit, divergence, and the control step's median and 99th percentile
(s; GP and Kalman filter included), and separately the final design's step time with nothing
else running in this script (``timing``).

    python scripts/idmpc_design.py                      # everything -> docs/data/idmpc_ablation.json
    python scripts/idmpc_design.py --only base,deadbeat # a subset, printed only
    python scripts/idmpc_design.py --jobs 2

Groups: "paper" (|tau| <= 500 N m), "ur5limits" (the paper arm with the UR5's 150/28 N m
limits), "arms" (the arms "ur5" and "alpha5" with their own limits, defaults only).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import time
from pathlib import Path

import numpy as np

UR5_LIMITS = [150.0, 150.0, 150.0, 28.0, 28.0, 28.0]
RUNS = [("clean", 0.0, 0), ("noisy", 0.001, 1), ("noisy", 0.001, 2), ("noisy", 0.001, 3)]

# (name, controller, overrides[, patch]): the first row of each group is the final design. A
# patch is an alternative that the module does not keep, applied here (see PATCHES).
PREVIOUS = {"idmpc.r_scaling": "uniform", "idmpc.limits": "allocation", "idmpc.horizon": 10}
FINAL = "gp-idmpc (final: authority R_a, qp + 1 SQP step, N = 5)"
PAPER_VARIANTS = [
    (FINAL, "gp-idmpc", {}),
    ("idmpc, no GP (final)", "idmpc", {}),
    ("previous design (uniform R_a, allocation, N = 10)", "gp-idmpc", PREVIOUS),
    ("uniform R_a", "gp-idmpc", {"idmpc.r_scaling": "uniform"}),
    ("sqp_iterations 0 (frozen M, h rows)", "gp-idmpc", {"idmpc.sqp_iterations": 0}),
    ("sqp_iterations 2", "gp-idmpc", {"idmpc.sqp_iterations": 2}),
    ("horizon 10", "gp-idmpc", {"idmpc.horizon": 10}),
    ("limits = allocation", "gp-idmpc", {"idmpc.limits": "allocation"}),
    ("limits = clip", "gp-idmpc", {"idmpc.limits": "clip"}),
    ("r_acceleration 3e-6", "gp-idmpc", {"idmpc.r_acceleration": 3e-6}),
    ("r_acceleration 3e-5", "gp-idmpc", {"idmpc.r_acceleration": 3e-5}),
    ("r_floor 1e-7", "gp-idmpc", {"idmpc.r_floor": 1e-7}),
    ("q_velocity 0.1", "gp-idmpc", {"idmpc.q_velocity": 0.1}),
    ("q_position 1000", "gp-idmpc", {"idmpc.q_position": 1000.0}),
    ("M, h at the mid-step state", "gp-idmpc", {}, "midpoint"),
    ("w_hat = 0 while saturated", "gp-idmpc", {}, "no_gp_when_saturated"),
    ("no Kalman filter", "gp-idmpc", {"estimator.kind": "none"}),
    ("KF acceleration_variance 1e4", "gp-idmpc", {"estimator.acceleration_variance": 1e4}),
    ("smc", "smc", {}),
    ("mpc", "mpc", {}),
    ("gp-mpc", "gp-mpc", {}),
]

UR5_VARIANTS = [
    (FINAL, "gp-idmpc", {}),
    ("idmpc, no GP (final)", "idmpc", {}),
    ("previous design (uniform R_a, allocation, N = 10)", "gp-idmpc", PREVIOUS),
    ("uniform R_a", "gp-idmpc", {"idmpc.r_scaling": "uniform"}),
    ("sqp_iterations 0 (frozen M, h rows)", "gp-idmpc", {"idmpc.sqp_iterations": 0}),
    ("sqp_iterations 2", "gp-idmpc", {"idmpc.sqp_iterations": 2}),
    ("horizon 10", "gp-idmpc", {"idmpc.horizon": 10}),
    ("limits = allocation", "gp-idmpc", {"idmpc.limits": "allocation"}),
    ("w_hat = 0 while saturated", "gp-idmpc", {}, "no_gp_when_saturated"),
    ("smc", "smc", {}),
    ("mpc", "mpc", {}),
    ("gp-mpc", "gp-mpc", {}),
]

ARM_VARIANTS = [
    (FINAL, "gp-idmpc", {}),
    ("idmpc (final)", "idmpc", {}),
    ("previous design", "gp-idmpc", PREVIOUS),
    ("smc", "smc", {}),
    ("mpc", "mpc", {}),
    ("gp-mpc", "gp-mpc", {}),
]


def _patch(name):
    """Apply alternative ``name`` to InverseDynamicsMPC.torque_map; returns the undo function."""
    from hydroarm.control.idmpc import InverseDynamicsMPC

    original = InverseDynamicsMPC.torque_map

    def midpoint(self, q, v, acceleration, w_hat):
        half = 0.5 * self.control_period
        return original(
            self, q + half * v + 0.5 * half * half * acceleration, v + half * acceleration, acceleration, w_hat
        )

    def no_gp_when_saturated(self, q, v, acceleration, w_hat):
        out = original(self, q, v, acceleration, w_hat)
        return original(self, q, v, acceleration, np.zeros_like(w_hat)) if out[2].any() else out

    InverseDynamicsMPC.torque_map = {"midpoint": midpoint, "no_gp_when_saturated": no_gp_when_saturated}[name]

    def undo():
        InverseDynamicsMPC.torque_map = original

    return undo


def _cpu_clock():
    """Record the thread CPU time of every FilteredController.compute; returns (list, undo)."""
    from hydroarm.control.estimator import FilteredController

    original = FilteredController.compute
    record = []

    def compute(self, t, y, reference):
        start = time.thread_time()
        out = original(self, t, y, reference)
        record.append(time.thread_time() - start)
        return out

    FilteredController.compute = compute

    def undo():
        FilteredController.compute = original

    return record, undo


def _limit_overrides(controller: str, limits) -> dict:
    return {} if limits is None else {"torque_limit": limits}  # one limit, every controller


def run_one(job):
    """One run: ``job = (group, name, controller, overrides, arm, limits, label, noise, seed)``."""
    import hydroarm
    from hydroarm.sim.experiment import ExperimentConfig, run_experiment, with_overrides

    group, name, controller, overrides, patch, arm, limits, label, noise, seed = job
    settings = {"arm": arm, "plant.noise_variance": noise, **_limit_overrides(controller, limits), **overrides}
    cfg = with_overrides(ExperimentConfig(), settings)
    undo_patch = _patch(patch) if patch else (lambda: None)
    cpu, undo_clock = _cpu_clock()
    start = time.perf_counter()
    try:
        traj = run_experiment(cfg, controller, seed=seed)
    finally:
        undo_patch()
        undo_clock()
    wall = time.perf_counter() - start
    metrics = hydroarm.tracking_metrics(traj)
    total = np.asarray(traj.timings.get("total", [np.nan]), dtype=float)
    bound = np.asarray(limits if limits is not None else hydroarm.load_arm(arm).torque_limit, dtype=float)
    return {
        "group": group,
        "name": name,
        "controller": controller,
        "overrides": overrides,
        "arm": arm,
        "case": label,
        "seed": seed,
        "Ep": metrics["Ep"],
        "Ep_steady": metrics["Ep_steady"],
        "diverged": bool(metrics["diverged"]),
        "max_torque_ratio": float(np.max(np.abs(traj.u) / bound)),
        "step_median_ms": float(np.nanmedian(total) * 1e3),
        "step_p99_ms": float(np.nanpercentile(total, 99) * 1e3),
        "step_max_ms": float(np.nanmax(total) * 1e3),
        "cpu_p99_ms": float(np.percentile(cpu, 99) * 1e3) if cpu else None,
        "wall_s": wall,
    }


def jobs_for(groups, only):
    jobs = []
    spec = {
        "paper": [("paper", None, PAPER_VARIANTS)],
        "ur5limits": [("paper", UR5_LIMITS, UR5_VARIANTS)],
        "arms": [("ur5", None, ARM_VARIANTS), ("alpha5", None, ARM_VARIANTS)],
    }
    for group in groups:
        for arm, limits, variants in spec[group]:
            for name, controller, overrides, *patch in variants:
                if only and name not in only:
                    continue
                for label, noise, seed in RUNS:
                    job = (f"{group}:{arm}", name, controller, overrides, patch[0] if patch else None, arm, limits)
                    jobs.append((*job, label, noise, seed))
    return jobs


def summarise(results):
    rows = {}
    for r in results:
        rows.setdefault((r["group"], r["name"]), []).append(r)
    table = []
    for (group, name), runs in rows.items():
        clean = [r for r in runs if r["case"] == "clean"]
        noisy = [r for r in runs if r["case"] == "noisy"]
        entry = {"group": group, "name": name, "controller": runs[0]["controller"], "overrides": runs[0]["overrides"]}
        for label, subset in (("clean", clean), ("noisy", noisy)):
            ep = np.mean([r["Ep"] for r in subset], axis=0)
            steady = np.mean([r["Ep_steady"] for r in subset], axis=0)
            entry[label] = {
                "Ep": ep.tolist(),
                "Ep_mean": float(np.mean(ep)),
                "Ep_steady": steady.tolist(),
                "diverged": any(r["diverged"] for r in subset),
                "max_torque_ratio": max(r["max_torque_ratio"] for r in subset),
                "step_median_ms": float(np.median([r["step_median_ms"] for r in subset])),
                "step_p99_ms": float(np.median([r["step_p99_ms"] for r in subset])),
                "cpu_p99_ms": float(np.median([r["cpu_p99_ms"] for r in subset])) if subset[0]["cpu_p99_ms"] else None,
            }
        table.append(entry)
    return table


def markdown(table):
    lines = []
    group = None
    for e in table:
        if e["group"] != group:
            group = e["group"]
            lines += ["", f"### {group}", ""]
            lines.append(
                "| variant | case | E_p per joint (rad^2) | mean | div | max|tau|/lim | med ms | p99 ms | cpu p99 ms |"
            )
            lines.append("|---|---|---|---|---|---|---|---|---|")
        for label in ("clean", "noisy"):
            s = e[label]
            joints = ", ".join(f"{x:.4f}" for x in s["Ep"])
            cpu = f"{s['cpu_p99_ms']:.3f}" if s["cpu_p99_ms"] is not None else "-"
            lines.append(
                f"| {e['name']} | {label} | {joints} | **{s['Ep_mean']:.4f}** | {'yes' if s['diverged'] else 'no'} "
                f"| {s['max_torque_ratio']:.3f} | {s['step_median_ms']:.3f} | {s['step_p99_ms']:.3f} | {cpu} |"
            )
    return "\n".join(lines)


def timing(repeats: int = 2):
    """The final design's step time on the paper task (clean + noisy seeds, 500 N m and UR5
    limits), run one after another in this process (the pool's two workers share the cores)."""
    rows = []
    for limits, label in ((None, "paper"), (UR5_LIMITS, "ur5limits")):
        for case, noise, seed in RUNS:
            for repeat in range(repeats):
                job = ("timing", FINAL, "gp-idmpc", {}, None, "paper", limits, case, noise, seed)
                r = run_one(job)
                r.update(limits=label, repeat=repeat)
                rows.append(r)
    return rows


def timing_markdown(rows):
    lines = ["", "### timing (one process, gp-idmpc + Kalman filter, ms per control step)", ""]
    lines += ["| limits | repeat | median | p99 | cpu p99 | max |", "|---|---|---|---|---|---|"]
    for label in ("paper", "ur5limits"):
        for repeat in sorted({r["repeat"] for r in rows}):
            sub = [r for r in rows if r["limits"] == label and r["repeat"] == repeat]
            lines.append(
                f"| {label} | {repeat} | {np.median([r['step_median_ms'] for r in sub]):.3f} "
                f"| {np.median([r['step_p99_ms'] for r in sub]):.3f} | {np.median([r['cpu_p99_ms'] for r in sub]):.3f} "
                f"| {max(r['step_max_ms'] for r in sub):.3f} |"
            )
    return "\n".join(lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--groups", default="paper,ur5limits,arms")
    parser.add_argument("--only", default="", help="comma-separated variant names (printed, not saved)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", default="docs/data/idmpc_ablation.json")
    args = parser.parse_args()
    only = [s for s in args.only.split(",") if s]
    jobs = jobs_for(args.groups.split(","), only)
    with multiprocessing.get_context("spawn").Pool(args.jobs) as pool:
        results = pool.map(run_one, jobs, chunksize=1)
    table = summarise(results)
    print(markdown(table))
    timed = timing() if not only else []
    if timed:
        print(timing_markdown(timed))
    if not only:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps({"table": table, "timing": timed, "runs": results}, indent=1))
        print(f"\nwritten {args.out}")


if __name__ == "__main__":
    main()
