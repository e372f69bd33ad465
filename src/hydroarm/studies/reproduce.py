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

The module holds the one study from its rows to its files, in that order: the rows and the
paper's own numbers (:data:`ROWS`, :data:`PAPER_EP`, paper reading, section 7), the plan
(:func:`plan_runs`), running and resuming (:func:`execute`), the numbers of summary.json
(:func:`summarise`), the tables (:func:`write_tables`) and :func:`reproduce` itself; report.md's
prose is :mod:`hydroarm.studies.report`, which reads only summary.json's numbers.
"""

from __future__ import annotations

import csv
import math
import os
import platform
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hydroarm.config import ConfigError
from hydroarm.control.registry import PAPER_CONTROLLERS
from hydroarm.model.arm import Arm
from hydroarm.model.loading import arm_description, load_arm
from hydroarm.sim.experiment import ExperimentConfig, run_experiment, start_for_arm, with_overrides
from hydroarm.sim.files import atomic_write, file_bytes
from hydroarm.sim.runner import Trajectory, fault_counts, stop_reason, tracking_metrics
from hydroarm.studies import figures
from hydroarm.studies.animate import animate
from hydroarm.studies.executor import Executor, ProgressHook, RunCache, StepHook, make_executor, run_tasks
from hydroarm.studies.figures import ANIMATION, FIGURES
from hydroarm.studies.outputs import claim_output, dumps, slug, strict
from hydroarm.studies.report import render_report
from hydroarm.studies.sweep.plan import arm_digest

# The rows of Tables 1-2 and the paper's own numbers

NOISE_VARIANCE = 0.001
"""The measurement noise of Table 2: variance on each measured q and v (rad^2, (rad/s)^2)."""

PAPER_EP = {
    "clean": {
        "SMC": [1.5872, 2.9348, 2.3282, 9.1378, 1.9941, 2.8227],
        "MPC": [0.09138, 0.1068, 0.2648, 0.3525, 0.2296, 0.2039],
        "GP-MPC": [0.0504, 0.0986, 0.1963, 0.1552, 0.1351, 0.1452],
    },
    "noisy": {
        "SMC": [3.2783, 5.391, 2.3581, 5.2402, 4.7431, 5.1747],
        "MPC": [0.1996, 0.2092, 0.4074, 0.5832, 2.3808, 0.3379],
        "GP-MPC": [0.1226, 0.1333, 0.1591, 0.3152, 0.2011, 0.2017],
    },
}
PAPER_GAIN = {"clean": 34.05, "noisy": 52.27}
"""The paper's "average control accuracy" gain of GP-MPC over MPC: the mean of the per-joint gains (%)."""

BEST = "GP-IDMPC+KF"
"""hydroarm's flagship row (the alias ``flagship``): GP-IDMPC behind its (default) Kalman filter."""

EXTRA_ROWS: dict[str, tuple[str, dict]] = {
    BEST: ("GP-IDMPC", {"estimator.kind": "auto"}),
    "SMC+KF": ("SMC", {"estimator.kind": "kalman"}),
    "MPC+KF": ("MPC", {"estimator.kind": "kalman"}),
    "GP-MPC+KF": ("GP-MPC", {"estimator.kind": "kalman"}),
    "IDMPC+KF": ("IDMPC", {"estimator.kind": "auto"}),
    "IDMPC+TDE+KF": ("IDMPC", {"observer.kind": "tde"}),
    "IDMPC+TDE-gated+KF": ("IDMPC", {"observer.kind": "tde", "observer.gate": True}),
    "IDMPC+NDOB+KF": ("IDMPC", {"observer.kind": "ndob"}),
    "IDMPC+NDOB-gated+KF": ("IDMPC", {"observer.kind": "ndob", "observer.gate": True}),
    "PI-IDMPC+KF": ("PI-IDMPC", {"estimator.kind": "auto"}),
}
"""Rows beyond the paper's: row name -> (registered controller, settings). Each row's name is
what its controller reports (``Trajectory.meta["controller"]``). The IDMPC rows are the fair
baselines of a learned disturbance model: no estimate, and the classic observers (TDE, NDOB with
L = 0.1, each with and without the saturation gate, :mod:`hydroarm.control.observers`) in the
same inverse-dynamics MPC behind the same filter."""

ROWS: tuple[str, ...] = (*PAPER_CONTROLLERS, *EXTRA_ROWS)
"""Every row of Tables 1-2, in their order."""


PAPER_DURATION = 10.0
"""s: the paper's task (its Tables 1-2)."""

REPLICATED_ROWS: tuple[str, ...] = ("GP-MPC", "GP-MPC+KF", BEST)
"""The rows whose closed loop amplifies a last-bit difference into another run (the sliding-window
GP's accept / reject of each hyperparameter step): measured, the quick reproduction under
OpenBLAS's Haswell and Sandybridge kernels moved their clean E_p by up to 39 % while every other
row agreed to 2e-10 (docs/data/reproducibility.md). Their clean runs are repeated from
:data:`REPLICA_OFFSET`-perturbed starts and reported as a mean and a spread (:func:`replica_summary`)."""

REPLICA_OFFSET = 1e-12
"""rad: the half-width of the uniform draw added to each joint's start position of a replica
(``initial_state.position_spread``, drawn with ``initial_state.seed`` = the replica's number)."""

DEFAULT_REPLICAS = {"full": 8, "quick": 4}
"""K, the runs per replicated row (the unperturbed one included), by mode."""

MAX_REPLICAS = 64
"""The most runs per replicated row ``--replicas`` takes."""


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
        for group, label, overrides in ablation_cases(base):
            config = with_overrides(base, overrides)
            for name in ("MPC", "GP-MPC"):
                runs.append(RunSpec(f"ablation/{group}={label}", name, 0, config))
        for group, label, name, overrides in idmpc_ablation_cases():
            config = with_overrides(base, overrides)
            row = f"{name}+KF" if config.estimator.kind != "none" else name
            runs.append(RunSpec(f"ablation-idmpc/{group}={label}", row, 0, config, name))
    keys = [spec.key for spec in runs]
    if len(set(keys)) != len(keys):  # two runs would share a file
        raise ValueError(f"two runs of the study have one file name: {sorted(k for k in keys if keys.count(k) > 1)}")
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


# The numbers: summary.json from the runs


def gain_percent(baseline: list[float], improved: list[float]) -> list[float]:
    """Per-joint improvement (%) of ``improved`` over ``baseline`` E_p (paper's definition)."""
    return [100.0 * (b - i) / b if b > 0 else 0.0 for b, i in zip(baseline, improved)]


def fault_totals(trajs: list[Trajectory]) -> dict[str, int]:
    """The runs' fault events (``meta["faults"]``) summed, only those that occurred; a run
    that stopped early adds ``stopped:<why>``."""
    totals: dict[str, int] = {}
    for traj in trajs:
        for name, count in fault_counts(traj).items():
            if count:
                totals[name] = totals.get(name, 0) + count
        stopped = stop_reason(traj)
        if stopped:
            key = f"stopped:{stopped}"
            totals[key] = totals.get(key, 0) + 1
    return totals


def _spread(values: np.ndarray) -> np.ndarray:
    """The std over the first axis (ddof 1: the spread of one run); zeros for one run."""
    return values.std(axis=0, ddof=1) if values.shape[0] > 1 else np.zeros(values.shape[1:])


def replica_summary(trajs: list[Trajectory]) -> dict:
    """The replicas' E_p and E_p after 2 s (K, n): per joint the mean, the spread (std, ddof 1),
    min and max; the same of the mean over joints."""
    metrics = [tracking_metrics(t) for t in trajs]
    ep = np.array([m["Ep"] for m in metrics], dtype=float)
    steady = np.array([m["Ep_steady"] for m in metrics], dtype=float)
    return {
        "count": len(trajs),
        "offset_rad": REPLICA_OFFSET,
        "Ep_mean": ep.mean(axis=0).tolist(),
        "Ep_spread": _spread(ep).tolist(),
        "Ep_min": ep.min(axis=0).tolist(),
        "Ep_max": ep.max(axis=0).tolist(),
        "Ep_mean_of_joints": float(ep.mean()),
        "Ep_mean_of_joints_spread": float(_spread(ep.mean(axis=1, keepdims=True))[0]),
        "Ep_steady_mean": steady.mean(axis=0).tolist(),
        "Ep_steady_spread": _spread(steady).tolist(),
        "Ep_per_replica": ep.tolist(),
    }


def summarise(runs: list, results: dict[str, Trajectory], paper_arm: bool = True) -> dict:
    """metrics.json: per case and controller, E_p per joint (mean over seeds) and more.
    ``paper_arm``: the runs are on the paper's arm (then the paper's gain is recorded beside ours).
    A row of :data:`REPLICATED_ROWS` with replicas (clean case) also gets ``replicas``
    (:func:`replica_summary`; its ``Ep`` stays the unperturbed run's); in the noisy case every such
    row's ``Ep_spread`` is the standard error of its mean over the seeds (std / sqrt(seeds))."""
    metrics: dict = {}
    for case in ("clean", "noisy"):
        metrics[case] = {}
        for name in ROWS:
            trajs = [results[s.key] for s in runs if s.case == case and s.controller == name]
            per_seed = [tracking_metrics(t) for t in trajs]
            ep = np.array([m["Ep"] for m in per_seed])
            steady = np.array([m["Ep_steady"] for m in per_seed])
            after = [t.t > 1.0 for t in trajs]
            entry = {
                "Ep": ep.mean(axis=0).tolist(),
                "Ep_std": ep.std(axis=0).tolist(),
                "Ep_mean": float(ep.mean()),
                "Ep_steady": steady.mean(axis=0).tolist(),
                "Ep_per_seed": ep.tolist(),
                "rms": np.mean([m["rms"] for m in per_seed], axis=0).tolist(),
                "max": np.max([m["max"] for m in per_seed], axis=0).tolist(),
                "torque_rms": np.mean([m["torque_rms"] for m in per_seed], axis=0).tolist(),
                "torque_max": np.max([np.max(np.abs(t.u), axis=0, initial=0.0) for t in trajs], axis=0).tolist(),
                "time_to_band": np.mean([m["time_to_band"] for m in per_seed], axis=0).tolist(),
                "seeds": [s.seed for s in runs if s.case == case and s.controller == name],
                "diverged": any(m["diverged"] for m in per_seed),
                "faults": fault_totals(trajs),
                "step_ms_median": float(np.median(np.concatenate([t.timings["total"] for t in trajs])) * 1e3),
                "step_ms_p99": float(np.percentile(np.concatenate([t.timings["total"] for t in trajs]), 99) * 1e3),
            }
            if trajs and after[0].any() and np.all(np.isfinite(trajs[0].disturbance_estimate[after[0]])):
                errors = np.concatenate([t.disturbance_estimate[a] - t.disturbance[a] for t, a in zip(trajs, after)])
                truth = np.concatenate([t.disturbance[a] for t, a in zip(trajs, after)])
                entry["disturbance_estimate_rms_after_1s"] = np.sqrt(np.mean(errors**2, axis=0)).tolist()
                entry["disturbance_rms_after_1s"] = np.sqrt(np.mean(truth**2, axis=0)).tolist()
            if name in REPLICATED_ROWS and case == "clean":
                replicas = [results[s.key] for s in runs if s.controller == name and s.case.startswith("replica")]
                if replicas:
                    entry["replicas"] = replica_summary(trajs + replicas)
            elif name in REPLICATED_ROWS and len(trajs) > 1:  # the seeds are the replicas: the mean's error
                root = math.sqrt(len(trajs))
                entry["Ep_spread"] = (_spread(ep) / root).tolist()
                entry["Ep_steady_spread"] = (_spread(steady) / root).tolist()
                entry["Ep_mean_of_joints_spread"] = float(_spread(ep.mean(axis=1, keepdims=True))[0] / root)
            metrics[case][name] = entry
        bound = [tracking_metrics(results[s.key]) for s in runs if s.case == f"bound-{case}"]
        bound_ep = np.mean([m["Ep"] for m in bound], axis=0).tolist()
        bound_gain = gain_percent(metrics[case]["MPC"]["Ep"], bound_ep)
        metrics[case]["MPC_dry_arm_bound"] = {
            "Ep": bound_ep,
            "gain_over_MPC_percent": bound_gain,
            "gain_mean_of_joints": float(np.mean(bound_gain)),
            "note": "MPC on the arm without water: what perfect disturbance compensation could reach",
        }
        gains = gain_percent(metrics[case]["MPC"]["Ep"], metrics[case]["GP-MPC"]["Ep"])
        metrics[case]["gain_gp_mpc_over_mpc_percent"] = {
            "per_joint": gains,
            "mean_of_joints": float(np.mean(gains)),
            "of_mean_Ep": 100.0 * (1 - metrics[case]["GP-MPC"]["Ep_mean"] / metrics[case]["MPC"]["Ep_mean"]),
            "steady_per_joint": gain_percent(metrics[case]["MPC"]["Ep_steady"], metrics[case]["GP-MPC"]["Ep_steady"]),
        }
        if paper_arm:
            metrics[case]["gain_gp_mpc_over_mpc_percent"]["paper_mean_of_joints"] = PAPER_GAIN[case]
    for case in ("clean", "noisy"):
        block, best = metrics[case], metrics[case][BEST]
        others = [name for name in ROWS if name != BEST]
        block["best"] = {
            "row": BEST,
            "beats_on_mean_Ep": [name for name in others if best["Ep_mean"] < block[name]["Ep_mean"]],
            "loses_on_mean_Ep_to": [name for name in others if best["Ep_mean"] >= block[name]["Ep_mean"]],
            "joints_beaten_vs_SMC": [j + 1 for j, (a, b) in enumerate(zip(best["Ep"], block["SMC"]["Ep"])) if a < b],
            "steady_ratio_SMC_over_best": [
                b / a if a > 0 else math.inf for a, b in zip(best["Ep_steady"], block["SMC"]["Ep_steady"])
            ],
            "steady_ratio_SMCKF_over_best": [  # the SMC behind the same estimator
                b / a if a > 0 else math.inf for a, b in zip(best["Ep_steady"], block["SMC+KF"]["Ep_steady"])
            ],
        }
    ablation: dict = {}
    ablation_idmpc: dict = {}
    for spec in runs:
        if spec.case.startswith("ablation-idmpc/"):
            group, label = spec.case.removeprefix("ablation-idmpc/").split("=", 1)
            traj = results[spec.key]
            m = tracking_metrics(traj)
            ablation_idmpc.setdefault(group, {})[label] = {
                "controller": spec.controller,
                "Ep_mean": float(np.mean(m["Ep"])),
                "Ep": m["Ep"],
                "Ep_steady_mean": float(np.mean(m["Ep_steady"])),
                "step_ms_median": float(np.median(traj.timings["total"]) * 1e3),
                "step_ms_p99": float(np.percentile(traj.timings["total"], 99) * 1e3),
                "diverged": m["diverged"],
            }
            continue
        if not spec.case.startswith("ablation/"):
            continue
        group, label = spec.case.removeprefix("ablation/").split("=", 1)
        traj = results[spec.key]
        m = tracking_metrics(traj)
        row = ablation.setdefault(group, {}).setdefault(label, {})
        row[spec.controller] = {
            "Ep_mean": float(np.mean(m["Ep"])),
            "Ep": m["Ep"],
            "Ep_steady_mean": float(np.mean(m["Ep_steady"])),
            "step_ms_median": float(np.median(traj.timings["total"]) * 1e3),
            "diverged": m["diverged"],
            "faults": fault_totals([traj]),
        }
    for rows in ablation.values():
        for row in rows.values():
            if "MPC" in row and "GP-MPC" in row:
                gains = gain_percent(row["MPC"]["Ep"], row["GP-MPC"]["Ep"])
                row["gain_mean_of_joints"] = float(np.mean(gains))
    metrics["ablation"] = ablation
    metrics["ablation_idmpc"] = ablation_idmpc
    return metrics


# The tables: table1/2 and the ablations (.md and .csv)


def _fmt(x: float) -> str:
    return f"{x:.4g}"


def held(entry: dict, key: str = "Ep") -> tuple[list[float], list[float] | None, float, float | None]:
    """``(per joint, their spreads or None, mean of joints, its spread or None)`` of a row's ``key``
    (``"Ep"`` or ``"Ep_steady"``): a replicated clean row's replica mean and spread, a replicated
    noisy row's mean over seeds and its standard error, any other row's numbers (spread None)."""
    replicas = entry.get("replicas")
    if replicas is not None:
        values, spread = replicas[f"{key}_mean"], replicas[f"{key}_spread"]
        mean_spread = replicas["Ep_mean_of_joints_spread"] if key == "Ep" else None
        return values, spread, float(np.mean(values)), mean_spread
    values = entry[key]
    spread = entry.get(f"{key}_spread")
    mean_spread = entry.get("Ep_mean_of_joints_spread") if key == "Ep" else None
    return values, spread, float(np.mean(values)), mean_spread


def held_digits(x: float, spread: float | None) -> str:
    """``x`` with only the digits its ``spread`` leaves: rounded at the spread's first significant
    digit, with the spread (``0.05 ± 0.02``); 4 significant digits when the spread is below them
    (or unknown)."""
    if spread is None or not math.isfinite(x) or not math.isfinite(spread) or spread <= 5e-5 * abs(x):
        return _fmt(x)
    decimals = -math.floor(math.log10(spread))
    factor = 10.0**decimals
    spread_rounded = math.ceil(spread * factor - 1e-9) / factor  # never below the spread
    if decimals <= 0:
        return f"{round(x * factor) / factor:.0f} ± {spread_rounded:.0f}"
    return f"{x:.{decimals}f} ± {spread_rounded:.{decimals}f}"


def _held_cells(entry: dict, key: str = "Ep") -> list[str]:
    values, spread, mean, mean_spread = held(entry, key)
    spreads = spread if spread is not None else [None] * len(values)
    return [held_digits(x, e) for x, e in zip(values, spreads)] + [held_digits(mean, mean_spread)]


def spread_note(block: dict, case: str) -> str:
    """What the ``±`` of a table's replicated rows (:data:`REPLICATED_ROWS`) is; ``""`` if none has one."""
    rows = [name for name in REPLICATED_ROWS if name in block]
    if case == "clean":
        counts = {block[name]["replicas"]["count"] for name in rows if "replicas" in block[name]}
        if not counts:
            return ""
        return (
            f"; rows {', '.join(rows)}: mean ± std of {max(counts)} runs from starts {REPLICA_OFFSET:g} rad apart "
            "(their closed loop turns a last-bit difference into another run), digits beyond the spread dropped"
        )
    if not any(block[name].get("Ep_spread") is not None for name in rows):
        return ""
    return (
        f"; rows {', '.join(rows)}: mean over seeds ± its standard error (their closed loop turns a last-bit "
        "difference into another run), digits beyond it dropped"
    )


def write_tables(metrics: dict, out: Path) -> None:
    """table1/2 (.md and .csv): ours beside the paper's (on the paper's arm only: elsewhere the
    paper's numbers, of another arm, are left out), steady state, gains; ablation tables."""
    settings = metrics.get("settings", {})
    paper_arm = settings.get("paper_arm", True)
    on_arm = "" if paper_arm else f" on the arm `{settings.get('experiment', {}).get('arm', '?')}`"
    for number, case in ((1, "clean"), (2, "noisy")):
        block = metrics[case]
        n = len(block["MPC"]["Ep"])
        header = ["row"] + [f"joint {j + 1}" for j in range(n)] + ["mean"]
        rows = []
        for name in PAPER_CONTROLLERS:
            label = f"{name} (ours" + (f", mean of {len(block[name]['seeds'])} seeds)" if case == "noisy" else ")")
            rows.append([label] + _held_cells(block[name]))
            if case == "noisy":
                rows.append([f"{name} (ours, std over seeds)"] + [_fmt(x) for x in block[name]["Ep_std"]] + [""])
            if paper_arm:
                paper = PAPER_EP[case][name][:n]
                rows.append([f"{name} (paper)"] + [_fmt(x) for x in paper] + [_fmt(np.mean(paper))])
        bound = block["MPC_dry_arm_bound"]["Ep"]
        rows.append(["MPC on the arm without water (bound)"] + [_fmt(x) for x in bound] + [_fmt(np.mean(bound))])
        for name in EXTRA_ROWS:
            label = "hydroarm's flagship: GP-IDMPC, Kalman filter" if name == BEST else f"{name[:-3]} + Kalman filter"
            rows.append([label] + _held_cells(block[name]))
        for name in ROWS:
            rows.append([f"{name} (ours, t > 2 s)"] + _held_cells(block[name], "Ep_steady"))
        rows.append(["GP-MPC gain over MPC, % (ours)"] + _gain_cells(block))
        if paper_arm:
            paper_gain = gain_percent(PAPER_EP[case]["MPC"][:n], PAPER_EP[case]["GP-MPC"][:n])
            rows.append(
                ["GP-MPC gain over MPC, % (paper)"] + [f"{g:.1f}" for g in paper_gain] + [f"{PAPER_GAIN[case]:.2f}"]
            )
        bound_gain = block["MPC_dry_arm_bound"]["gain_over_MPC_percent"]
        rows.append(
            ["bound: gain of perfect compensation, %"]
            + [f"{g:.1f}" for g in bound_gain]
            + [f"{np.mean(bound_gain):.1f}"]
        )
        rows.append(["GP-MPC gain, t > 2 s, % (ours)"] + _gain_cells(block, "Ep_steady"))
        title = (
            f"Table 1: E_p (rad^2){on_arm}, no measurement noise"
            if case == "clean"
            else f"Table 2: E_p (rad^2){on_arm}, measurement noise of variance 0.001"
        )
        title += spread_note(block, case)
        duration = settings.get("experiment", {}).get("duration", PAPER_DURATION)
        if paper_arm and duration != PAPER_DURATION:
            title += (
                f"; ours over a {duration:g} s task, the paper's over its {PAPER_DURATION:g} s one: the start-up "
                "weighs more in a shorter task, so compare the rows of a full run"
            )
        _write_table(out / f"table{number}", title, header, rows)
    header = [
        "setting",
        "value",
        "MPC E_p mean",
        "GP-MPC E_p mean",
        "gain, mean of joints (%)",
        "GP-MPC t>2 s E_p mean",
        "MPC step median (ms)",
        "GP-MPC step median (ms)",
    ]
    rows = []
    for group, values in metrics["ablation"].items():
        for label, row in values.items():
            mpc, gp = row.get("MPC", {}), row.get("GP-MPC", {})
            rows.append([
                group, label, _fmt(mpc.get("Ep_mean", math.nan)), _fmt(gp.get("Ep_mean", math.nan)),
                f"{row.get('gain_mean_of_joints', math.nan):.1f}", _fmt(gp.get("Ep_steady_mean", math.nan)),
                f"{mpc.get('step_ms_median', math.nan):.3f}", f"{gp.get('step_ms_median', math.nan):.3f}",
            ])  # fmt: skip
    if rows:
        _write_table(
            out / "ablation", "Ablation of the GP-MPC (clean, seed 0; one setting changed at a time)", header, rows
        )
    header = ["choice", "value", "row", "E_p mean", "t>2 s E_p mean", "step median (ms)", "step p99 (ms)", "diverged"]
    rows = [
        [group, label, row["controller"], _fmt(row["Ep_mean"]), _fmt(row["Ep_steady_mean"]),
         f"{row['step_ms_median']:.3f}", f"{row['step_ms_p99']:.3f}", str(row["diverged"])]
        for group, values in metrics.get("ablation_idmpc", {}).items()
        for label, row in values.items()
    ]  # fmt: skip
    if rows:
        _write_table(
            out / "ablation_idmpc",
            f"Ablation of hydroarm's flagship ({BEST}; clean, seed 0; one choice changed at a time)",
            header,
            rows,
        )


def _gain_cells(block: dict, key: str = "Ep") -> list[str]:
    """GP-MPC's gain over MPC per joint and its mean of joints (%), from the GP-MPC row's held
    numbers (:func:`held`) and with their spread (MPC's own is at round-off)."""
    values, spread, _, _ = held(block["GP-MPC"], key)
    mpc = block["MPC"][key]
    gains = gain_percent(mpc, values)
    if spread is None:
        return [f"{g:.1f}" for g in gains] + [f"{np.mean(gains):.1f}"]
    spreads = [100.0 * e / b if b > 0 else math.nan for e, b in zip(spread, mpc)]
    cells = [held_digits(g, max(e, 0.05)) for g, e in zip(gains, spreads)]
    mean_spread = float(np.sqrt(np.sum(np.square(spreads)))) / len(spreads)  # joints independent
    return cells + [held_digits(float(np.mean(gains)), max(mean_spread, 0.05))]


def _write_table(stem: Path, title: str, header: list[str], rows: list[list[str]]) -> None:
    with stem.with_suffix(".csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        writer.writerows(rows)
    lines = [f"### {title}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    stem.with_suffix(".md").write_text("\n".join(lines) + "\n")


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
