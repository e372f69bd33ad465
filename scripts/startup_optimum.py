"""How far is GP-IDMPC's start-up from an optimal one? Open-loop torques optimised on the true plant.

The paper task starts 3 rad from the reference on joints 1 and 6 and 2 rad on joints 3 and 4,
and the whole of E_p's start-up share is spent in the first ~0.25 s, with joint 1 saturated at
its 500 N m. This script asks what the best torque sequence over those first K control steps
could reach if the controller knew the true plant exactly (water, added mass, current): it
minimises ``sum_{k <= K} |q_k - q_r,k|^2`` (the start-up's share of 1000 E_p) over the K x n
torques within the limits, by L-BFGS-B (SciPy) with central-difference gradients on the true
plant, from the torques a closed-loop controller applied.

The optimisation runs on the plant with a coarser inner step (``--inner-step``, default 5 ms:
two RK4 steps per control period) for speed; every result is re-evaluated on the plant of the
default settings. A local optimiser on a non-convex problem finds a local optimum near its start:
the starts are the closed-loop torques of several controllers and settings, so different
start-up strategies are tried.

Usage: python scripts/startup_optimum.py [--steps 30] [--iterations 150] [--out docs/data/startup_optimum.json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import scipy.optimize

from hydroarm.sim.experiment import ExperimentConfig, build_experiment, run_experiment, with_overrides

STARTS = {  # label -> (controller, overrides): the closed-loop runs whose torques start the search
    "GP-IDMPC (defaults)": ("gp-idmpc", {}),
    "GP-IDMPC, q_position 3000": ("gp-idmpc", {"idmpc.q_position": 3000.0}),
    "SMC": ("smc", {}),
}


def start_up_cost(plant, x0, q_r, torques, period) -> tuple[float, np.ndarray]:
    """``(sum_k |q_k - q_r,k|^2 for k = 0..K, per-joint sums (n,))`` of the open-loop torques (K, n)."""
    n = torques.shape[1]
    x = x0.copy()
    per_joint = (x[:n] - q_r[0]) ** 2
    for k, tau in enumerate(torques):
        x, _ = plant.step(k * period, x, tau, period)
        if not np.all(np.isfinite(x)):
            return 1e12, np.full(n, np.inf)
        per_joint = per_joint + (x[:n] - q_r[k + 1]) ** 2
    return float(per_joint.sum()), per_joint


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=30, help="start-up control steps K optimised")
    parser.add_argument("--iterations", type=int, default=150, help="L-BFGS-B iterations per start")
    parser.add_argument("--inner-step", type=float, default=0.005, help="plant inner step while optimising (s)")
    parser.add_argument("--out", default="docs/data/startup_optimum.json")
    parser.add_argument("--start", action="append", choices=list(STARTS), help="only these starts (repeatable)")
    args = parser.parse_args()

    config = ExperimentConfig()
    exact = build_experiment(config, None)
    coarse = build_experiment(with_overrides(config, {"plant.inner_step": args.inner_step}), None).plant
    period, steps, n = config.control_period, args.steps, exact.arm.n_joints
    limit = np.broadcast_to(np.asarray(exact.arm.torque_limit, dtype=float), (n,))
    q_r = exact.reference.sample(np.arange(steps + 1) * period)[0]
    bounds = [(-lim, lim) for lim in np.tile(limit, steps)]
    results = {}
    for label, (controller, overrides) in STARTS.items():
        if args.start and label not in args.start:
            continue
        run = run_experiment(with_overrides(config, overrides), controller, seed=0)
        e2 = (run.x[:, :n] - run.q_ref) ** 2
        start = run.u[:steps].copy()

        def cost_and_gradient(flat: np.ndarray, h: float = 1e-2) -> tuple[float, np.ndarray]:
            value = start_up_cost(coarse, exact.x0, q_r, flat.reshape(steps, n), period)[0]
            gradient = np.empty_like(flat)
            for i in range(flat.size):
                up, down = flat.copy(), flat.copy()
                up[i] += h
                down[i] -= h
                gradient[i] = (
                    start_up_cost(coarse, exact.x0, q_r, up.reshape(steps, n), period)[0]
                    - start_up_cost(coarse, exact.x0, q_r, down.reshape(steps, n), period)[0]
                ) / (2 * h)
            return value, gradient

        began = time.perf_counter()
        found = scipy.optimize.minimize(
            cost_and_gradient, start.ravel(), jac=True, method="L-BFGS-B", bounds=bounds,
            options={"maxiter": args.iterations},
        )  # fmt: skip
        optimised = np.clip(found.x.reshape(steps, n), -limit, limit)
        before, before_joints = start_up_cost(exact.plant, exact.x0, q_r, start, period)
        after, after_joints = start_up_cost(exact.plant, exact.x0, q_r, optimised, period)
        tail = float(e2[steps + 1 :].sum())  # the closed loop's error after the start-up window
        results[label] = {
            "closed_loop_Ep_mean": float(e2.mean()),
            "start_up_cost_closed_loop": before,
            "start_up_cost_optimised": after,
            "improvement_percent": 100.0 * (before - after) / before,
            "per_joint_closed_loop": before_joints.tolist(),
            "per_joint_optimised": after_joints.tolist(),
            "Ep_mean_with_optimised_start_up": (after + tail) / e2.size,
            "optimiser": {
                "message": str(found.message),
                "iterations": int(found.nit),
                "seconds": time.perf_counter() - began,
            },
        }
        print(f"{label}: start-up cost {before:.3f} -> {after:.3f} ({results[label]['improvement_percent']:.2f} %), "
              f"E_p mean {e2.mean():.5f} -> {results[label]['Ep_mean_with_optimised_start_up']:.5f} "
              f"({found.nit} iterations, {found.message})", flush=True)  # fmt: skip
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    settings = {"steps": steps, "iterations": args.iterations, "inner_step": args.inner_step, "starts": list(results)}
    out.write_text(json.dumps({"settings": settings, "starts": results}, indent=1) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
