"""The bench.json document: assembled from the sections, targets checked, and validated."""

from __future__ import annotations

import math
import os
import platform
from pathlib import Path

import numpy as np

from hydroarm_bench.stats import PEER_PACKAGES, STEP_KEYS, TARGETS, version

SCHEMA = 1


def json_default(value):
    """``json.dumps(default=...)`` for NumPy scalars and arrays."""
    if isinstance(value, (np.generic, np.bool_)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def _step(row: dict) -> dict:
    return {key: row[key] for key in STEP_KEYS}


def _peer_speedup(section: dict, label: str, key: str):
    peer = section["peers"].get(label, {})
    if not peer.get("available"):
        return None, peer.get("reason", "not run")
    return peer.get(key), None


def _cpu_model() -> str:
    """The CPU's model name (Linux: /proc/cpuinfo's ``model name``; elsewhere platform's), so a
    bench.json says which processor its times are of: they differ by ~1.5x between the x86-64
    machines we run on."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _machine(load_start) -> dict:
    import numba
    import scipy

    return {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_model": _cpu_model(),
        "cpu_count": os.cpu_count(),
        "load_average_start": list(load_start),
        "load_average_end": list(os.getloadavg()),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "numba": numba.__version__,
        "pinocchio": version("pin"),
        "peers": {name: version(name) for name in PEER_PACKAGES},
    }


def assemble(quick, blas_threads, how, load_start, breakdown, throughput, mpc_peers, gp_peers, plant, scaling) -> dict:
    """The bench.json document (without ``profile`` and ``suite_wall_s``, added by the driver)."""
    do_mpc, do_mpc_reason = _peer_speedup(mpc_peers, "do_mpc_ipopt", "speedup_full_step")
    osqp, osqp_reason = _peer_speedup(mpc_peers, "cvxpy_osqp", "speedup_full_step")
    clarabel, clarabel_reason = _peer_speedup(mpc_peers, "cvxpy_clarabel", "speedup_full_step")
    cvxpy_values = [v for v in (osqp, clarabel) if v is not None]
    sklearn, sklearn_reason = _peer_speedup(gp_peers, "sklearn", "speedup")
    gpytorch, gpytorch_reason = _peer_speedup(gp_peers, "gpytorch", "speedup")
    report = {
        "schema": SCHEMA,
        "quick": quick,
        "pi_idmpc_step_ms": _step(breakdown["PI-IDMPC"]["total"]),
        "gp_idmpc_step_ms": _step(breakdown["GP-IDMPC"]["total"]),
        "gp_mpc_step_ms": _step(breakdown["GP-MPC"]["total"]),
        "mpc_step_ms": _step(breakdown["MPC"]["total"]),
        "smc_step_ms": _step(breakdown["SMC"]["total"]),
        "speedup_vs_do_mpc": do_mpc,
        "speedup_vs_cvxpy": min(cvxpy_values) if cvxpy_values else None,
        "speedup_vs_cvxpy_osqp": osqp,
        "speedup_vs_cvxpy_clarabel": clarabel,
        "gp_speedup_vs_sklearn": sklearn,
        "gp_speedup_vs_gpytorch": gpytorch,
        "paper_scenario_wall_s": throughput["GP-MPC"]["wall_s"],
        "paper_scenario_sim_s_per_wall_s": throughput["GP-MPC"]["simulated_s_per_wall_s"],
        "blas_threads": blas_threads,
        "blas_threads_set_by": how,
        "breakdown": breakdown,
        "peers": {"mpc": mpc_peers, "gp": gp_peers, "plant": plant},
        "scaling": scaling,
        "throughput": throughput,
        "machine": _machine(load_start),
        "targets": TARGETS,
    }
    for key, reason in (
        ("speedup_vs_do_mpc", do_mpc_reason),
        ("speedup_vs_cvxpy", None if cvxpy_values else (osqp_reason or clarabel_reason)),
        ("gp_speedup_vs_sklearn", sklearn_reason),
        ("gp_speedup_vs_gpytorch", gpytorch_reason),
    ):
        if report[key] is None:
            report[f"{key}_reason"] = reason or "not run"
    report["target_status"] = target_status(report)
    return report


def target_status(report: dict) -> dict:
    """Each target of :data:`TARGETS` against what was measured (``met``: None when not measured)."""

    def check(value, target, larger_is_better):
        if value is None:
            return {"measured": None, "target": target, "met": None}
        met = value >= target if larger_is_better else value <= target
        return {"measured": value, "target": target, "met": bool(met)}

    mpc_peers = report["peers"]["mpc"]["peers"]
    agreements = [p["first_torque_max_abs_diff_nm"] for p in mpc_peers.values() if p.get("available")]
    sklearn = report["peers"]["gp"]["peers"].get("sklearn", {})
    return {
        "pi_idmpc_median_ms": check(report["pi_idmpc_step_ms"]["median"], TARGETS["pi_idmpc_median_ms"], False),
        "pi_idmpc_p99_ms": check(report["pi_idmpc_step_ms"]["p99"], TARGETS["pi_idmpc_p99_ms"], False),
        "gp_idmpc_median_ms": check(report["gp_idmpc_step_ms"]["median"], TARGETS["gp_idmpc_median_ms"], False),
        "gp_idmpc_p99_ms": check(report["gp_idmpc_step_ms"]["p99"], TARGETS["gp_idmpc_p99_ms"], False),
        "gp_mpc_median_ms": check(report["gp_mpc_step_ms"]["median"], TARGETS["gp_mpc_median_ms"], False),
        "gp_mpc_p99_ms": check(report["gp_mpc_step_ms"]["p99"], TARGETS["gp_mpc_p99_ms"], False),
        "speedup_vs_do_mpc": check(report["speedup_vs_do_mpc"], TARGETS["speedup_vs_do_mpc"], True),
        "speedup_vs_cvxpy": check(report["speedup_vs_cvxpy"], TARGETS["speedup_vs_cvxpy"], True),
        "mpc_torque_agreement_nm": check(
            max(agreements) if agreements else None, TARGETS["torque_agreement_nm"], False
        ),
        "gp_speedup_vs_sklearn": check(report["gp_speedup_vs_sklearn"], TARGETS["gp_speedup_vs_sklearn"], True),
        "gp_mean_agreement": check(sklearn.get("mean_at_our_theta_max_abs_diff"), TARGETS["gp_mean_agreement"], False),
        "paper_scenario_wall_s": check(report["paper_scenario_wall_s"], TARGETS["paper_scenario_wall_s"], False),
        # the sections added after assemble(): not measured until they are there (or when skipped)
        "uvms_real_time_factor": check(
            report.get("uvms", {}).get("real_time_factor"), TARGETS["uvms_real_time_factor"], True
        ),
        "viewer_open_s": check(
            report.get("viewer", {}).get("open_to_drawn_s", {}).get("median"), TARGETS["viewer_open_s"], False
        ),
        "viewer_recording_mb": check(
            report["viewer"]["html_bytes"] / 1e6 if "html_bytes" in report.get("viewer", {}) else None,
            TARGETS["viewer_recording_mb"],
            False,
        ),
        "env_vector_speedup": check(report.get("envs", {}).get("speedup"), TARGETS["env_vector_speedup"], True),
        # the whole Hinsdale dataset (measured only where it is: HYDROARM_HINSDALE_TRIALS)
        "replay_all_trials_s": check(
            (report.get("replay") or {}).get("full", {}).get("replay_all_s"), TARGETS["replay_all_trials_s"], False
        ),
        "calibrate_4_on_6_s": check(
            (report.get("replay") or {}).get("full", {}).get("calibrate_s"), TARGETS["calibrate_4_on_6_s"], False
        ),
    }


def validate_report(report: dict) -> list[str]:
    """Shape and sanity problems of a bench.json document (empty list: valid). No timing thresholds."""
    problems = []
    for key in ("gp_idmpc_step_ms", "gp_mpc_step_ms", "mpc_step_ms", "smc_step_ms"):
        row = report.get(key)
        if not isinstance(row, dict) or set(STEP_KEYS) - set(row):
            problems.append(f"{key}: missing median/p90/p99/max")
            continue
        values = [row[k] for k in STEP_KEYS]
        if not all(isinstance(v, (int, float)) and v > 0 and math.isfinite(v) for v in values):
            problems.append(f"{key}: times must be positive and finite: {row}")
        elif not (row["median"] <= row["p90"] <= row["p99"] <= row["max"]):
            problems.append(f"{key}: percentiles out of order: {row}")
    for key in ("speedup_vs_do_mpc", "speedup_vs_cvxpy", "gp_speedup_vs_sklearn"):
        if key not in report:
            problems.append(f"{key}: missing")
        elif report[key] is None:
            if not report.get(f"{key}_reason"):
                problems.append(f"{key}: null without {key}_reason")
        elif not (isinstance(report[key], (int, float)) and report[key] > 0):
            problems.append(f"{key}: must be a positive number or null")
    wall = report.get("paper_scenario_wall_s")
    if not (isinstance(wall, (int, float)) and wall > 0):
        problems.append("paper_scenario_wall_s: must be positive")
    threads = report.get("blas_threads")
    if not (isinstance(threads, int) and threads >= 1) and not (threads is None and report.get("blas_threads_set_by")):
        problems.append("blas_threads: must be an int >= 1 (or null with blas_threads_set_by saying why)")
    parts = report.get("breakdown", {}).get("GP-MPC", {})
    total = parts.get("total", {})
    for key, row in parts.items():
        if key == "total":
            continue
        for stat in STEP_KEYS:
            if row.get(stat) is not None and total.get(stat) is not None and row[stat] > total[stat] * (1 + 1e-9):
                problems.append(f"GP-MPC {key} {stat} {row[stat]} exceeds total {total[stat]}")
    return problems
