"""Reproduce Liu et al. 2023: Tables 1-2, Figures 4-15, an ablation, a report.

``reproduce(out_dir)`` runs SMC, MPC and GP-MPC on the true underwater plant
along the paper task, without noise (Table 1) and with measurement noise of
variance 0.001 over several seeds (Table 2), plus an ablation of the GP-MPC's
settings, and writes into ``out_dir``:

* ``runs/*.npz``: every trajectory (re-plot without re-running);
* ``metrics.json``: ``{"clean": {"SMC": {"Ep": [...]}, ...}, "noisy": {...}}`` (E_p per
  joint, rad^2, and more per controller), ``summary.json``: that plus the
  ablation, the settings, wall times and the machine;
* ``table1.md``/``.csv``, ``table2.md``/``.csv``, ``ablation.md``/``.csv``;
* ``fig04_...png`` to ``fig15_...png``: the paper's figures;
* ``gpmpc_arm.gif``: the arm moving under GP-MPC, the reference ghosted;
* ``report.md``: settings, tables, figures, and where and why we differ.

Beside the paper's rows (SMC, MPC, GP-MPC on the raw measurement, exactly as the paper's
study), the tables carry hydroarm's own best controller (:data:`BEST`, behind its Kalman
filter) and the paper's controllers behind the same filter (``SMC+KF``, ...), so that every
comparison with it uses the same estimator; ``ablation_idmpc.md`` varies its choices.

Each run is written atomically as soon as it finishes (``runs/<case>__<controller>__seed<n>.npz``,
through the studies' one executor and resume cache, :mod:`hydroarm.studies.executor`); a
later call with the same settings loads the finished runs (their settings digest,
controller and seed must match, and a file that cannot be read is recomputed) and runs
only the rest, so an interrupted reproduction loses nothing.
"""

from __future__ import annotations

import json
import os
import platform
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hydroarm.control.registry import PAPER_CONTROLLERS
from hydroarm.model.loading import load_arm
from hydroarm.studies import figures
from hydroarm.studies.animate import animate
from hydroarm.studies.executor import (
    Executor,
    ProgressHook,
    RunCache,
    StepHook,
    atomic_write,
    file_bytes,
    make_executor,
    run_tasks,
)
from hydroarm.studies.experiment import ExperimentConfig, run_experiment, with_overrides
from hydroarm.studies.figures import ANIMATION, FIGURES
from hydroarm.studies.report import render_report
from hydroarm.studies.reproduce_tables import BEST, EXTRA_ROWS, NOISE_VARIANCE, summarise, write_tables
from hydroarm.studies.runner import Trajectory


@dataclass(frozen=True)
class RunSpec:
    """One closed-loop run of the study: a case label, a controller, a seed, its settings."""

    case: str
    controller: str
    seed: int
    config: ExperimentConfig
    build: str | None = None
    """The registered controller to build, when ``controller`` is a row name (``"SMC+KF"``)."""

    @property
    def key(self) -> str:
        return f"{self.case}__{self.controller}__seed{self.seed}".replace("/", "-").replace("+", "p")

    @property
    def id(self) -> str:
        """The run id: the name of its file in ``runs/`` (the settings are checked on loading)."""
        return self.key

    @property
    def label(self) -> str:
        return self.key

    @property
    def arm_key(self) -> None:
        return None  # the run loads its arm itself (run_experiment)


def ablation_cases(base: ExperimentConfig) -> list[tuple[str, str, dict]]:
    """(group, label, overrides) of the GP-MPC ablation (issue 4's list)."""
    cases: list[tuple[str, str, dict]] = []
    for window in (5, 10, 20, 40):
        cases.append(("GP window N_train", str(window), {"gp.window": window}))
    for steps in (0, 1, 5, 20):
        cases.append(("hyperparameter steps per control step", str(steps), {"gp.hyper_steps": steps}))
    for features in ("state", "state+nominal", "state+torque"):
        cases.append(("GP input features", features, {"gpmpc.features": features}))
    for feedforward in ("acceleration", "torque"):
        cases.append(("where the estimate enters", feedforward, {"gpmpc.feedforward": feedforward}))
    for horizon in (5, 10, 20):
        cases.append(("MPC horizon N", str(horizon), {"mpc.horizon": horizon}))
    for r in (0.1, 1e-3):
        cases.append(("R", f"{r:g}", {"mpc.r": r}))
    for discretisation in ("euler", "taylor2"):
        cases.append(("MPC prediction model", discretisation, {"mpc.discretisation": discretisation}))
    for period in (0.005, 0.01, 0.02):
        cases.append(("control period T (s)", f"{period:g}", {"control_period": period}))
    uniform = {"water.current.model": "uniform", "water.current.mean": [0.3, 0.2, 0.0],
               "water.current.amplitude": [0.2, 0.0, 0.0], "water.current.frequency_hz": 0.2}  # fmt: skip
    cases.append(("current model", "paper", {"water.current.model": "paper"}))
    cases.append(("current model", "uniform", uniform))
    return cases


DRY = {"water.drag": False, "water.added_mass": False, "water.buoyancy": False, "water.current.model": "none"}
"""The plant without water: MPC on it bounds what any disturbance compensation can reach."""


def idmpc_ablation_cases() -> list[tuple[str, str, str, dict]]:
    """(group, label, controller, overrides) of the ablation of hydroarm's best controller."""
    cases: list[tuple[str, str, str, dict]] = [
        ("GP", "off (IDMPC)", "IDMPC", {}),
        ("GP", "on (GP-IDMPC)", "GP-IDMPC", {}),
    ]
    for kind in ("none", "kalman"):
        cases.append(("state estimator", kind, "GP-IDMPC", {"estimator.kind": kind}))
    for limits in ("allocation", "qp", "clip"):
        cases.append(("torque limits", limits, "GP-IDMPC", {"idmpc.limits": limits}))
    for r in (1e-4, 1e-5, 1e-6):
        cases.append(("R_a", f"{r:g}", "GP-IDMPC", {"idmpc.r_acceleration": r}))
    return cases


def plan_runs(base: ExperimentConfig, noisy_seeds: int, ablation: bool) -> list[RunSpec]:
    """Every run of the study: clean (seed 0), noisy (seeds 0..noisy_seeds-1), the paper's
    controllers and :data:`EXTRA_ROWS`, the dry-arm bound (MPC with the water removed:
    perfect disturbance knowledge), the ablations."""
    noisy = with_overrides(base, {"plant.noise_variance": NOISE_VARIANCE})
    runs = [RunSpec("clean", name, 0, base) for name in PAPER_CONTROLLERS]
    runs += [RunSpec("noisy", name, seed, noisy) for seed in range(noisy_seeds) for name in PAPER_CONTROLLERS]
    for row, (name, overrides) in EXTRA_ROWS.items():
        runs.append(RunSpec("clean", row, 0, with_overrides(base, overrides), name))
        noisy_row = with_overrides(noisy, overrides)
        runs += [RunSpec("noisy", row, seed, noisy_row, name) for seed in range(noisy_seeds)]
    runs.append(RunSpec("bound-clean", "MPC", 0, with_overrides(base, DRY)))
    runs += [RunSpec("bound-noisy", "MPC", seed, with_overrides(noisy, DRY)) for seed in range(noisy_seeds)]
    if ablation:
        for group, label, overrides in ablation_cases(base):
            config = with_overrides(base, overrides)
            for name in ("MPC", "GP-MPC"):
                runs.append(RunSpec(f"ablation/{group}={label}", name, 0, config))
        for group, label, name, overrides in idmpc_ablation_cases():
            config = with_overrides(base, overrides)
            row = f"{name}+KF" if config.estimator.kind != "none" else name
            runs.append(RunSpec(f"ablation-idmpc/{group}={label}", row, 0, config, name))
    return runs


def load_finished(path: Path, spec: RunSpec) -> Trajectory | None:
    """The saved run if it is readable and was made with these settings; else None."""
    if not path.exists():
        return None
    try:
        traj = Trajectory.load(path)
    except Exception:  # corrupt or partial file: recompute it
        return None
    meta = traj.meta
    if (
        meta.get("digest") != spec.config.digest()
        or meta.get("controller") != spec.controller
        or meta.get("seed") != spec.seed
    ):
        return None
    return traj


class TrajectoryFiles(RunCache):
    """The reproduction's resume cache: ``runs/<key>.npz``, one trajectory per run."""

    suffix = ".npz"

    def read(self, task: RunSpec) -> Trajectory | None:
        return load_finished(self.path(task), task)

    def write(self, task: RunSpec, outcome: bytes) -> Trajectory:
        atomic_write(self.path(task), outcome)
        return Trajectory.load(self.path(task))


def run_one(spec: RunSpec, arm: None, progress: StepHook | None) -> bytes:
    """Worker: run ``spec``; the trajectory as ``.npz`` bytes (the driver writes them)."""
    traj = run_experiment(spec.config, spec.build or spec.controller, spec.seed, progress=progress)
    traj.meta["case"] = spec.case
    return file_bytes(traj.save, "run.npz")


def execute(
    runs: list[RunSpec],
    run_dir: Path,
    workers: int = 2,
    on_progress: ProgressHook | None = None,
    on_step: ProgressHook | None = None,
    executor: Executor | None = None,
) -> dict[str, Trajectory]:
    """Run what is not finished yet (in ``workers`` processes, or on ``executor``) and return
    every trajectory by key; the first run that raised is raised once the others are done."""
    cache = TrajectoryFiles(run_dir)
    finished, todo = cache.lookup(runs)
    runner = executor if executor is not None else make_executor(max(1, workers))
    report = run_tasks(todo, run_one, cache, runner, reused=len(finished), on_progress=on_progress, on_step=on_step)
    if report.failed:
        raise report.failed[0][1]
    return {**finished, **report.results}


def write_figures(runs: list[RunSpec], results: dict[str, Trajectory], out: Path, torque_limit: np.ndarray) -> None:
    """The paper's Figures 4-15 from the clean run and the noisy seed-0 run."""
    pick = {(s.case, s.controller): results[s.key] for s in runs if s.seed == 0 and s.case in ("clean", "noisy")}
    titles = FIGURES
    for case in ("clean", "noisy"):
        gp = pick[(case, "GP-MPC")]
        names = list(titles)
        if case == "clean":
            dist, derr, pos, comp, vel, tor = names[0], names[1], names[4], names[5], names[6], names[7]
        else:
            dist, derr, pos, vel, tor, comp = names[2], names[3], names[8], names[9], names[10], names[11]
        figures.plot_disturbance(gp, out / dist, titles[dist])
        figures.plot_disturbance_error(gp, out / derr, titles[derr])
        figures.plot_tracking(gp, out / pos, titles[pos], "position")
        figures.plot_tracking(gp, out / vel, titles[vel], "velocity")
        figures.plot_torque(gp, out / tor, titles[tor], torque_limit)
        figures.plot_error_comparison(
            {name: pick[(case, name)] for name in (*PAPER_CONTROLLERS, BEST)}, out / comp, titles[comp]
        )


def reproduce(
    out: Path,
    quick: bool = False,
    noisy_seeds: int | None = None,
    ablation: bool | None = None,
    workers: int = 2,
    config: ExperimentConfig | None = None,
    on_progress: ProgressHook | None = None,
    on_step: ProgressHook | None = None,
) -> dict:
    """Run the whole study into ``out`` (see the module docstring); returns metrics.json's content.

    ``quick``: a 3 s task, 2 noisy seeds and no ablation (for CI); defaults:
    10 s, 5 noisy seeds, ablation on. ``on_progress(done, total, label)``: the runs
    (finished or reused); ``on_step(k, total, label)``: the control steps of a run.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    base = config if config is not None else ExperimentConfig()
    if quick:
        base = with_overrides(base, {"duration": 3.0})
    seeds = noisy_seeds if noisy_seeds is not None else (2 if quick else 5)
    do_ablation = ablation if ablation is not None else not quick
    runs = plan_runs(base, seeds, do_ablation)
    start = time.perf_counter()
    results = execute(runs, out / "runs", workers, on_progress, on_step)
    run_wall = time.perf_counter() - start
    metrics = summarise(runs, results)
    metrics["settings"] = {
        "experiment": base.model_dump(mode="json"),
        "noise_variance": NOISE_VARIANCE,
        "noisy_seeds": seeds,
        "quick": quick,
        "ablation": do_ablation,
        "workers": workers,
    }
    write_tables(metrics, out)
    write_figures(runs, results, out, load_arm(base.arm).torque_limit)
    clean_gp = next(results[s.key] for s in runs if s.case == "clean" and s.controller == "GP-MPC")
    animate(clean_gp, out / ANIMATION, duration=min(5.0, base.duration), fps=10)
    metrics["wall_time_s"] = {"runs": run_wall, "total": time.perf_counter() - start}
    metrics["machine"] = {"python": platform.python_version(), "cpus": os.cpu_count(), "platform": platform.platform()}
    (out / "metrics.json").write_text(json.dumps({case: metrics[case] for case in ("clean", "noisy")}, indent=1))
    (out / "summary.json").write_text(json.dumps(metrics, indent=1))
    write_report(metrics, out)
    return metrics


def write_report(metrics: dict, out: Path) -> None:
    """report.md: settings, tables, figures, differences from the paper and why."""
    (out / "report.md").write_text(render_report(metrics, out))
