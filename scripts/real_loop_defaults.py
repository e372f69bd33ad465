"""The real loop on default settings (issue 32): does each ID-MPC survive a 16-bit encoder, one
period of delay and the published friction with nothing hand-set?

For each arm (the paper arm, ur5, alpha5 and the 7-joint arm of examples/urdf/iiwa14.urdf) and
each of GP-IDMPC, PI-IDMPC and IDMPC, two 10 s runs of the arm's task (seed 0):

* the real loop: exactly ``hydroarm run --controller C --arm A --set sensor.velocity=differenced
  --set sensor.resolution=9.5874e-05 --set sensor.delay=1 --set friction.scale=1``, every other
  setting at its default (the filter's kind and sigma_a^2 follow the sensor: docs/robustness.md);
* the ideal loop: the same with no real-loop setting (q and v measured, no delay, no friction).

Per row: diverged, mean E_p over joints and samples (rad^2) in each loop and their ratio (the
issue's bar: at most 1.5). Writes ``--out`` (JSON) and the Markdown table beside it (``.md``),
which docs/robustness.md quotes (tests/test_doc_figures.py ties them).

Usage: python scripts/real_loop_defaults.py [--out docs/data/real_loop_defaults.json] [--workers 2]
[--loops real] (``--loops real``: rerun the real loops only, keeping the file's ideal-loop runs)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides

ARMS: dict[str, str] = {
    "paper": "paper",
    "ur5": "ur5",
    "alpha5": "alpha5",
    "iiwa14 (7 joints)": "examples/urdf/iiwa14.urdf",
}
"""Row label -> the arm (built-in name, or a path relative to the repository root)."""

CONTROLLERS = ("GP-IDMPC", "PI-IDMPC", "IDMPC")
REAL_LOOP: dict[str, object] = {
    "sensor.velocity": "differenced",
    "sensor.resolution": 9.5874e-05,  # rad per count: 2 pi / 2^16, a 16-bit encoder
    "sensor.delay": 1,
    "friction.scale": 1.0,
}
"""The issue's command's four settings; nothing else is set."""

BAR = 1.5
"""The issue's bar on E_p(real loop) / E_p(ideal loop)."""

ROOT = Path(__file__).resolve().parents[1]


def run(task: tuple[str, str, str]) -> dict:
    """One run: ``(arm label, controller, "real" or "ideal")``."""
    label, controller, loop = task
    arm = ARMS[label]
    arm = str(ROOT / arm) if arm.endswith(".urdf") else arm
    config = with_overrides(ExperimentConfig(arm=arm), REAL_LOOP if loop == "real" else {})
    experiment = build_experiment(config, controller)
    start = time.perf_counter()
    traj = experiment.run(0)
    wall = time.perf_counter() - start
    finished = not traj.meta["stopped"] and len(traj.t) == int(round(config.duration / config.control_period))
    error = traj.q_ref - traj.q
    return {
        "arm": label,
        "controller": controller,
        "loop": loop,
        "estimator": getattr(experiment.controller, "name", controller),
        "acceleration_variance": getattr(getattr(experiment.controller, "kalman", None), "acceleration_variance", None),
        "diverged": bool(traj.diverged),
        "diverged_at_s": traj.meta.get("diverged_at_s"),
        "Ep": float(np.mean(error**2)),
        "finished": finished,
        "wall_s": wall,
    }


def rows(results: list[dict]) -> list[dict]:
    """One row per arm and controller: the real loop against the ideal one."""
    by = {(r["arm"], r["controller"], r["loop"]): r for r in results}
    out = []
    for label in ARMS:
        for controller in CONTROLLERS:
            real, ideal = by[(label, controller, "real")], by[(label, controller, "ideal")]
            ratio = real["Ep"] / ideal["Ep"] if real["finished"] and ideal["finished"] else math.nan
            out.append(
                {
                    "arm": label,
                    "controller": controller,
                    "diverged": real["diverged"] or not real["finished"],
                    "Ep_real": real["Ep"],
                    "Ep_ideal": ideal["Ep"],
                    "ratio": ratio,
                    "within_bar": bool(not real["diverged"] and real["finished"] and ratio <= BAR),
                    "acceleration_variance": real["acceleration_variance"],
                }
            )
    return out


def table(table_rows: list[dict]) -> str:
    lines = [
        "| arm | controller | diverged | E_p real loop (rad^2) | E_p ideal loop (rad^2) | real / ideal |",
        "|---|---|---|---|---|---|",
    ]
    for row in table_rows:
        lines.append(
            f"| {row['arm']} | {row['controller']} | {'yes' if row['diverged'] else 'no'} | "
            f"{row['Ep_real']:.4f} | {row['Ep_ideal']:.4f} | {row['ratio']:.2f} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "data" / "real_loop_defaults.json")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--loops", nargs="*", default=["real", "ideal"], help="run only these loops and keep --out's runs of the others"
    )
    args = parser.parse_args()
    todo = [(label, c, loop) for label in ARMS for c in CONTROLLERS for loop in ("real", "ideal") if loop in args.loops]
    start = time.perf_counter()
    results = []
    if set(args.loops) != {"real", "ideal"}:  # merge: the stored runs of the other loop
        results = [r for r in json.loads(args.out.read_text())["runs"] if r["loop"] not in args.loops]
    with ProcessPoolExecutor(args.workers) as pool:
        for k, result in enumerate(pool.map(run, todo), 1):
            results.append(result)
            print(f"[{k}/{len(todo)}] {result['arm']} {result['controller']} {result['loop']}: "
                  f"Ep={result['Ep']:.4g} diverged={result['diverged']}", flush=True)  # fmt: skip
    table_rows = rows(results)
    payload = {
        "command": "hydroarm run --controller C --arm A " + " ".join(f"--set {k}={v}" for k, v in REAL_LOOP.items()),
        "bar": BAR,
        "rows": table_rows,
        "runs": results,
        "wall_time_s": time.perf_counter() - start,
        "loops_run": args.loops,
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(payload, indent=1) + "\n")
    args.out.with_suffix(".md").write_text(table(table_rows))
    print(table(table_rows))


if __name__ == "__main__":
    main()
