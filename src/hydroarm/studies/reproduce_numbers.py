"""The reproduction's numbers and tables: summary.json's numbers from the runs (:func:`summarise`:
per case and row E_p and more, the bound, the gains, where hydroarm's best wins, the ablations)
and table1/2 and the ablation tables (.md and .csv, :func:`write_tables`), with only the digits
a replicated row's spread leaves (:func:`held_digits`). The rows are :mod:`hydroarm.studies.reproduce_rows`'."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from hydroarm.control.registry import PAPER_CONTROLLERS
from hydroarm.sim.runner import Trajectory, fault_counts, stop_reason, tracking_metrics
from hydroarm.studies.reproduce_rows import (
    BEST,
    EXTRA_ROWS,
    PAPER_DURATION,
    PAPER_EP,
    PAPER_GAIN,
    REPLICA_OFFSET,
    REPLICATED_ROWS,
    ROWS,
)

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
        metrics[case] = {name: _row_entry(runs, results, case, name) for name in ROWS}
        _add_gains(metrics[case], runs, results, case, paper_arm)
    for case in ("clean", "noisy"):
        metrics[case]["best"] = _best_entry(metrics[case])
    metrics["ablation"], metrics["ablation_idmpc"] = ablation_metrics(runs, results)
    return metrics


def _row_entry(runs: list, results: dict[str, Trajectory], case: str, name: str) -> dict:
    """One row of :func:`summarise`'s ``case`` block: its runs' metrics over the seeds."""
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
    return entry


def _add_gains(block: dict, runs: list, results: dict[str, Trajectory], case: str, paper_arm: bool) -> None:
    """Into a case's ``block``: the dry-arm MPC bound (its ``bound-<case>`` runs) and GP-MPC's gain over MPC."""
    bound = [tracking_metrics(results[s.key]) for s in runs if s.case == f"bound-{case}"]
    bound_ep = np.mean([m["Ep"] for m in bound], axis=0).tolist()
    bound_gain = gain_percent(block["MPC"]["Ep"], bound_ep)
    block["MPC_dry_arm_bound"] = {
        "Ep": bound_ep,
        "gain_over_MPC_percent": bound_gain,
        "gain_mean_of_joints": float(np.mean(bound_gain)),
        "note": "MPC on the arm without water: what perfect disturbance compensation could reach",
    }
    gains = gain_percent(block["MPC"]["Ep"], block["GP-MPC"]["Ep"])
    block["gain_gp_mpc_over_mpc_percent"] = {
        "per_joint": gains,
        "mean_of_joints": float(np.mean(gains)),
        "of_mean_Ep": 100.0 * (1 - block["GP-MPC"]["Ep_mean"] / block["MPC"]["Ep_mean"]),
        "steady_per_joint": gain_percent(block["MPC"]["Ep_steady"], block["GP-MPC"]["Ep_steady"]),
    }
    if paper_arm:
        block["gain_gp_mpc_over_mpc_percent"]["paper_mean_of_joints"] = PAPER_GAIN[case]


def _best_entry(block: dict) -> dict:
    """Where hydroarm's best row (:data:`BEST`) wins and loses in a case's ``block``."""
    best = block[BEST]
    others = [name for name in ROWS if name != BEST]
    return {
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


def _ablation_cell(traj: Trajectory, replicas: list[Trajectory]) -> dict:
    """One ablation run's numbers; with its replicas (a GP run's), their :func:`replica_summary`
    under ``replicas`` (``Ep`` and ``Ep_mean`` stay the unperturbed run's, as in the main tables)."""
    m = tracking_metrics(traj)
    cell = {
        "Ep_mean": float(np.mean(m["Ep"])),
        "Ep": m["Ep"],
        "Ep_steady_mean": float(np.mean(m["Ep_steady"])),
        "step_ms_median": float(np.median(traj.timings["total"]) * 1e3),
        "step_ms_p99": float(np.percentile(traj.timings["total"], 99) * 1e3),
        "diverged": m["diverged"],
        "faults": fault_totals([traj]),
    }
    if replicas:
        summary = replica_summary([traj, *replicas])
        steady = np.array(summary["Ep_steady_mean"])
        summary["Ep_steady_mean_of_joints"] = float(steady.mean())
        summary["Ep_steady_mean_of_joints_spread"] = float(
            _spread(
                np.array([tracking_metrics(t)["Ep_steady"] for t in (traj, *replicas)]).mean(axis=1, keepdims=True)
            )[0]
        )
        cell["replicas"] = summary
    return cell


def ablation_metrics(runs: list, results: dict[str, Trajectory]) -> tuple[dict, dict]:
    """The two ablations' numbers: ``ablation[group][label][controller]`` (MPC and GP-MPC side by
    side, and GP-MPC's gain) and ``ablation_idmpc[group][label]`` (one row each); a GP cell with
    replicas (:func:`ablation_runs`) carries their spread (:func:`_ablation_cell`)."""
    replicas: dict[tuple[str, str], list[Trajectory]] = {}
    for spec in runs:
        head, _, rest = spec.case.partition("/")
        if "-replica" in head:
            base = head.split("-replica")[0]
            replicas.setdefault((f"{base}/{rest}", spec.controller), []).append(results[spec.key])
    ablation: dict = {}
    ablation_idmpc: dict = {}
    for spec in runs:
        cell = None
        if spec.case.startswith(("ablation/", "ablation-idmpc/")):
            cell = _ablation_cell(results[spec.key], replicas.get((spec.case, spec.controller), []))
        if spec.case.startswith("ablation-idmpc/"):
            group, label = spec.case.removeprefix("ablation-idmpc/").split("=", 1)
            cell.pop("faults")
            ablation_idmpc.setdefault(group, {})[label] = {"controller": spec.controller, **cell}
        elif spec.case.startswith("ablation/"):
            group, label = spec.case.removeprefix("ablation/").split("=", 1)
            cell.pop("step_ms_p99")
            ablation.setdefault(group, {}).setdefault(label, {})[spec.controller] = cell
    for rows in ablation.values():
        for row in rows.values():
            if "MPC" in row and "GP-MPC" in row:
                gains = gain_percent(row["MPC"]["Ep"], ablation_held(row["GP-MPC"])[0])
                row["gain_mean_of_joints"] = float(np.mean(gains))
    return ablation, ablation_idmpc


def ablation_held(cell: dict) -> tuple[list[float], float, float | None, float, float | None]:
    """An ablation cell's held numbers: ``(E_p per joint, E_p mean of joints, its spread,
    E_p after 2 s mean of joints, its spread)``: its replicas' means and spreads where it has
    replicas (a GP run), else its own run's numbers (spreads None)."""
    replicas = cell.get("replicas")
    if replicas is None:
        return cell["Ep"], cell["Ep_mean"], None, cell["Ep_steady_mean"], None
    return (
        replicas["Ep_mean"],
        replicas["Ep_mean_of_joints"],
        replicas["Ep_mean_of_joints_spread"],
        replicas["Ep_steady_mean_of_joints"],
        replicas["Ep_steady_mean_of_joints_spread"],
    )


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
    for number, case in ((1, "clean"), (2, "noisy")):
        header, rows = _main_table_rows(metrics[case], case, settings.get("paper_arm", True))
        _write_table(out / f"table{number}", _main_table_title(metrics[case], case, settings), header, rows)
    _write_ablation_tables(metrics, out)


def _main_table_rows(block: dict, case: str, paper_arm: bool) -> tuple[list[str], list[list[str]]]:
    """Table 1 (``case`` clean) or 2 (noisy): its header and rows (ours, the paper's on its arm,
    the bound, hydroarm's rows, steady state, gains)."""
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
        ["bound: gain of perfect compensation, %"] + [f"{g:.1f}" for g in bound_gain] + [f"{np.mean(bound_gain):.1f}"]
    )
    rows.append(["GP-MPC gain, t > 2 s, % (ours)"] + _gain_cells(block, "Ep_steady"))
    return header, rows


def _main_table_title(block: dict, case: str, settings: dict) -> str:
    """Table 1's or 2's title: the case, the arm if not the paper's, the spread and the task's length."""
    paper_arm = settings.get("paper_arm", True)
    on_arm = "" if paper_arm else f" on the arm `{settings.get('experiment', {}).get('arm', '?')}`"
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
    return title


def _write_ablation_tables(metrics: dict, out: Path) -> None:
    """ablation (.md and .csv) of the GP-MPC and ablation_idmpc of hydroarm's best, if they ran;
    a GP cell with replicas as its mean with the digits its spread leaves (:func:`ablation_held`)."""
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
            mpc, gp = row.get("MPC", {}), row.get("GP-MPC")
            _, gp_mean, gp_spread, gp_steady, gp_steady_spread = (
                ablation_held(gp) if gp else (0, math.nan, None, math.nan, None)
            )
            rows.append([
                group, label, _fmt(mpc.get("Ep_mean", math.nan)), held_digits(gp_mean, gp_spread),
                f"{row.get('gain_mean_of_joints', math.nan):.1f}", held_digits(gp_steady, gp_steady_spread),
                f"{mpc.get('step_ms_median', math.nan):.3f}", f"{(gp or {}).get('step_ms_median', math.nan):.3f}",
            ])  # fmt: skip
    if rows:
        _write_table(
            out / "ablation",
            "Ablation of the GP-MPC (clean, seed 0; one setting changed at a time)"
            + _ablation_spread_note(metrics["ablation"]),
            header,
            rows,
        )
    header = ["choice", "value", "row", "E_p mean", "t>2 s E_p mean", "step median (ms)", "step p99 (ms)", "diverged"]
    rows = []
    for group, values in metrics.get("ablation_idmpc", {}).items():
        for label, row in values.items():
            _, mean, spread, steady, steady_spread = ablation_held(row)
            rows.append([
                group, label, row["controller"], held_digits(mean, spread), held_digits(steady, steady_spread),
                f"{row['step_ms_median']:.3f}", f"{row['step_ms_p99']:.3f}", str(row["diverged"])
            ])  # fmt: skip
    if rows:
        _write_table(
            out / "ablation_idmpc",
            f"Ablation of hydroarm's flagship ({BEST}; clean, seed 0; one choice changed at a time)"
            + _ablation_spread_note(metrics["ablation_idmpc"]),
            header,
            rows,
        )


def _ablation_spread_note(table: dict) -> str:
    """What the ``±`` of an ablation table's GP cells is; ``""`` if none has replicas."""
    counts = {
        cell["replicas"]["count"]
        for rows in table.values()
        for row in rows.values()
        for cell in ([row] if "controller" in row else [v for v in row.values() if isinstance(v, dict)])
        if "replicas" in cell
    }
    if not counts:
        return ""
    return (
        f"; GP cells: mean ± std of {max(counts)} runs from starts {REPLICA_OFFSET:g} rad apart (their closed "
        "loop turns a last-bit difference into another run), digits beyond the spread dropped"
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
