"""Reproduce Liu et al. 2023: Tables 1-2, Figures 4-15, an ablation, a report.

``reproduce(out_dir)`` runs SMC, MPC and GP-MPC on the true underwater plant
along the paper task, without noise (Table 1) and with measurement noise of
variance 0.001 over several seeds (Table 2), plus an ablation of the GP-MPC's
settings, and writes into ``out_dir``:

* ``hydroarm-run.json``: the folder's manifest (:func:`claim_folder`);
* ``runs/*.npz``: every trajectory (re-plot without re-running);
* ``summary.json``: every number (the results file to read): ``{"clean": {"SMC": {"Ep":
  [...]}, ...}, "noisy": {...}}`` (E_p per joint, rad^2, and more per row), the ablations,
  the settings, the arm, wall times and the machine; ``metrics.json``: its ``clean`` and
  ``noisy`` only (Tables 1-2's numbers). Both strict JSON (``null`` for an undefined number);
* ``table1.md``/``.csv``, ``table2.md``/``.csv``, ``ablation.md``/``.csv``;
* ``fig04_...png`` to ``fig15_...png``: the paper's figures;
* ``gpmpc_arm.gif``: the arm moving under GP-MPC, the reference ghosted;
* ``report.md``: settings, tables, figures, and where and why we differ (on another arm than
  the paper's: the controllers compared on that arm alone; :mod:`hydroarm.studies.report`).

Beside the paper's rows (SMC, MPC, GP-MPC on the raw measurement, exactly as the paper's
study), the tables carry hydroarm's flagship (:data:`BEST`, behind its Kalman
filter) and the paper's controllers behind the same filter (``SMC+KF``, ...), so that every
comparison with it uses the same estimator; ``ablation_idmpc.md`` varies its choices.

Each run is written atomically as soon as it finishes (``runs/<case>__<controller>__seed<n>.npz``
as a :func:`~hydroarm.studies.outputs.slug`, e.g. ``clean__gp-mpc__seed0.npz``,
through the studies' one executor and resume cache, :mod:`hydroarm.studies.executor`); a
later call with the same settings loads the finished runs (their settings digest,
controller and seed must match, and a file that cannot be read is recomputed) and runs
only the rest, so an interrupted reproduction loses nothing.

The study is three modules: its rows and the paper's own numbers
(:mod:`hydroarm.studies.reproduce_rows`: ``ROWS``, ``PAPER_EP``, paper reading, section 7), the
numbers of summary.json and the tables (:mod:`hydroarm.studies.reproduce_numbers`: ``summarise``,
``write_tables``), and here the plan (:func:`plan_runs`), running and resuming (:func:`execute`),
the figures and :func:`reproduce` itself; report.md's prose is :mod:`hydroarm.studies.report`,
which reads only summary.json's numbers.
"""

from __future__ import annotations

import os
import platform
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hydroarm.config import ConfigError
from hydroarm.control.registry import PAPER_CONTROLLERS
from hydroarm.model.arm.description import Arm
from hydroarm.model.arm.loading import arm_description, load_arm
from hydroarm.sim.experiment import ExperimentConfig, run_experiment, start_for_arm, with_overrides
from hydroarm.sim.files import atomic_write, file_bytes
from hydroarm.sim.runner import Trajectory
from hydroarm.studies import figures
from hydroarm.studies.animate import animate
from hydroarm.studies.executor import Executor, ProgressHook, RunCache, StepHook, make_executor, run_tasks
from hydroarm.studies.figures import ANIMATION, FIGURES
from hydroarm.studies.outputs import claim_output, dumps, slug, strict
from hydroarm.studies.report import render_report
from hydroarm.studies.reproduce_numbers import summarise, write_tables
from hydroarm.studies.reproduce_rows import (
    ABLATION_REPLICAS,
    BEST,
    DEFAULT_REPLICAS,
    EXTRA_ROWS,
    MAX_REPLICAS,
    NOISE_VARIANCE,
    REPLICA_OFFSET,
    REPLICATED_ROWS,
)
from hydroarm.studies.sweep.plan import arm_digest

# The plan and the runs: every run of the study, resumed from runs/


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
        """``<case>__<controller>__seed<n>`` as a safe, readable file name (:func:`slug`):
        ``ablation-control-period-t-s-0.02__mpc__seed0``, ``clean__gp-idmpc-kf__seed0``."""
        return slug(f"{self.case}__{self.controller}__seed{self.seed}")

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
    """(group, label, controller, overrides) of the ablation of hydroarm's flagship."""
    cases: list[tuple[str, str, str, dict]] = [
        ("GP", "off (IDMPC)", "IDMPC", {}),
        ("GP", "on (GP-IDMPC)", "GP-IDMPC", {}),
    ]
    for features in ("state", "state+acceleration"):
        cases.append(("GP inputs", features, "GP-IDMPC", {"idmpc.gp_features": features}))
    for kind in ("none", "kalman"):  # on the noisy sensor: on the clean one the matched filter passes y through
        overrides = {"estimator.kind": kind, "plant.noise_variance": NOISE_VARIANCE}
        cases.append(("state estimator, noisy sensor (seed 0)", kind, "GP-IDMPC", overrides))
    mistuned = {"estimator.kind": "kalman", "estimator.measurement_variance": NOISE_VARIANCE}
    cases.append(("state estimator, clean sensor", f"kalman assuming noise {NOISE_VARIANCE:g}", "GP-IDMPC", mistuned))
    for limits in ("qp", "allocation"):  # ("clip" diverges on the paper task)
        cases.append(("torque limits", limits, "GP-IDMPC", {"idmpc.limits": limits}))
    for iterations in (0, 1, 2):
        cases.append(
            ("SQP steps on the torque rows", str(iterations), "GP-IDMPC", {"idmpc.sqp_iterations": iterations})
        )
    for scaling in ("authority", "uniform"):
        cases.append(("acceleration weights", scaling, "GP-IDMPC", {"idmpc.r_scaling": scaling}))
    for floor in (1e-9, 1e-6):
        cases.append(("weight floor r_floor", f"{floor:g}", "GP-IDMPC", {"idmpc.r_floor": floor}))
    for horizon in (5, 10):
        cases.append(("horizon N", str(horizon), "GP-IDMPC", {"idmpc.horizon": horizon}))
    return cases


def replica_config(config: ExperimentConfig, replica: int) -> ExperimentConfig:
    """``config`` started from the task's start plus a seeded draw of :data:`REPLICA_OFFSET` rad
    per joint (replica 0: unchanged)."""
    if replica == 0:
        return config
    return with_overrides(config, {"initial_state.position_spread": REPLICA_OFFSET, "initial_state.seed": replica})


def plan_runs(base: ExperimentConfig, noisy_seeds: int, ablation: bool, replicas: int = 1) -> list[RunSpec]:
    """Every run of the study: clean (seed 0), noisy (seeds 0..noisy_seeds-1), the paper's
    controllers and :data:`EXTRA_ROWS`, the dry-arm bound (MPC with the water removed:
    perfect disturbance knowledge), the ablations, and replicas 1..replicas-1 of the clean
    runs of :data:`REPLICATED_ROWS` (case ``replica<r>-clean``, :func:`replica_config`)."""
    noisy = with_overrides(base, {"plant.noise_variance": NOISE_VARIANCE})
    runs = [RunSpec("clean", name, 0, base) for name in PAPER_CONTROLLERS]
    runs += [RunSpec("noisy", name, seed, noisy) for seed in range(noisy_seeds) for name in PAPER_CONTROLLERS]
    for row, (name, overrides) in EXTRA_ROWS.items():
        runs.append(RunSpec("clean", row, 0, with_overrides(base, overrides), name))
        noisy_row = with_overrides(noisy, overrides)
        runs += [RunSpec("noisy", row, seed, noisy_row, name) for seed in range(noisy_seeds)]
    runs.append(RunSpec("bound-clean", "MPC", 0, with_overrides(base, DRY)))
    runs += [RunSpec("bound-noisy", "MPC", seed, with_overrides(noisy, DRY)) for seed in range(noisy_seeds)]
    clean_runs = {spec.controller: spec for spec in runs if spec.case == "clean"}
    for replica in range(1, replicas):
        for row in REPLICATED_ROWS:
            spec = clean_runs[row]
            runs.append(RunSpec(f"replica{replica}-clean", row, 0, replica_config(spec.config, replica), spec.build))
    if ablation:
        runs += ablation_runs(base, min(replicas, ABLATION_REPLICAS))
    keys = [spec.key for spec in runs]
    if len(set(keys)) != len(keys):  # two runs would share a file
        raise ValueError(f"two runs of the study have one file name: {sorted(k for k in keys if keys.count(k) > 1)}")
    return runs


def ablation_runs(base: ExperimentConfig, replicas: int = 1) -> list[RunSpec]:
    """The ablations' runs (clean, seed 0): MPC and GP-MPC per :func:`ablation_cases`, one row per
    :func:`idmpc_ablation_cases`; and replicas 1..replicas-1 of every GP run among them (cases
    ``ablation-replica<r>/...`` and ``ablation-idmpc-replica<r>/...``, :func:`replica_config`):
    a GP loop turns a last-bit difference into another run, so its cell is a mean and a spread
    like the main tables' GP rows."""
    runs: list[RunSpec] = []
    for group, label, overrides in ablation_cases(base):
        config = with_overrides(base, overrides)
        runs.append(RunSpec(f"ablation/{group}={label}", "MPC", 0, config))
        for replica in range(replicas):
            prefix = "ablation" if replica == 0 else f"ablation-replica{replica}"
            runs.append(RunSpec(f"{prefix}/{group}={label}", "GP-MPC", 0, replica_config(config, replica)))
    for group, label, name, overrides in idmpc_ablation_cases():
        config = with_overrides(base, overrides)
        row = f"{name}+KF" if config.estimator.kind != "none" else name
        for replica in range(replicas if name.startswith("GP-") else 1):
            prefix = "ablation-idmpc" if replica == 0 else f"ablation-idmpc-replica{replica}"
            runs.append(RunSpec(f"{prefix}/{group}={label}", row, 0, replica_config(config, replica), name))
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


# The study: figures, folder, summary, report


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


@dataclass(frozen=True)
class Study:
    """What one call of :func:`reproduce` runs: the base settings (``--quick`` applied), the
    noisy seeds, whether the ablation runs, and every run."""

    base: ExperimentConfig
    noisy_seeds: int
    ablation: bool
    quick: bool
    runs: list[RunSpec]
    replicas: int = 1
    """K, the runs of each clean row of :data:`REPLICATED_ROWS` (:data:`DEFAULT_REPLICAS`)."""

    def settings(self) -> dict:
        """The settings that determine the results (the output folder's manifest)."""
        return {
            "experiment": self.base.canonical(),
            "noisy_seeds": self.noisy_seeds,
            "ablation": self.ablation,
            "quick": self.quick,
            "replicas": self.replicas,
        }

    def description(self) -> str:
        what = "--quick" if self.quick else f"{self.base.duration:g} s"
        ablation = "ablation" if self.ablation else "no ablation"
        return (
            f"hydroarm reproduce --arm {self.base.arm} ({what}, {self.noisy_seeds} noisy seeds, {ablation}, "
            f"{self.replicas} replicas)"
        )


def plan_study(
    quick: bool = False,
    noisy_seeds: int | None = None,
    ablation: bool | None = None,
    config: ExperimentConfig | None = None,
    replicas: int | None = None,
) -> Study:
    """The study :func:`reproduce` runs for these arguments (see there)."""
    base = config if config is not None else ExperimentConfig()
    if quick:
        base = with_overrides(base, {"duration": 3.0})
    seeds = noisy_seeds if noisy_seeds is not None else (2 if quick else 5)
    do_ablation = ablation if ablation is not None else not quick
    count = replicas if replicas is not None else DEFAULT_REPLICAS["quick" if quick else "full"]
    if not (isinstance(count, int) and 1 <= count <= MAX_REPLICAS):
        raise ConfigError(f"replicas = {count!r}: must be an integer in [1, {MAX_REPLICAS}] (runs per replicated row)")
    return Study(base, seeds, do_ablation, quick, plan_runs(base, seeds, do_ablation, count), count)


def claim_folder(out: Path, study: Study, overwrite: bool = False, dry_run: bool = False) -> None:
    """Check ``out`` may take this study's results (:func:`~hydroarm.studies.outputs.claim_output`:
    the same study resumes, more seeds or the ablation extend it; a folder of other settings
    raises :class:`~hydroarm.studies.outputs.OutputConflict` unless ``overwrite``)."""
    runs = {spec.key: spec.config.digest() for spec in study.runs}
    claim_output(out, "reproduce", study.settings(), runs, study.description(), overwrite, dry_run)


def check_study(
    out: Path,
    config: ExperimentConfig,
    quick: bool = False,
    noisy_seeds: int | None = None,
    ablation: bool | None = None,
    replicas: int | None = None,
    overwrite: bool = False,
) -> None:
    """Everything :func:`reproduce` would refuse, before any run: the settings against the arm
    (:func:`~hydroarm.sim.experiment.check_settings_for_arm`), the study's plan and whether
    ``out`` may take it (:func:`claim_folder`, nothing written). Raises :class:`ConfigError`."""
    from hydroarm.sim.experiment import check_settings_for_arm

    check_settings_for_arm(config, load_arm(config.arm))
    claim_folder(out, plan_study(quick, noisy_seeds, ablation, config, replicas), overwrite, dry_run=True)


def is_paper_arm(arm: Arm) -> bool:
    """True if ``arm`` is the paper's arm (by content, not by name): only then are the
    paper's numbers printed beside ours."""
    return arm_digest(arm) == arm_digest(load_arm("paper"))


def arm_summary(arm: Arm, config: ExperimentConfig) -> dict:
    """What the report says about the arm: name, joints, torque limits (N m), its
    description, and the joint-space inertia M(q0) diagonal at the task's start (kg m^2)."""
    _, x0 = start_for_arm(arm, config)
    spec = getattr(arm, "spec", None)
    return {
        "name": config.arm,
        "joints": arm.n_joints,
        "torque_limit": arm.torque_limit.tolist(),
        "description": getattr(spec, "description", "") or arm_description(config.arm),
        "inertia_diagonal_at_start": np.diag(arm.mass_matrix(x0[: arm.n_joints])).tolist(),
    }


def reproduce(
    out: Path,
    quick: bool = False,
    noisy_seeds: int | None = None,
    ablation: bool | None = None,
    workers: int = 2,
    config: ExperimentConfig | None = None,
    on_progress: ProgressHook | None = None,
    on_step: ProgressHook | None = None,
    overwrite: bool = False,
    replicas: int | None = None,
) -> dict:
    """Run the whole study into ``out`` (see the module docstring); returns summary.json's content.

    ``quick``: a 3 s task, 2 noisy seeds and no ablation (for CI); defaults:
    10 s, 5 noisy seeds, ablation on. ``on_progress(done, total, label)``: the runs
    (finished or reused); ``on_step(k, total, label)``: the control steps of a run.
    A folder holding results of other settings is refused
    (:class:`~hydroarm.studies.outputs.OutputConflict`) unless ``overwrite`` (see
    :func:`claim_folder`). ``replicas``: K, the runs of each clean row of
    :data:`REPLICATED_ROWS` (default :data:`DEFAULT_REPLICAS`: 8, quick 4; 1 = none).
    """
    out = Path(out)
    study = plan_study(quick, noisy_seeds, ablation, config, replicas)
    claim_folder(out, study, overwrite)
    base, seeds, do_ablation, runs = study.base, study.noisy_seeds, study.ablation, study.runs
    arm = load_arm(base.arm)
    paper = is_paper_arm(arm)
    start = time.perf_counter()
    results = execute(runs, out / "runs", workers, on_progress, on_step)
    run_wall = time.perf_counter() - start
    metrics = summarise(runs, results, paper_arm=paper)
    metrics["settings"] = {
        "experiment": base.canonical(),
        "noise_variance": NOISE_VARIANCE,
        "noisy_seeds": seeds,
        "quick": quick,
        "ablation": do_ablation,
        "replicas": study.replicas,
        "replica_offset_rad": REPLICA_OFFSET,
        "replicated_rows": list(REPLICATED_ROWS),
        "workers": workers,
        "paper_arm": paper,
        "arm": arm_summary(arm, base),
    }
    write_tables(metrics, out)
    write_figures(runs, results, out, arm.torque_limit)
    clean_gp = next(results[s.key] for s in runs if s.case == "clean" and s.controller == "GP-MPC")
    animate(clean_gp, out / ANIMATION, duration=min(5.0, base.duration), fps=10)
    metrics["wall_time_s"] = {"runs": run_wall, "total": time.perf_counter() - start}
    metrics["machine"] = {"python": platform.python_version(), "cpus": os.cpu_count(), "platform": platform.platform()}
    metrics["files"] = RESULT_FILES
    atomic_write(out / "metrics.json", dumps(tables_numbers(metrics), indent=1))
    atomic_write(out / "summary.json", dumps(metrics, indent=1))
    write_report(metrics, out)
    return strict(metrics)


RESULT_FILES = {
    "summary.json": "everything: the numbers of every row (clean, noisy), the ablations, the settings, "
    "the arm, wall times and the machine. Read this one.",
    "metrics.json": "the numbers of Tables 1-2 only: summary.json's `clean` and `noisy` (kept for scripts "
    "that read it; nothing in it is missing from summary.json)",
}
"""Which results file holds what (written into summary.json and report.md)."""


def tables_numbers(metrics: dict) -> dict:
    """metrics.json: the ``clean`` and ``noisy`` blocks of summary.json (Tables 1-2's numbers)."""
    return {case: metrics[case] for case in ("clean", "noisy")}


def write_report(metrics: dict, out: Path) -> None:
    """report.md: settings, tables, figures, differences from the paper and why."""
    (out / "report.md").write_text(render_report(metrics, out))
