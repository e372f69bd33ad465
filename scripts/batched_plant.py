"""The batched compiled plant's throughput: N copies of an arm stepped together, copy-steps per second.

Each count of copies (``--copies``, default 1 8 64 512) starts from the arm's task start moved by a
seeded uniform draw (0.1 rad, 0.1 rad/s) with seeded random torques within a tenth of the torque
limits held per copy, and is stepped ``--steps`` control periods of 10 ms by
:class:`hydroarm.model.arm.fast.BatchedArm` (numba's threads: every core this process may use)
after one warm-up period. Prints JSON: per count the wall time, copy-steps per second and per
CPU second, and whether every copy stayed finite. The CPU baseline of the GPU design in
docs/model.md ("A GPU path"); no JAX or Warp backend exists yet, so it runs the CPU kernel only.

    python scripts/batched_plant.py [--arm paper] [--copies 1 8 64 512] [--steps 100] [--drag-points N]
"""

from __future__ import annotations

import argparse
import json
import time

import numba
import numpy as np

from hydroarm.model.arm.fast import BatchedArm
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides

PERIOD = 0.01


def measure(arm: str, copies: int, steps: int, drag_points: int | None = None, seed: int = 0) -> dict:
    """One count of copies: ``{"copies", "wall_s", "copy_steps_per_s", "copy_steps_per_cpu_s", "finite"}``."""
    overrides = {"arm": arm, "plant.compiled": True}
    if drag_points is not None:
        overrides["plant.drag_points"] = drag_points
    experiment = build_experiment(with_overrides(ExperimentConfig(), overrides), None)
    plant, n = experiment.plant, experiment.arm.n_joints
    rng = np.random.default_rng(seed)
    x = experiment.x0 + rng.uniform(-0.1, 0.1, (copies, 2 * n))
    tau = 0.1 * np.asarray(experiment.arm.torque_limit, dtype=float) * rng.uniform(-1, 1, (copies, n))
    batch = BatchedArm(plant.fast)
    batch.step(0.0, x, tau, PERIOD, plant.inner_step)  # warm-up: compile or load, start the threads
    cpu, wall = time.process_time(), time.perf_counter()
    for k in range(steps):
        x = batch.step(k * PERIOD, x, tau, PERIOD, plant.inner_step)[0]
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return {
        "copies": copies,
        "wall_s": wall,
        "copy_steps_per_s": copies * steps / wall,
        "copy_steps_per_cpu_s": copies * steps / cpu if cpu > 0 else None,
        "finite": bool(np.all(np.isfinite(x))),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--arm", default="paper")
    parser.add_argument("--copies", type=int, nargs="+", default=[1, 8, 64, 512])
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--drag-points", type=int, default=None)
    args = parser.parse_args(argv)
    if args.steps < 1 or min(args.copies) < 1:
        parser.error("--steps and every --copies must be >= 1")
    rows = [measure(args.arm, c, args.steps, args.drag_points) for c in args.copies]
    print(json.dumps({"arm": args.arm, "threads": numba.get_num_threads(), "backend": "numba (CPU)",
                      "steps": args.steps, "rows": rows}, indent=2))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
