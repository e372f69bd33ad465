"""Where does the compiled fixed-base plant's control step (``plant.compiled``) spend its time?

The paper scenario's plant (``--arm`` overridden), one 10 ms control step from the states of
its SMC closed loop, timed round-robin (each state through every variant in turn, so that a load
change on a shared machine hits them alike) against MuJoCo stepping the same arm (RK4, 1 ms, one
geom per cylinder; skipped without mujoco):

* ``full``: the paper-accuracy step (1 ms RK4, the water's 8 Gauss points);
* ``dry``: the same arm with no water at all (the rigid body's share: RNEA + CRBA + Cholesky +
  the disturbance's M q'' pass, 40 evaluations);
* ``no_drag``: the water without the Morison drag (the strips' Gauss points' share);
* ``drag_points3``: 3 Gauss points per drag piece;
* ``one_rk4_step``: one 1 ms RK4 step instead of ten (with ``full``: the per-call cost, scratch
  allocation and dispatch, ``(10 one - full) / 9``).

Medians in microseconds and their ratios to ``full``; the whole control period is one compiled
call in every variant. Absolute times depend on the machine and its load; the ratios are what
this measures.

    python scripts/arm_fast_profile.py [--arm paper] [--states 300] [--rounds 3]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from hydroarm.model.arm.fast import FastArmDynamics
from hydroarm.model.arm.fast_kernels import step_kernel
from hydroarm.sim.experiment import build_experiment, with_overrides

BENCH = Path(__file__).resolve().parents[1] / "bench"


def _stepper(dynamics: FastArmDynamics, period: float, inner: float):
    """(t, x, u) -> one control step of ``dynamics``."""
    return lambda t, x, u: dynamics.step(t, x, u, period, inner)


def _variants(experiment) -> dict:
    """The timed functions (t, x, u) -> anything, by name."""
    plant, arm = experiment.plant, experiment.arm
    fast, water = plant.fast, plant.fast.water
    uniform, friction = float(plant.config.friction), plant.friction
    dynamics = {
        "full": fast,
        "dry": FastArmDynamics(arm, water.off(), uniform, friction),
        "no_drag": FastArmDynamics(arm, water.model_copy(update={"drag": False}), uniform, friction),
        "drag_points3": FastArmDynamics(arm, water, uniform, friction, drag_points=3),
    }
    period, inner = experiment.control_period, plant.inner_step
    paths = {name: _stepper(d, period, inner) for name, d in dynamics.items()}
    paths["one_rk4_step"] = lambda t, x, u: step_kernel(t, x, u, 1, inner, fast.compiled)
    sys.path.insert(0, str(BENCH))
    from hydroarm_bench.arm_fast import _mujoco_stepper

    stepper = _mujoco_stepper(arm, water, 1, period)
    if not isinstance(stepper, str):
        paths["mujoco_rk4_1ms_segments1"] = stepper
    return paths


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arm", default="paper")
    parser.add_argument("--states", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    sys.path.insert(0, str(BENCH))
    from hydroarm_bench.loop import paper_config

    config = paper_config(10.0, {"arm": args.arm})
    traj = build_experiment(config, "SMC").run(0)
    experiment = build_experiment(with_overrides(config, {"plant.compiled": True}), "SMC")
    rows = np.linspace(0, len(traj.u) - 1, min(args.states, len(traj.u))).astype(int)
    states = [(float(traj.t[k]), np.ascontiguousarray(traj.x[k]), np.ascontiguousarray(traj.u[k])) for k in rows]
    paths = _variants(experiment)
    for t, x, u in states[:20]:  # warm-up: numba's caches, MuJoCo's first steps
        for function in paths.values():
            function(t, x, u)
    seconds = {name: [] for name in paths}
    for _ in range(args.rounds):
        for t, x, u in states:
            for name, function in paths.items():
                start = time.perf_counter_ns()
                function(t, x, u)
                seconds[name].append((time.perf_counter_ns() - start) * 1e-3)
    medians = {name: float(np.median(values)) for name, values in seconds.items()}
    full = medians["full"]
    report = {
        "arm": args.arm,
        "median_us": medians,
        "share_of_full": {name: value / full for name, value in medians.items()},
        "per_call_us": (10.0 * medians["one_rk4_step"] - full) / 9.0,
    }
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
