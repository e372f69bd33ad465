"""Memory and transfer: a water model learned on the paper task, saved, then run on a trajectory it
has never seen (examples/tasks/unseen.toml), started on that trajectory (no initial error).

PI-IDMPC learns on the paper task (10 s, seed 1, clean or noisy) and saves its model; on the
unseen trajectory (4 s, seed 2) it runs with the saved model, from its textbook prior, and with
the plant's own coefficients (the most any memory of the water can give); the IDMPC with every
classic observer and GP-IDMPC run beside it. Recorded: mean E_p over joints over
the first 2 s and after 2 s. Results: docs/data/transfer_study.json.

    python scripts/transfer_study.py [--out docs/data/transfer_study.json]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides

UNSEEN = {"task.kind": "file", "task.file": "examples/tasks/unseen.toml", "task.start": "on_trajectory"}
OBSERVERS = {
    "IDMPC": {},
    "IDMPC+TDE": {"observer.kind": "tde"},
    "IDMPC+TDE-gated": {"observer.kind": "tde", "observer.gate": True},
    "IDMPC+NDOB": {"observer.kind": "ndob"},
    "IDMPC+NDOB-gated": {"observer.kind": "ndob", "observer.gate": True},
}


def errors(experiment, seed: int) -> dict:
    traj = experiment.run(seed=seed)
    error = (traj.q - traj.q_ref) ** 2
    return {
        "Ep_mean_first_2s": float(np.mean(error[traj.t <= 2.0])),
        "Ep_mean_after_2s": float(np.mean(error[traj.t > 2.0])),
        "diverged": bool(traj.diverged),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=Path, default=Path("docs/data/transfer_study.json"))
    args = parser.parse_args()
    results: dict = {}
    for case, noise in (("clean", 0.0), ("noisy", 1e-3)):
        learn = build_experiment(with_overrides(ExperimentConfig(), {"plant.noise_variance": noise}), "PI-IDMPC")
        learn.run(seed=1)
        learner = learn.controller.controller  # behind the Kalman filter
        path = Path(tempfile.mkdtemp()) / "water.json"
        learner.save_model(path)
        unseen = with_overrides(ExperimentConfig(duration=4.0), {**UNSEEN, "plant.noise_variance": noise})
        rows = {}
        loaded = build_experiment(unseen, "PI-IDMPC")
        loaded.controller.controller.load_model(path)
        rows["PI-IDMPC, saved model"] = errors(loaded, 2)
        rows["PI-IDMPC, textbook prior"] = errors(build_experiment(unseen, "PI-IDMPC"), 2)
        # the most any memory can give: the plant's own C_d, C_m and volumes, held with 1e-4 x the prior's variance
        oracle = build_experiment(unseen, "PI-IDMPC")
        model = oracle.controller.controller.model
        model.theta = model.regressor.parameters(unseen.water)
        model.covariance = 1e-4 * model.covariance
        model.save(path.with_name("plant.json"))
        oracle.controller.controller.load_model(path.with_name("plant.json"))
        rows["PI-IDMPC, the plant's own coefficients"] = errors(oracle, 2)
        rows["GP-IDMPC"] = errors(build_experiment(unseen, "GP-IDMPC"), 2)
        for row, overrides in OBSERVERS.items():
            rows[row] = errors(build_experiment(with_overrides(unseen, overrides), "IDMPC"), 2)
        coefficients = {k: v.tolist() for k, v in learner.model.coefficients().items()}
        results[case] = {"rows": rows, "learned_coefficients": coefficients}
        for row, values in rows.items():
            print(case, row, f"{values['Ep_mean_first_2s']:.3g} {values['Ep_mean_after_2s']:.3g}", flush=True)
    args.out.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
