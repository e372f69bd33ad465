"""Timing of hydroarm.control.gp.SlidingWindowGP: window update and whole GP control step.

1. ``window_update``: with fixed hyperparameters (hyper_steps = 0), the cost of
   ``add(x, y)`` (the window slides by one sample) followed by ``predict(x*)``,
   either with a full refactorisation of the new window (batched Cholesky +
   triangular inverse, O(N^3)) or with the O(N^2) rank update of the inverse
   Cholesky factor. ``max_abs_diff`` compares the incremental factor, after all
   repetitions (no periodic refactorisation), with a fresh full factorisation.
2. ``control_step``: N = 10 (the paper's N_train), 6 outputs, d = 12 and 24:
   ``add`` + ``update_hyperparameters`` + ``predict`` per 10 ms control step,
   for several hyper_steps, on a smooth arm-like trajectory.

Medians of time.perf_counter_ns over >= 1000 repetitions, BLAS limited to one
thread (threadpoolctl if available, else environment variables set before
NumPy is imported). Prints one JSON document.

Run: PYTHONPATH=src python bench/gp_window_update.py [--reps 1000] [--quick]
"""

from __future__ import annotations

import os

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from hydroarm.control import gp as gp_module  # noqa: E402
from hydroarm.control.gp import GPConfig, SlidingWindowGP  # noqa: E402

try:
    from threadpoolctl import threadpool_limits
except ImportError:  # environment variables above still apply
    threadpool_limits = None

CONTROL_PERIOD_S = 0.01
N_OUTPUTS = 6


def arm_like_stream(n_steps: int, n_inputs: int, seed: int = 0):
    """Smooth inputs (angles ~ +-5 rad, velocities ~ +-10 rad/s) and torque-like targets."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_steps)[:, None] * CONTROL_PERIOD_S
    omega = rng.uniform(0.5, 2.0, n_inputs)
    phase = rng.uniform(0, 2 * np.pi, n_inputs)
    amplitude = np.where(np.arange(n_inputs) < n_inputs // 2, 3.0, 8.0)
    X = amplitude * np.sin(omega * t + phase)
    mixing = rng.normal(size=(n_inputs, N_OUTPUTS))
    Y = 100.0 * np.tanh(X @ mixing / n_inputs) + 50.0 * np.sin(X[:, :N_OUTPUTS])
    return X, Y


def time_window_update(window: int, n_inputs: int, incremental: bool, reps: int) -> dict:
    config = GPConfig(
        window=window,
        hyper_steps=0,
        incremental_min_window=2 if incremental else 10**9,
        refactor_every=10**9,
        theta0=tuple([100.0, 1.0] + [3.0] * n_inputs),
    )
    gp = SlidingWindowGP(n_inputs, N_OUTPUTS, config)
    X, Y = arm_like_stream(window + reps + 2, n_inputs)
    for k in range(window):
        gp.update(X[k], Y[k])
    gp.predict(X[window])  # factorise the first full window
    times = np.empty(reps)
    for i, k in enumerate(range(window, window + reps)):
        start = time.perf_counter_ns()
        gp.update(X[k], Y[k])
        gp.predict(X[k + 1])
        times[i] = time.perf_counter_ns() - start
    linv = gp._linv.copy()
    gp._invalidate_factor()
    gp.predict(X[window + reps])
    return {
        "median_us": float(np.median(times) / 1e3),
        "max_abs_diff_vs_fresh": float(np.max(np.abs(linv - gp._linv))),
        "max_abs_linv": float(np.max(np.abs(gp._linv))),
        "n_incremental_updates": gp.stats.n_incremental_updates,
    }


def time_control_step(n_inputs: int, hyper_steps: int, max_step_halvings: int, reps: int, warmup: int = 200) -> dict:
    config = GPConfig(hyper_steps=hyper_steps, max_step_halvings=max_step_halvings)
    gp = SlidingWindowGP(n_inputs, N_OUTPUTS, config)
    X, Y = arm_like_stream(warmup + reps + 2, n_inputs, seed=1)
    for k in range(1, warmup):
        gp.update(X[k - 1], Y[k - 1])
        gp.update_hyperparameters()
        gp.predict(X[k])
    total = np.empty(reps)
    update_predict = np.empty(reps)
    for i, k in enumerate(range(warmup, warmup + reps)):
        start = time.perf_counter_ns()
        gp.update(X[k - 1], Y[k - 1])
        middle = time.perf_counter_ns()
        gp.update_hyperparameters()
        gp.predict(X[k])
        end = time.perf_counter_ns()
        total[i] = end - start
        update_predict[i] = end - middle
    return {
        "n_inputs": n_inputs,
        "hyper_steps": hyper_steps,
        "max_step_halvings": max_step_halvings,
        "add_update_predict_median_us": float(np.median(total) / 1e3),
        "update_predict_median_us": float(np.median(update_predict) / 1e3),
        "add_update_predict_p90_us": float(np.percentile(total, 90) / 1e3),
        "stats": gp.stats.as_dict(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=1000, help="repetitions per measurement (>= 1000 for the record)")
    parser.add_argument("--quick", action="store_true", help="fewer sizes (smoke test)")
    args = parser.parse_args()
    windows = (10, 50) if args.quick else (10, 20, 50, 100, 200)
    n_inputs_window = 12

    limiter = threadpool_limits(limits=1) if threadpool_limits is not None else None
    try:
        window_rows = []
        for window in windows:
            full = time_window_update(window, n_inputs_window, incremental=False, reps=args.reps)
            incremental = time_window_update(window, n_inputs_window, incremental=True, reps=args.reps)
            window_rows.append(
                {
                    "N": window,
                    "full_refactorisation_us": round(full["median_us"], 1),
                    "incremental_us": round(incremental["median_us"], 1),
                    "full_over_incremental": round(full["median_us"] / incremental["median_us"], 2),
                    "incremental_max_abs_diff_vs_fresh": incremental["max_abs_diff_vs_fresh"],
                    "max_abs_linv": incremental["max_abs_linv"],
                }
            )
        default_halvings = GPConfig().max_step_halvings
        step_settings = [(0, 0), (1, 0), (1, default_halvings), (2, default_halvings), (3, default_halvings)]
        step_rows = [
            time_control_step(n_inputs, hyper_steps, halvings, args.reps)
            for n_inputs in (12, 24)
            for hyper_steps, halvings in step_settings
        ]
    finally:
        if limiter is not None:
            limiter.unregister()

    report = {
        "what": "hydroarm.control.gp SlidingWindowGP timings (median microseconds)",
        "machine": {
            "python": platform.python_version(),
            "numpy": np.__version__,
            "processor": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(),
            "blas_threads": 1,
            "threadpoolctl": threadpool_limits is not None,
        },
        "reps": args.reps,
        "window_update": {
            "setting": f"add + predict with fixed theta, {N_OUTPUTS} outputs, d = {n_inputs_window}",
            "default_incremental_min_window": GPConfig().incremental_min_window,
            "rows": window_rows,
        },
        "control_step": {
            "setting": f"N = {GPConfig().window}, {N_OUTPUTS} outputs, default GPConfig but hyper_steps/halvings",
            "rows": step_rows,
        },
        "module": gp_module.__name__,
    }
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
