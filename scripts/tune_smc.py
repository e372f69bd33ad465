"""Grid search of the sliding-mode baseline's gains on the paper task (true plant).

Scores each gain set by the mean E_p over joints, averaged over a clean run and
a noisy run (variance 0.001, seed 0), so the baseline is tuned for both tables.
``--on land`` tunes on the dry arm (the nominal model, as the paper's premise
"tuned once on land" has every controller); ``--on water`` on the true plant
(an oracle tuning no real controller could do).
Usage: python scripts/tune_smc.py --on land|water [--out FILE]
"""

from __future__ import annotations

import argparse
import itertools
import json
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

import hydroarm
from hydroarm.control.smc import SlidingModeController, SMCConfig
from hydroarm.model.arm.plant import PlantConfig
from hydroarm.sim.runner import run_closed_loop, tracking_metrics


def score(args: tuple[str, tuple[float, float, float, float]]) -> dict:
    where, (slope, switching, layer, linear) = args
    arm = hydroarm.load_arm("paper")
    config = SMCConfig(surface_slope=slope, switching_gain=switching, boundary_layer=layer, linear_gain=linear)
    result = {"surface_slope": slope, "switching_gain": switching, "boundary_layer": layer, "linear_gain": linear}
    for label, variance in (("clean", 0.0), ("noisy", 0.001)):
        water = hydroarm.Water() if where == "water" else hydroarm.Water().off()
        plant = hydroarm.UnderwaterPlant(arm, water, PlantConfig(noise_variance=variance))
        traj = run_closed_loop(plant, SlidingModeController(arm, config), hydroarm.paper_reference(), 10.0, seed=0)
        result[label] = float(np.mean(tracking_metrics(traj)["Ep"]))
    result["score"] = 0.5 * (result["clean"] + result["noisy"])
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--on", choices=("land", "water"), default="land")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    out = args.out or Path(f"docs/data/smc_tuning_{args.on}.json")
    grid = list(itertools.product([10.0, 20.0, 40.0], [50.0, 200.0, 800.0], [0.5, 2.0], [0.0, 10.0, 30.0]))
    with ProcessPoolExecutor(max_workers=2) as pool:
        results = sorted(pool.map(score, [(args.on, gains) for gains in grid]), key=lambda r: r["score"])
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1))
    for row in results[:8]:
        print(row)


if __name__ == "__main__":
    main()
