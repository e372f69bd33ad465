"""Section 6: the floating vehicle-manipulator system (BlueROV2 Heavy + Alpha 5), one core.

Median time of one 10 ms control step of the plant (the whole system: rigid body, the arm's
water, the vehicle's water, thrusters), for the reference path (``UVMSPlant``: 1 ms RKMK4,
Pinocchio + compiled strips, 8 Gauss points), the compiled path (``FastUVMSPlant``, default
settings: 5 ms RKMK4, 3 drag points) and the compiled path at the reference's settings
(``compiled_fine``: 1 ms, 8 drag points, the same physics), the real-time factor (10 ms / median
step), and the compiled path's deviation from the reference over the same scripted run (arm
joint PD, thrusters driven by a fixed pattern, 0.2 m/s current). Target: >= 200x real time (docs/vehicle.md).
"""

from __future__ import annotations

import math
import time

import numpy as np

TARGET_REAL_TIME = 200.0
PERIOD = 0.01
GAINS_P = np.array([0.3, 0.3, 0.1, 0.002])
GAINS_D = np.array([0.05, 0.05, 0.02, 0.0003])


def _run(plant, system, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """States (steps, n_state) and step times (ns) of a scripted run."""
    x = plant.initial_state(system.neutral(q_arm=[1.5, 1.0, 1.0, 0.5]))
    nq, n = system.nq, system.n_arm
    states, times = np.empty((steps, x.shape[0])), np.empty(steps)
    for k in range(steps):
        t = k * PERIOD
        target = np.array([1.5 + 0.8 * math.sin(2.0 * t), 1.0 + 0.5 * math.sin(3.0 * t), 1.0, 0.5 * math.sin(t)])
        tau = GAINS_P * (target - x[7 : 7 + n]) - GAINS_D * x[nq + 6 : nq + 6 + n]
        u = np.concatenate([tau, 10.0 * np.sin(np.arange(8) + t)])
        start = time.perf_counter_ns()
        x, _ = plant.step(t, x, u, PERIOD)
        times[k] = time.perf_counter_ns() - start
        states[k] = x
    return states, times


def bench_uvms(quick: bool = False) -> dict:
    """The ``uvms`` section of bench.json."""
    from hydroarm.model.vehicle.fast import FastUVMSConfig, FastUVMSPlant
    from hydroarm.model.vehicle.plant import UVMSPlant
    from hydroarm.model.vehicle.system import build_uvms
    from hydroarm.model.water.morison import CurrentConfig, Water

    system = build_uvms()
    water = Water(current=CurrentConfig(model="uniform", mean=[0.2, 0.0, 0.0]))
    steps = 200 if quick else 1000
    reference = UVMSPlant(system, water)
    fast = FastUVMSPlant(system, water)
    fine_config = FastUVMSConfig(inner_step=1e-3, drag_points=water.quadrature_points)
    fine = FastUVMSPlant(system, water, fine_config)
    _run(reference, system, 5)  # warm-up: kernels load or compile
    _run(fast, system, 5)
    _run(fine, system, 5)
    ref_states, ref_times = _run(reference, system, steps)
    fast_states, fast_times = _run(fast, system, steps)
    _, fine_times = _run(fine, system, steps)
    nq = system.nq
    config = FastUVMSConfig()
    rows = {}
    for name, times in (("reference", ref_times), ("compiled", fast_times), ("compiled_fine", fine_times)):
        median_ms = float(np.median(times)) / 1e6
        rows[name] = {
            "median_step_ms": median_ms,
            "p90_step_ms": float(np.percentile(times, 90)) / 1e6,
            "real_time_factor": PERIOD * 1e3 / median_ms,
            "n": int(steps),
        }
    rows["compiled"]["settings"] = {"inner_step_s": config.inner_step, "drag_points": config.drag_points}
    rows["compiled_fine"]["settings"] = {
        "inner_step_s": fine_config.inner_step,
        "drag_points": fine_config.drag_points,
    }
    rows["reference"]["settings"] = {"inner_step_s": 1e-3, "gauss_points": water.quadrature_points}
    return {
        "system": "bluerov2_heavy + alpha5 (10 DOF, 8 wetted cylinders, 8 thrusters), 0.2 m/s current",
        "control_period_s": PERIOD,
        **rows,
        "median_step_ms": rows["compiled"]["median_step_ms"],
        "real_time_factor": rows["compiled"]["real_time_factor"],
        "target_real_time_factor": TARGET_REAL_TIME,
        "target_met": rows["compiled"]["real_time_factor"] >= TARGET_REAL_TIME,
        "compiled_vs_reference": {
            "duration_s": steps * PERIOD,
            "max_position_error_m": float(np.max(np.abs(fast_states[:, :3] - ref_states[:, :3]))),
            "max_arm_angle_error_rad": float(np.max(np.abs(fast_states[:, 7:nq] - ref_states[:, 7:nq]))),
        },
    }


def render_uvms(section: dict) -> str:
    """The section's table for bench.md."""
    lines = [
        "",
        "## 6. Vehicle-manipulator system (UVMS)",
        "",
        section["system"] + ".",
        "",
        "| path | settings | median step (ms) | p90 (ms) | real-time factor |",
        "|---|---|---:|---:|---:|",
    ]
    for name in ("reference", "compiled", "compiled_fine"):
        row = section.get(name)  # compiled_fine: not in a bench.json written before it was added
        if row is None:
            continue
        settings = ", ".join(f"{k} {v}" for k, v in row["settings"].items())
        lines.append(
            f"| {name} | {settings} | {row['median_step_ms']:.4f} | {row['p90_step_ms']:.4f} | "
            f"{row['real_time_factor']:.0f}x |"
        )
    check = section["compiled_vs_reference"]
    lines += [
        "",
        f"Target >= {section['target_real_time_factor']:.0f}x real time: "
        f"{'met' if section['target_met'] else 'missed'}. Compiled vs reference over {check['duration_s']:.0f} s: "
        f"base position {check['max_position_error_m']:.1e} m, arm angles {check['max_arm_angle_error_rad']:.1e} rad.",
        "",
    ]
    return "\n".join(lines)
