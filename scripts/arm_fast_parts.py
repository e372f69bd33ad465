"""What each part of the compiled fixed-base plant's evaluation costs, and the floor it sets.

One evaluation of :func:`hydroarm.model.arm.fast_kernels.evaluate` (one RK4 stage; a 10 ms
control period at 1 ms is 40 of them) is the rigid body's RNEA (forward pass with the joints'
sines and cosines, body forces, backward pass), the water's cylinders (8 Gauss points per drag
piece), the CRBA (``M + M_A``), the Cholesky solve and the disturbance's ``M q''`` pass. Each is
switched off in turn in a copy of ``evaluate`` (compiled here, not cached) and the evaluation
timed in a compiled loop of ``--reps`` calls, the variants round-robin over ``--rounds`` rounds,
each variant's fastest round kept (on a shared machine the load only adds time; the fastest
round is the closest to the part's own cost). Beside them: one empty compiled call from Python with the
step's arguments (numba's dispatch), one allocation of the step's scratch, and MuJoCo's RK4 at
1 ms (one geom per cylinder) over the same 10 ms, per call from Python as the bench times it.

``floor_vs_mujoco`` is MuJoCo's time over ``40 (rnea + water) + dispatch``: what the compiled
step would be against MuJoCo if the mass matrix, its solve and the disturbance cost nothing, so
the most any reformulation of them (ABA included: its articulated inertias are the CRBA's
transforms plus a rank-one update per body) could give without changing the water's quadrature
(which paper accuracy, 1e-12 of the reference, fixes).

    python scripts/arm_fast_parts.py [--arm paper] [--reps 500] [--rounds 40] [--out FILE.json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numba
import numpy as np

from hydroarm.model.arm import fast_kernels as kernels
from hydroarm.model.dynamics.fixed_order import cholesky_solve_into
from hydroarm.model.water.current import current_at
from hydroarm.sim.experiment import build_experiment, with_overrides

BENCH = Path(__file__).resolve().parents[1] / "bench"
VARIANTS = {  # (water, crba, cholesky, mass_times)
    "all": (True, True, True, True),
    "no_water": (False, True, True, True),
    "no_crba": (True, False, True, True),
    "no_cholesky": (True, True, False, True),
    "no_mass_times": (True, True, True, False),
    "rnea_only": (False, False, False, False),
}


@numba.njit
def _evaluate(t, q, v, tau, arm, work, out_acc, out_dist, out_drag, flags, saved):  # pragma: no cover
    """``evaluate`` (no friction, no Reynolds drag) with its parts switched by ``flags``; a
    switched-off CRBA copies ``saved`` (n, n), a switched-off solve copies the right-hand side."""
    n = q.shape[0]
    joint_acceleration, nle, water_force, rhs = work[19], work[20], work[21], work[23]
    mass, water_velocity = work[24], work[25]
    current_at(t, work[27][4], work[27][5], joint_acceleration, water_velocity)
    kernels._forward(q, v, arm, work)
    kernels._body_forces(arm, work)
    if flags[0]:
        kernels._water_wrenches(arm, water_velocity, work)
    kernels._backward(arm, work, nle, water_force, out_drag)
    if flags[1]:
        kernels.crba(arm, work, mass)
    else:
        mass[:, :] = saved
    for i in range(n):
        rhs[i] = tau[i] - nle[i] + water_force[i]
    if flags[2]:
        cholesky_solve_into(mass, rhs, out_acc)
    else:
        out_acc[:] = rhs
    if flags[3]:
        kernels.mass_times(arm, work, out_acc, out_dist)


@numba.njit
def _loop(t, x, tau, arm, flags, reps, saved):  # pragma: no cover - compiled
    """``reps`` evaluations at (t, x) under tau."""
    n = tau.shape[0]
    work = kernels.scratch(arm)
    acc, dist, drag = np.empty(n), np.empty(n), np.empty(n)
    total = 0.0
    for _ in range(reps):
        _evaluate(t, x[:n], x[n:], tau, arm, work, acc, dist, drag, flags, saved)
        total += acc[0]
    return total


@numba.njit
def _empty(t, x, tau, steps, h, arm):  # pragma: no cover - compiled
    """Nothing, with the step kernel's arguments (the dispatch's cost)."""
    return x


@numba.njit
def _scratch_loop(arm, reps):  # pragma: no cover - compiled
    """``reps`` allocations of the step's scratch."""
    total = 0
    for _ in range(reps):
        total += kernels.scratch(arm)[0].shape[0]
    return total


def _per_call_us(function, reps: int) -> float:
    """The fastest of ten rounds of ``function()``'s time (microseconds)."""
    rounds = []
    for _ in range(10):
        start = time.perf_counter_ns()
        for _ in range(reps):
            function()
        rounds.append((time.perf_counter_ns() - start) * 1e-3 / reps)
    return float(np.min(rounds))


def measure(arm_name: str, reps: int, rounds: int) -> dict:
    """The parts of ``arm_name``'s evaluation (module docstring), microseconds."""
    sys.path.insert(0, str(BENCH))
    from hydroarm_bench.arm_fast import _mujoco_stepper
    from hydroarm_bench.loop import paper_config

    config = paper_config(1.0, {"arm": arm_name})
    experiment = build_experiment(with_overrides(config, {"plant.compiled": True}), "SMC")
    fast = experiment.plant.fast
    if experiment.plant.friction.active or config.water.drag_model != "constant":
        raise SystemExit("arm_fast_parts: the variants assume no joint friction model and a constant C_d")
    n, arm = fast.n, fast.compiled
    rng = np.random.default_rng(0)
    x, tau = np.concatenate([rng.normal(0.0, 0.5, n), rng.normal(0.0, 0.3, n)]), rng.normal(0.0, 2.0, n)
    saved = fast.terms(x[:n], x[n:])[0]
    flags = {name: np.array(value) for name, value in VARIANTS.items()}
    for value in flags.values():
        _loop(0.1, x, tau, arm, value, 10, saved)
    samples = {name: [] for name in flags}
    for _ in range(rounds):
        for name, value in flags.items():
            start = time.perf_counter_ns()
            _loop(0.1, x, tau, arm, value, reps, saved)
            samples[name].append((time.perf_counter_ns() - start) * 1e-3 / reps)
    evaluation = {name: float(np.min(values)) for name, values in samples.items()}
    _empty(0.1, x, tau, 10, 1e-3, arm)
    _scratch_loop(arm, 10)
    dispatch = _per_call_us(lambda: _empty(0.1, x, tau, 10, 1e-3, arm), reps)
    start = time.perf_counter_ns()
    _scratch_loop(arm, reps)
    scratch = (time.perf_counter_ns() - start) * 1e-3 / reps  # one round: a small share
    full = evaluation["all"]
    parts = {
        "water": full - evaluation["no_water"],
        "crba": full - evaluation["no_crba"],
        "cholesky": full - evaluation["no_cholesky"],
        "mass_times": full - evaluation["no_mass_times"],
        "rnea": evaluation["rnea_only"],
    }
    out = {"evaluation_us": evaluation, "part_us": parts, "dispatch_us": dispatch, "scratch_us": scratch}
    out["share_of_evaluation"] = {name: value / full for name, value in parts.items()}
    stepper = _mujoco_stepper(experiment.arm, config.water, 1, 0.01)
    if not isinstance(stepper, str):
        stepper(0.1, x, tau)
        mujoco = _per_call_us(lambda: stepper(0.1, x, tau), 20)
        floor = 40.0 * (parts["rnea"] + parts["water"]) + dispatch
        out |= {"mujoco_rk4_1ms_segments1_us": mujoco, "step_estimate_us": 40.0 * full + dispatch + scratch}
        out |= {"floor_us": floor, "floor_vs_mujoco": mujoco / floor}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arm", default="paper")
    parser.add_argument("--reps", type=int, default=500)
    parser.add_argument("--rounds", type=int, default=40)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    stamp = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    report = {"generated": stamp, "cpus": os.cpu_count(), "load_average_start": os.getloadavg()[0]}
    report["arms"] = {name: measure(name, args.reps, args.rounds) for name in args.arm.split(",")}
    report["load_average_end"] = os.getloadavg()[0]
    text = json.dumps(report, indent=2)
    print(text)
    if args.out is not None:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
