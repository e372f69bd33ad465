"""How far is the compiled fixed-base plant (``plant.compiled``) from the reference path?

The paper scenario (default settings, 10 s) under ``--controller`` (SMC by default): the
reference plant's closed loop, then for the compiled plant at the reference's settings and at a
fast setting (longer inner step, fewer drag points): the largest difference (rad, rad/s) of one
control step from each of the reference run's states (the local error), of its own closed loop
over the whole run, and the speed of the 1000 steps against the reference's (a ratio in the same
run; absolute times depend on the machine). The open loop under the recorded torques is no
measure: the uncontrolled arm amplifies round-off (1e-15 grows to 0.5 rad in 10 s).

    python scripts/arm_fast_accuracy.py [--controller SMC] [--duration 10]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides

FAST = {"plant.inner_step": 2.5e-3, "plant.drag_points": 3}
SETTINGS = {"compiled": {"plant.compiled": True}, "compiled_fast": {"plant.compiled": True, **FAST}}


def _local(plant, traj, period):
    """Each recorded state stepped once: (next states (K, 2n), wall time s)."""
    out = []
    start = time.perf_counter()
    for k in range(len(traj.u)):
        out.append(plant.step(traj.t[k], traj.x[k], traj.u[k], period)[0])
    return np.asarray(out), time.perf_counter() - start


def _diff(a, b, n):
    diff = np.abs(a - b)
    return {"max_abs_q_rad": float(diff[:, :n].max()), "max_abs_v_rad_s": float(diff[:, n:].max())}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--controller", default="SMC")
    parser.add_argument("--duration", type=float, default=10.0)
    args = parser.parse_args(argv)
    base = ExperimentConfig(duration=args.duration)
    reference = build_experiment(base, args.controller)
    traj = reference.run(0)
    period = base.control_period
    n = reference.plant.n
    _local(reference.plant, traj, period)  # warm up
    reference_next, reference_s = _local(reference.plant, traj, period)
    rows = {}
    for label, overrides in SETTINGS.items():
        experiment = build_experiment(with_overrides(base, overrides), args.controller)
        _local(experiment.plant, traj, period)  # compile / warm up
        local_next, seconds = _local(experiment.plant, traj, period)
        closed = experiment.run(0)
        rows[label] = {
            "settings": overrides,
            "one_step_from_reference_states": _diff(local_next, reference_next, n),
            "closed_loop_vs_reference": _diff(closed.x, traj.x, n),
            "step_speedup_vs_reference": reference_s / seconds,
        }
    print(json.dumps({"controller": args.controller, "duration_s": args.duration, "steps": len(traj.u), **rows},
                     indent=2))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
