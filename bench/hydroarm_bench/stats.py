"""Shared measuring helpers: step statistics, growth exponents, ratios, peers' presence, threads."""

from __future__ import annotations

import importlib.metadata
import importlib.util
import os
import time

import numpy as np

TARGETS = {
    "pi_idmpc_median_ms": 0.3,
    "pi_idmpc_p99_ms": 0.6,
    "gp_idmpc_median_ms": 0.3,
    "gp_idmpc_p99_ms": 0.6,
    "gp_mpc_median_ms": 1.0,
    "gp_mpc_p99_ms": 2.0,
    "speedup_vs_do_mpc": 20.0,
    "speedup_vs_cvxpy": 5.0,
    "gp_speedup_vs_sklearn": 10.0,
    "paper_scenario_wall_s": 2.0,
    "torque_agreement_nm": 1e-4,
    "gp_mean_agreement": 1e-6,
    "uvms_real_time_factor": 200.0,
    "viewer_open_s": 2.0,
    "viewer_recording_mb": 20.0,
    "env_vector_speedup": 1.6,
    "replay_all_trials_s": 60.0,
    "calibrate_4_on_6_s": 60.0,
}
PEER_PACKAGES = (
    "do-mpc",
    "casadi",
    "cvxpy",
    "osqp",
    "clarabel",
    "scikit-learn",
    "torch",
    "gpytorch",
    "linear-operator",
)
STEP_KEYS = ("median", "p90", "p99", "max")
STEP_BARS_MS = {"median": 0.3, "p99": 1.0, "max": 5.0}
"""Issue 32's bars on the flagship's whole control step (ms): the ``planner`` and ``flagship`` sections' ``meets``."""
FULL_SAMPLES = 1000  # samples per measurement in full mode (peers and scaling included)


def meets_bars(stats: dict) -> dict[str, bool]:
    """Per bar of :data:`STEP_BARS_MS`, whether the step statistics ``stats`` (ms, :func:`stats_ms`) meet it."""
    return {key: stats[key] <= limit for key, limit in STEP_BARS_MS.items()}


def stats_ms(samples_s) -> dict:
    """median / p90 / p99 / max (ms) and the count of samples given in seconds."""
    values = np.asarray(samples_s, dtype=float) * 1e3
    values = values[np.isfinite(values)]
    if values.size == 0:
        return {"median": None, "p90": None, "p99": None, "max": None, "n": 0}
    return {
        "median": float(np.median(values)),
        "p90": float(np.percentile(values, 90)),
        "p99": float(np.percentile(values, 99)),
        "max": float(values.max()),
        "n": int(values.size),
    }


def growth_exponent(sizes, times) -> float | None:
    """Least-squares slope of log(time) on log(size): time ~ size^exponent."""
    sizes = np.asarray(sizes, dtype=float)
    times = np.asarray(times, dtype=float)
    keep = np.isfinite(times) & (times > 0)
    if keep.sum() < 2:
        return None
    return float(np.polyfit(np.log(sizes[keep]), np.log(times[keep]), 1)[0])


def ratio(numerator, denominator) -> float | None:
    """numerator / denominator, or None when either is missing or the denominator is not positive."""
    if numerator is None or denominator is None or denominator <= 0:
        return None
    return float(numerator / denominator)


def version(package: str) -> str | None:
    """The installed version of a distribution, or None."""
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return None


def missing(*modules: str) -> str | None:
    """Why a peer cannot run (the modules that are not installed), or None when all are."""
    absent = [name for name in modules if importlib.util.find_spec(name) is None]
    if absent:
        return f"not installed: {', '.join(absent)} (pip install 'hydroarm[bench]')"
    return None


def time_calls(function, args_list, repeat: int = 1) -> list[float]:
    """Seconds of ``function(*args)`` for every args of ``args_list`` (``repeat`` times each)."""
    seconds = []
    for args in args_list:
        for _ in range(repeat):
            start = time.perf_counter_ns()
            function(*args)
            seconds.append((time.perf_counter_ns() - start) * 1e-9)
    return seconds


def limit_threads() -> tuple[object | None, int | None, str]:
    """Limit BLAS (and OpenMP) to one thread; returns (limiter, threads in force, how)."""
    try:
        from threadpoolctl import threadpool_info, threadpool_limits
    except ImportError:
        value = os.environ.get("OPENBLAS_NUM_THREADS") or os.environ.get("OMP_NUM_THREADS")
        return None, int(value) if value and value.isdigit() else None, "environment variables (threadpoolctl missing)"
    limiter = threadpool_limits(limits=1)
    threads = [pool.get("num_threads") for pool in threadpool_info() if pool.get("user_api") == "blas"]
    return limiter, (max(threads) if threads else 1), "threadpoolctl"
