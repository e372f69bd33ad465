"""The reproduction's numbers: metrics.json from the runs, Tables 1-2 and the ablation tables.

Rows: the paper's controllers on the raw measurement (:data:`PAPER_CONTROLLERS`), then
:data:`EXTRA_ROWS` (hydroarm's best and the paper's controllers behind the same Kalman
filter). The paper's own numbers (:data:`PAPER_EP`, paper reading, section 7) are printed beside ours.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from hydroarm.control.registry import PAPER_CONTROLLERS
from hydroarm.sim.runner import Trajectory, fault_counts, stop_reason, tracking_metrics

NOISE_VARIANCE = 0.001

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

BEST = "GP-IDMPC+KF"
"""hydroarm's best controller row: GP-IDMPC behind its (default) Kalman filter."""

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
"""The paper's "average control accuracy" gain: the mean of the per-joint gains (%)."""


PAPER_DURATION = 10.0
"""s: the paper's task (its Tables 1-2)."""


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


def summarise(runs: list, results: dict[str, Trajectory], paper_arm: bool = True) -> dict:
    """metrics.json: per case and controller, E_p per joint (mean over seeds) and more.
    ``paper_arm``: the runs are on the paper's arm (then the paper's gain is recorded beside ours)."""
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
            if trajs and np.all(np.isfinite(trajs[0].disturbance_estimate[after[0]])):
                errors = np.concatenate([t.disturbance_estimate[a] - t.disturbance[a] for t, a in zip(trajs, after)])
                truth = np.concatenate([t.disturbance[a] for t, a in zip(trajs, after)])
                entry["disturbance_estimate_rms_after_1s"] = np.sqrt(np.mean(errors**2, axis=0)).tolist()
                entry["disturbance_rms_after_1s"] = np.sqrt(np.mean(truth**2, axis=0)).tolist()
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


def _fmt(x: float) -> str:
    return f"{x:.4g}"


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
            ep = block[name]["Ep"]
            label = f"{name} (ours" + (f", mean of {len(block[name]['seeds'])} seeds)" if case == "noisy" else ")")
            rows.append([label] + [_fmt(x) for x in ep] + [_fmt(np.mean(ep))])
            if case == "noisy":
                rows.append([f"{name} (ours, std over seeds)"] + [_fmt(x) for x in block[name]["Ep_std"]] + [""])
            if paper_arm:
                paper = PAPER_EP[case][name][:n]
                rows.append([f"{name} (paper)"] + [_fmt(x) for x in paper] + [_fmt(np.mean(paper))])
        bound = block["MPC_dry_arm_bound"]["Ep"]
        rows.append(["MPC on the arm without water (bound)"] + [_fmt(x) for x in bound] + [_fmt(np.mean(bound))])
        for name in EXTRA_ROWS:
            ep = block[name]["Ep"]
            label = "hydroarm's best: GP-IDMPC, Kalman filter" if name == BEST else f"{name[:-3]} + Kalman filter"
            rows.append([label] + [_fmt(x) for x in ep] + [_fmt(np.mean(ep))])
        for name in ROWS:
            steady = block[name]["Ep_steady"]
            rows.append([f"{name} (ours, t > 2 s)"] + [_fmt(x) for x in steady] + [_fmt(np.mean(steady))])
        gain = block["gain_gp_mpc_over_mpc_percent"]
        rows.append(
            ["GP-MPC gain over MPC, % (ours)"]
            + [f"{g:.1f}" for g in gain["per_joint"]]
            + [f"{gain['mean_of_joints']:.1f}"]
        )
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
        rows.append(
            ["GP-MPC gain, t > 2 s, % (ours)"]
            + [f"{g:.1f}" for g in gain["steady_per_joint"]]
            + [f"{np.mean(gain['steady_per_joint']):.1f}"]
        )
        title = (
            f"Table 1: E_p (rad^2){on_arm}, no measurement noise"
            if case == "clean"
            else f"Table 2: E_p (rad^2){on_arm}, measurement noise of variance 0.001"
        )
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
            f"Ablation of hydroarm's best ({BEST}; clean, seed 0; one choice changed at a time)",
            header,
            rows,
        )


def _write_table(stem: Path, title: str, header: list[str], rows: list[list[str]]) -> None:
    with stem.with_suffix(".csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        writer.writerows(rows)
    lines = [f"### {title}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    stem.with_suffix(".md").write_text("\n".join(lines) + "\n")
