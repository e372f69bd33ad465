"""Every controller on every arm, each baseline tuned for that arm by `hydroarm tune`.

For each case (the built-in arms, the paper arm with the UR5's per-joint torque limits, and the
7-joint arm of examples/urdf/iiwa14.urdf): the SMC and the MPC are tuned on the dry arm
(hydroarm.studies.tune, the procedure of `hydroarm tune`; GP-MPC uses the tuned MPC), and
IDMPC / GP-IDMPC run with their defaults (no per-arm tuning). Every controller then runs the
arm's task in the water, clean (seed 0) and noisy (variance 0.001, seeds 1-3), on its default
estimator, and the SMC also behind the Kalman filter. Writes docs/data/arms_comparison.json and
.md.

Usage: python scripts/arms_study.py [--duration 10] [--workers 2] [--out docs/data/arms_comparison]
    [--rows "GP-MPC|GP-IDMPC+KF"]   (only these rows run, on the tuned settings OUT.json records;
                                     its other rows are kept)
"""

from __future__ import annotations

import argparse
import json
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides
from hydroarm.sim.files import atomic_write
from hydroarm.sim.runner import tracking_metrics
from hydroarm.studies.executor import RunCache, make_executor, run_tasks
from hydroarm.studies.tune import tune

UR5_LIMITS = [150.0, 150.0, 150.0, 28.0, 28.0, 28.0]
CASES = {
    "paper": {"arm": "paper"},
    "paper, UR5 limits": {
        "arm": "paper",
        "torque_limit": UR5_LIMITS,
    },
    "ur5": {"arm": "ur5"},
    "alpha5": {"arm": "alpha5"},
    "iiwa14 (7 joints)": {"arm": "examples/urdf/iiwa14.urdf"},
}
ROWS = {  # row -> (controller, overrides)
    "SMC": ("SMC", {}),
    "SMC+KF": ("SMC", {"estimator.kind": "kalman"}),
    "MPC": ("MPC", {}),
    "GP-MPC": ("GP-MPC", {}),
    "IDMPC+KF": ("IDMPC", {}),
    "GP-IDMPC+KF": ("GP-IDMPC", {}),
}
SEEDS = {"clean": [0], "noisy": [1, 2, 3]}


@dataclass(frozen=True)
class Run:
    id: str
    label: str
    controller: str
    seed: int
    settings: dict
    arm_key: None = None


def run_one(task: Run, arm, progress) -> dict:
    config = ExperimentConfig.model_validate(task.settings)
    experiment = build_experiment(config, task.controller)
    controller = experiment.controller
    while not hasattr(controller, "torque_limit"):  # behind a Kalman filter, or GP-MPC's MPC
        controller = getattr(controller, "controller", None) or controller.mpc
    limit = controller.torque_limit
    traj = experiment.run(task.seed, progress)
    m = tracking_metrics(traj)
    return {
        "Ep": m["Ep"],
        "Ep_steady": m["Ep_steady"],
        "diverged": bool(traj.diverged),
        "max_torque_over_limit": float(np.nanmax(np.abs(traj.u) / limit)),
        "step_ms_median": float(np.nanmedian(traj.timings["total"]) * 1e3),
        "step_ms_p99": float(np.nanpercentile(traj.timings["total"], 99) * 1e3),
    }


class Cache(RunCache):
    def read(self, task):
        try:
            return json.loads(self.path(task).read_text())
        except (OSError, ValueError):
            return None

    def write(self, task, outcome):
        atomic_write(self.path(task), json.dumps(outcome))
        return outcome


def tune_baselines(case: str, base: ExperimentConfig, args) -> dict:
    """The SMC's and the MPC's settings tuned on this case's dry arm (`hydroarm tune`'s procedure)."""
    best = {}
    for controller in ("SMC", "MPC"):
        folder = args.cache / "tune" / case.replace(" ", "_").replace(",", "").replace("(", "").replace(")", "")
        result = tune(base, controller, folder / controller, workers=args.workers)
        best.update(result.best)
        print(case, controller, "tuned:", result.best, f"score {result.rows[0]['score']:.5g}", flush=True)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("docs/data/arms_comparison"))
    parser.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "hydroarm-arms-study")
    parser.add_argument(
        "--rows",
        default=None,
        help="only these rows, separated by |, on the tuned settings OUT.json records; its other rows are kept",
    )
    args = parser.parse_args()
    rows = list(ROWS) if args.rows is None else args.rows.split("|")
    unknown = [row for row in rows if row not in ROWS]
    if unknown:
        parser.error(f"--rows: unknown {unknown}; the rows are {list(ROWS)}")
    results: dict = {}
    tuned: dict = {}
    if args.rows is not None:
        recorded = json.loads(args.out.with_suffix(".json").read_text())
        if recorded["duration"] != args.duration:
            parser.error(f"--rows: OUT.json was run for {recorded['duration']} s, not --duration {args.duration}")
        results, tuned = recorded["results"], recorded["tuned"]
    for case, overrides in CASES.items():
        base = with_overrides(ExperimentConfig(), {**overrides, "duration": args.duration})
        best = tuned[case] if args.rows is not None else tune_baselines(case, base, args)
        tuned[case] = best
        tasks = []
        for row, (controller, extra) in ((row, ROWS[row]) for row in rows):
            for table, seeds in SEEDS.items():
                for seed in seeds:
                    settings = with_overrides(
                        base, {**best, **extra, "plant.noise_variance": 1e-3 if table == "noisy" else 0.0}
                    )
                    key = (
                        f"{case}|{row}|{table}|{seed}".replace(" ", "_")
                        .replace(",", "")
                        .replace("(", "")
                        .replace(")", "")
                    )
                    key = key.replace("|", "__").replace("/", "-").replace("+", "p")
                    tasks.append(
                        Run(
                            f"{key}-{settings.digest()}",
                            f"{case} {row} {table} {seed}",
                            controller,
                            seed,
                            settings.model_dump(mode="json"),
                        )
                    )
        cache = Cache(args.cache / "runs")
        finished, todo = cache.lookup(tasks)
        report = run_tasks(todo, run_one, cache, make_executor(args.workers), reused=len(finished))
        if report.failed:
            raise report.failed[0][1]
        outcomes = {**finished, **report.results}
        block = results.setdefault(case, {})
        for row in rows:
            for table in SEEDS:
                runs = [outcomes[t.id] for t in tasks if t.label.startswith(f"{case} {row} {table} ")]
                ep = np.mean([r["Ep"] for r in runs], axis=0)
                block.setdefault(row, {})[table] = {
                    "Ep": ep.tolist(),
                    "Ep_mean": float(ep.mean()),
                    "Ep_steady_mean": float(np.mean([r["Ep_steady"] for r in runs])),
                    "diverged": any(r["diverged"] for r in runs),
                    "step_ms_median": float(np.median([r["step_ms_median"] for r in runs])),
                    "step_ms_p99": float(np.max([r["step_ms_p99"] for r in runs])),
                    "max_torque_over_limit": float(np.max([r["max_torque_over_limit"] for r in runs])),
                }
        print(case, {row: round(block[row]["clean"]["Ep_mean"], 5) for row in rows}, flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(
        json.dumps({"duration": args.duration, "tuned": tuned, "results": results}, indent=1)
    )
    lines = [
        f"Mean E_p over joints (rad^2), {args.duration:g} s task of each arm; noisy = mean of seeds 1-3.",
        "Baselines tuned on the dry arm by `hydroarm tune` for each arm; IDMPC/GP-IDMPC on their defaults.",
        "The lowest of each row in bold.",
        "",
        "| case | table | " + " | ".join(ROWS) + " |",
        "|---|---|" + "---|" * len(ROWS),
    ]
    for case, block in results.items():
        for table in SEEDS:
            values = {row: block[row][table]["Ep_mean"] for row in ROWS}
            low = min(values.values())
            cells = [
                ("**{:.4g}**" if v == low else "{:.4g}").format(v)
                + (" (diverged)" if block[row][table]["diverged"] else "")
                for row, v in values.items()
            ]
            lines.append(f"| {case} | {table} | " + " | ".join(cells) + " |")
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
