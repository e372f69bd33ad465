"""Can any MPC setting beat the tuned sliding-mode baseline on every joint? (issue 4)

Runs the SMC (default gains) and the MPC and GP-MPC over a grid of MPC weights and
horizons on the paper task (10 s, true plant), clean and noisy (variance 0.001,
seed 1), and records per-joint E_p, which joints the MPC beats the SMC on, and the
GP-MPC's gain over the MPC. The "dry" case runs the MPC and the SMC on the arm
without water, where the MPC's model is exact: it separates what the water costs
from what the controller's structure costs (the start-up transient).

Writes the JSON (``--out``) and a figure (``--figure``): per joint, E_p of MPC and
GP-MPC against R with the SMC's as a line, and the paper-style gain against R.
Usage: python scripts/mpc_vs_smc.py [--out docs/data/mpc_vs_smc.json]
       [--figure docs/figures/mpc_vs_smc.png] [--workers 2]
"""

from __future__ import annotations

import argparse
import itertools
import json
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from hydroarm.sim.experiment import ExperimentConfig, run_experiment, with_overrides
from hydroarm.sim.runner import tracking_metrics

R_VALUES = [0.1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6]
GRID = {"mpc.r": R_VALUES, "mpc.q_velocity": [0.01, 1.0], "mpc.horizon": [10, 20]}
DRY = {"water.drag": False, "water.added_mass": False, "water.buoyancy": False, "water.current.model": "none"}
CASES = {"clean": ({"plant.noise_variance": 0.0}, 0), "noisy": ({"plant.noise_variance": 1e-3}, 1), "dry": (DRY, 0)}
PAPER_GAIN = {"clean": 34.05, "noisy": 52.27}


def ep(task: tuple[str, dict, str]) -> tuple[str, dict, str, list[float]]:
    """``(controller, overrides, case, E_p per joint)`` of one run."""
    controller, overrides, case = task
    case_overrides, seed = CASES[case]
    config = with_overrides(ExperimentConfig(), {**overrides, **case_overrides})
    return controller, overrides, case, tracking_metrics(run_experiment(config, controller, seed=seed))["Ep"]


def tasks_for(settings: list[dict]) -> list[tuple[str, dict, str]]:
    """SMC once per case; MPC and GP-MPC per setting in water; the MPC alone on the dry arm
    (with no disturbance the GP-MPC is the MPC), at the default velocity weight and horizon."""
    tasks = [("SMC", {}, case) for case in CASES]
    tasks += [(name, s, case) for s in settings for name in ("MPC", "GP-MPC") for case in ("clean", "noisy")]
    tasks += [("MPC", s, "dry") for s in settings if s["mpc.q_velocity"] == 0.01 and s["mpc.horizon"] == 10]
    return tasks


def summarise(results: list, settings: list[dict]) -> dict:
    """The JSON: SMC per case, one row per setting (water cases), the dry-arm rows."""
    found = {(name, json.dumps(o, sort_keys=True), case): np.array(e) for name, o, case, e in results}
    smc = {case: found[("SMC", "{}", case)] for case in CASES}
    rows, dry_rows = [], []
    for s in settings:
        key = json.dumps(s, sort_keys=True)
        row = {"settings": s}
        for case in ("clean", "noisy"):
            mpc, gp = found[("MPC", key, case)], found[("GP-MPC", key, case)]
            row[case] = {
                "MPC": mpc.tolist(), "GP-MPC": gp.tolist(),
                "MPC_beats_SMC_joints": [int(j + 1) for j in np.flatnonzero(mpc < smc[case])],
                "GP-MPC_beats_MPC_joints": [int(j + 1) for j in np.flatnonzero(gp < mpc)],
                "mean": {"SMC": float(smc[case].mean()), "MPC": float(mpc.mean()), "GP-MPC": float(gp.mean())},
                "mean_order_GP-MPC_MPC_SMC": bool(gp.mean() < mpc.mean() < smc[case].mean()),
                "gain_mean_of_joints_percent": float(np.mean(100.0 * (mpc - gp) / mpc)),
            }  # fmt: skip
        rows.append(row)
        if ("MPC", key, "dry") in found:
            mpc = found[("MPC", key, "dry")]
            dry_rows.append({
                "settings": s, "MPC": mpc.tolist(),
                "MPC_beats_SMC_joints": [int(j + 1) for j in np.flatnonzero(mpc < smc["dry"])],
            })  # fmt: skip
    return {"SMC": {case: smc[case].tolist() for case in CASES}, "grid": rows, "dry_arm": dry_rows}


def plot(summary: dict, path: Path) -> None:
    """E_p per joint against R (N = 10, q_v = 0.01): MPC, GP-MPC, MPC on the dry arm and the
    SMC (lines), clean; last panel: the paper-style gain against R, clean and noisy."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [
        r for r in summary["grid"] if r["settings"]["mpc.q_velocity"] == 0.01 and r["settings"]["mpc.horizon"] == 10
    ]
    r_values = [r["settings"]["mpc.r"] for r in rows]
    dry = {d["settings"]["mpc.r"]: d["MPC"] for d in summary["dry_arm"]}
    fig, axes = plt.subplots(2, 4, figsize=(16, 7.5), constrained_layout=True)
    for j in range(6):
        ax = axes.flat[j]
        ax.loglog(r_values, [r["clean"]["MPC"][j] for r in rows], "o-", label="MPC (water)")
        ax.loglog(r_values, [r["clean"]["GP-MPC"][j] for r in rows], "s-", label="GP-MPC (water)")
        ax.loglog(r_values, [dry[r][j] for r in r_values], "^--", color="grey", label="MPC (dry arm, exact model)")
        ax.axhline(summary["SMC"]["clean"][j], color="k", label="SMC (water)")
        ax.axhline(summary["SMC"]["dry"][j], color="k", ls=":", label="SMC (dry arm)")
        ax.set_title(f"joint {j + 1}: E_p, no noise")
        ax.set_xlabel("R (1/(N m)^2)")
        ax.set_ylabel("E_p (rad^2)")
        ax.invert_xaxis()
    axes.flat[0].legend(fontsize=8)
    ax = axes.flat[6]
    for case, marker in (("clean", "o-"), ("noisy", "s-")):
        ax.semilogx(r_values, [r[case]["gain_mean_of_joints_percent"] for r in rows], marker, label=case)
        ax.axhline(PAPER_GAIN[case], ls=":", color="C0" if case == "clean" else "C1", label=f"paper, {case}")
    ax.set_title("GP-MPC gain over MPC (mean of joints)")
    ax.set_xlabel("R (1/(N m)^2)")
    ax.set_ylabel("gain (%)")
    ax.invert_xaxis()
    ax.legend(fontsize=8)
    ax = axes.flat[7]
    for case, marker in (("clean", "o-"), ("noisy", "s-")):
        ax.semilogx(r_values, [len(r[case]["MPC_beats_SMC_joints"]) for r in rows], marker, label=case)
    ax.set_title("joints on which the MPC beats the SMC")
    ax.set_xlabel("R (1/(N m)^2)")
    ax.set_ylabel("joints (of 6)")
    ax.set_ylim(0, 6.5)
    ax.invert_xaxis()
    ax.legend(fontsize=8)
    fig.suptitle("MPC weight R against the tuned SMC (paper task, 10 s; Q = diag(300, 0.01), N = 10)")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/data/mpc_vs_smc.json"))
    parser.add_argument("--figure", type=Path, default=Path("docs/figures/mpc_vs_smc.png"))
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    settings = [dict(zip(GRID, values)) for values in itertools.product(*GRID.values())]
    with ProcessPoolExecutor(args.workers) as pool:
        results = list(pool.map(ep, tasks_for(settings)))
    summary = summarise(results, settings)
    for row in summary["grid"]:
        print(row["settings"], {c: row[c]["MPC_beats_SMC_joints"] for c in ("clean", "noisy")},
              {c: round(row[c]["gain_mean_of_joints_percent"], 1) for c in ("clean", "noisy")},
              {c: row[c]["mean_order_GP-MPC_MPC_SMC"] for c in ("clean", "noisy")})  # fmt: skip
    for row in summary["dry_arm"]:
        print("dry", row["settings"]["mpc.r"], row["MPC_beats_SMC_joints"])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(summary, indent=1))
    plot(summary, args.figure)
    print(f"wrote {args.out} and {args.figure}")


if __name__ == "__main__":
    main()
