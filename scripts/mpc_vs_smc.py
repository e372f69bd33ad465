"""Can any MPC setting beat the tuned sliding-mode baseline on every joint? (issue 4)

Runs the SMC (default gains) and the MPC and GP-MPC over a grid of MPC weights and
horizons on the paper task (10 s, true plant), clean and noisy (variance 0.001,
seed 1), and records per-joint E_p and which joints the MPC beats the SMC on.
Usage: python scripts/mpc_vs_smc.py [--out docs/data/mpc_vs_smc.json] [--workers 2]
"""

from __future__ import annotations

import argparse
import itertools
import json
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from hydroarm.experiments import ExperimentConfig, run_experiment, with_overrides
from hydroarm.simulate import tracking_metrics

GRID = {"mpc.r": [0.1, 1e-3, 1e-4], "mpc.q_velocity": [0.01, 1.0], "mpc.horizon": [10, 20]}
CASES = {"clean": (0.0, 0), "noisy": (1e-3, 1)}


def ep(task: tuple[str, dict, str]) -> tuple[str, dict, str, list[float]]:
    controller, overrides, case = task
    variance, seed = CASES[case]
    config = with_overrides(ExperimentConfig(), {**overrides, "plant.noise_variance": variance})
    return controller, overrides, case, tracking_metrics(run_experiment(config, controller, seed=seed))["Ep"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/data/mpc_vs_smc.json"))
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    settings = [dict(zip(GRID, values)) for values in itertools.product(*GRID.values())]
    tasks = [("SMC", {}, case) for case in CASES]
    tasks += [(name, s, case) for s in settings for name in ("MPC", "GP-MPC") for case in CASES]
    with ProcessPoolExecutor(args.workers) as pool:
        results = list(pool.map(ep, tasks))
    smc = {case: np.array(e) for name, _, case, e in results if name == "SMC"}
    rows = []
    for s in settings:
        row = {"settings": s}
        for case in CASES:
            mpc = np.array(next(e for n, o, c, e in results if n == "MPC" and o == s and c == case))
            gp = np.array(next(e for n, o, c, e in results if n == "GP-MPC" and o == s and c == case))
            row[case] = {
                "MPC": mpc.tolist(), "GP-MPC": gp.tolist(),
                "MPC_beats_SMC_joints": [int(j + 1) for j in np.flatnonzero(mpc < smc[case])],
                "GP-MPC_beats_MPC_joints": [int(j + 1) for j in np.flatnonzero(gp < mpc)],
                "mean": {"SMC": float(smc[case].mean()), "MPC": float(mpc.mean()), "GP-MPC": float(gp.mean())},
                "gain_mean_of_joints_percent": float(np.mean(100.0 * (mpc - gp) / mpc)),
            }  # fmt: skip
        rows.append(row)
        print(s, {c: row[c]["MPC_beats_SMC_joints"] for c in CASES}, {c: row[c]["mean"] for c in CASES})
    output = {"SMC": {case: smc[case].tolist() for case in CASES}, "grid": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(output, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
