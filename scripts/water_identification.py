"""Identify the water from a logged run: C_d, C_m and volumes of the paper arm's cylinders by
:func:`hydroarm.control.learned_water.fit_water` (smoothing splines, weighted least squares,
instrumental variables), from an identification run in still water.

The IDMPC tracks examples/tasks/identification.toml, started on it, for 60 s, in the paper's
plant with the current off (an identification run in a tank: the paper's current is a joint
acceleration kick, not a flow the basis describes), clean (seed 1) and with the paper's
measurement noise (variance 1e-3 on q and v, seeds 1-5). The fit reads the measured positions
and the applied torques, with the reference as instruments (and without, for comparison).
Recorded per run: every coefficient's relative error against the plant's, and which the torques
see. Results: docs/data/water_identification.json.

    python scripts/water_identification.py [--duration 60] [--out docs/data/water_identification.json]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from hydroarm.control.learned_water import PhysicsInformedModel, fit_water
from hydroarm.model.arm.loading import load_arm
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides

RUN = {
    "task.kind": "file",
    "task.file": "examples/tasks/identification.toml",
    "task.start": "on_trajectory",
    "water.current.model": "none",
}
RUNS = {"clean": (0.0, [1]), "noisy": (1e-3, [1, 2, 3, 4, 5])}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--out", type=Path, default=Path("docs/data/water_identification.json"))
    args = parser.parse_args()
    results: dict = {"duration_s": args.duration, "runs": {}}
    for case, (noise, seeds) in RUNS.items():
        config = with_overrides(ExperimentConfig(duration=args.duration), {**RUN, "plant.noise_variance": noise})
        model = PhysicsInformedModel(load_arm(config.arm))
        truth = model.regressor.physical(model.regressor.parameters(config.water))
        for seed in seeds:
            traj = build_experiment(config, "IDMPC").run(seed=seed)
            for method, instruments in (("instrumental variables", traj.q_ref), ("least squares", None)):
                fit = fit_water(model, traj.t, traj.y[:, : model.n], traj.u, instruments=instruments)
                c = len(truth["cd"])
                seen = fit.identifiable.reshape(3, c)
                errors = {k: (fit.coefficients[k] / truth[k] - 1.0).tolist() for k in ("cd", "cm", "volume")}
                results["runs"][f"{case}, seed {seed}, {method}"] = {
                    "relative_error": errors,
                    "identifiable": {k: seen[i].tolist() for i, k in enumerate(("cd", "cm", "volume"))},
                    "residual_std_Nm": fit.residual_std.tolist(),
                }
                worst = max(abs(e) for k, i in (("cd", 0), ("cm", 1), ("volume", 2))
                            for e, s in zip(errors[k], seen[i]) if s)  # fmt: skip
                print(case, seed, method, f"largest error of a seen coefficient {100 * worst:.1f} %", flush=True)
    results["truth"] = {k: v.tolist() for k, v in truth.items()}
    args.out.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
