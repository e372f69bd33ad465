"""Section 2d: the compiled fixed-base plant (``plant.compiled``) against the reference path and MuJoCo.

For the paper arm and Alpha 5 (the paper scenario's settings, ``arm`` overridden): one 10 ms
control step of the plant from the states of the arm's SMC closed loop, timed round-robin (each
state through every path in turn, so that a load change on a shared machine hits them alike):

* ``reference``: :meth:`UnderwaterPlant.step` (1 ms RK4, 8 Gauss points; three Pinocchio calls
  per RK4 stage and a compiled stage kernel), what every run uses by default;
* ``compiled``: ``plant.compiled = true`` at the reference's settings (its numbers to ~1e-14);
* ``compiled_fast``: ``plant.inner_step = 2.5e-3``, ``plant.drag_points = 3``;
* ``mujoco_rk4_1ms_segments{1,8}``: MuJoCo stepping the same arm (hydroarm's own MJCF export,
  :func:`hydroarm.model.water.mujoco_check.arm_to_mjcf`: the Pinocchio inertias and joints, each
  wetted cylinder as 1 or 8 geoms under MuJoCo's ellipsoid fluid model, gravity on) with its RK4
  integrator at 1 ms: ten ``mj_step`` per control step (skipped with a reason without mujoco);
* ``batched_64``: 64 copies of the compiled step in one ``BatchedArm`` call (numba threads:
  every core), against 64 single compiled steps.

Target: the compiled paper-accuracy step at least 2x faster than MuJoCo's RK4 at 1 ms (the
cheaper, 1-geom MuJoCo model). Also the largest state difference of one step, compiled vs
reference, over the states timed, and the 10 s SMC closed loop of the compiled plant and of the
fast setting against the reference's run (largest state differences; the run's wall time against
the reference's, the controller included).
"""

from __future__ import annotations

import time

import numpy as np

from hydroarm_bench.stats import ratio, stats_ms

TARGET_VS_MUJOCO = 2.0
FAST = {"plant.inner_step": 2.5e-3, "plant.drag_points": 3}
COPIES = 64


def _mujoco_stepper(arm, water, segments: int, period: float):
    """A function (t, x, tau) -> x_next stepping MuJoCo's model of ``arm`` over ``period``, or
    a string saying why there is none."""
    try:
        import mujoco
    except ImportError:
        return "mujoco not installed (pip install 'hydroarm[mujoco]')"
    from hydroarm.model.water.mujoco_check import arm_to_mjcf

    gravity = " ".join(f"{g:.17g}" for g in arm.model.gravity.linear)
    xml = arm_to_mjcf(arm, water, segments=segments)
    xml = xml.replace('gravity="0 0 0" integrator="Euler"', f'gravity="{gravity}" integrator="RK4" timestep="0.001"')
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    n = arm.n_joints
    steps = int(round(period / model.opt.timestep))

    def step(t, x, tau):
        data.time = t
        data.qpos[:] = x[:n]
        data.qvel[:] = x[n:]
        data.qfrc_applied[:] = tau
        for _ in range(steps):
            mujoco.mj_step(model, data)
        return np.concatenate([data.qpos, data.qvel])

    return step


def _round_robin(paths: dict, states: list) -> dict:
    """Seconds per call of every path over ``states``, interleaved state by state."""
    seconds = {name: [] for name in paths}
    for t, x, u in states:
        for name, function in paths.items():
            start = time.perf_counter_ns()
            function(t, x, u)
            seconds[name].append((time.perf_counter_ns() - start) * 1e-9)
    return seconds


ARMS = ("paper", "alpha5")


def _closed_loop(config, controller: str, overrides: dict, reference) -> dict:
    """The 10 s closed loop with ``overrides`` against the reference's run ``reference``: the largest
    state differences and the wall time of the run against the reference's (same process)."""
    from hydroarm.sim.experiment import build_experiment, with_overrides

    experiment = build_experiment(with_overrides(config, overrides), controller)
    experiment.run(0)  # warm-up (compiles or loads the kernels)
    start = time.perf_counter()
    traj = experiment.run(0)
    wall = time.perf_counter() - start
    n = experiment.plant.n
    diff = np.abs(traj.x - reference.x)
    return {"max_abs_q_rad": float(diff[:, :n].max()), "max_abs_v_rad_s": float(diff[:, n:].max()), "run_wall_s": wall}


def _bench_arm(arm_name: str, quick: bool) -> dict:
    """One arm's row: its SMC closed loop's states stepped by every path, round-robin."""
    from hydroarm.sim.experiment import build_experiment, with_overrides
    from hydroarm_bench.loop import paper_config

    config = paper_config(10.0, {"arm": arm_name})
    reference = build_experiment(config, "SMC")
    arm, plant = reference.arm, reference.plant
    reference.run(0)  # warm-up
    start = time.perf_counter()
    traj = reference.run(0)
    reference_wall = time.perf_counter() - start
    period = config.control_period
    count = 200 if quick else 1000
    rows = np.linspace(0, len(traj.u) - 1, min(count, len(traj.u))).astype(int)
    states = [(float(traj.t[k]), traj.x[k], traj.u[k]) for k in rows]
    compiled = build_experiment(with_overrides(config, {"plant.compiled": True}), "SMC").plant
    fast = build_experiment(with_overrides(config, {"plant.compiled": True, **FAST}), "SMC").plant
    paths = {
        "reference": lambda t, x, u: plant.step(t, x, u, period),
        "compiled": lambda t, x, u: compiled.step(t, x, u, period),
        "compiled_fast": lambda t, x, u: fast.step(t, x, u, period),
    }
    skipped = {}
    for segments in (1, 8):
        stepper = _mujoco_stepper(arm, config.water, segments, period)
        if isinstance(stepper, str):
            skipped[f"mujoco_rk4_1ms_segments{segments}"] = stepper
        else:
            paths[f"mujoco_rk4_1ms_segments{segments}"] = stepper
    _round_robin(paths, states[:20])  # warm-up: numba caches, MuJoCo's first steps
    seconds = _round_robin(paths, states)
    out = {
        "setting": f"{arm_name} arm, control period {period * 1e3:g} ms, {len(states)} states of its SMC "
        "closed loop, round-robin",
        "step_ms": {name: stats_ms(values) for name, values in seconds.items()},
        "skipped": skipped,
        "compiled_max_abs_diff_one_step": max(
            float(np.abs(compiled.step(t, x, u, period)[0] - plant.step(t, x, u, period)[0]).max())
            for t, x, u in states
        ),
        "closed_loop_10s": {
            "reference_run_wall_s": reference_wall,
            "compiled": _closed_loop(config, "SMC", {"plant.compiled": True}, traj),
            "compiled_fast": _closed_loop(config, "SMC", {"plant.compiled": True, **FAST}, traj),
        },
    }
    out.update(_ratios({name: float(np.median(values)) for name, values in seconds.items()}))
    out["batched"] = _batched(compiled, states, period, quick)
    return out


def _ratios(medians: dict) -> dict:
    """Speed-ups (ratios of median step times) of the compiled paths against the reference and MuJoCo."""
    out = {}
    for peer in ("reference", "mujoco_rk4_1ms_segments1", "mujoco_rk4_1ms_segments8"):
        if peer in medians:
            out[f"compiled_speedup_vs_{peer}"] = ratio(medians[peer], medians["compiled"])
            out[f"compiled_fast_speedup_vs_{peer}"] = ratio(medians[peer], medians["compiled_fast"])
    if "mujoco_rk4_1ms_segments1" in medians:
        out["target_met"] = bool(out["compiled_speedup_vs_mujoco_rk4_1ms_segments1"] >= TARGET_VS_MUJOCO)
    return out


def bench_arm_fast(quick: bool) -> dict:
    """The section: one row per arm of :data:`ARMS` (see the module's docstring)."""
    return {
        "compiled_fast_settings": FAST,
        "target_compiled_speedup_vs_mujoco": TARGET_VS_MUJOCO,
        "arms": {name: _bench_arm(name, quick) for name in ARMS},
    }


def _batched(plant, states: list, period: float, quick: bool) -> dict:
    """64 copies in one BatchedArm call against 64 single compiled steps (copy-steps per second)."""
    import numba

    from hydroarm.model.arm.fast import BatchedArm

    batch = BatchedArm(plant.fast)
    picks = [states[k % len(states)] for k in range(COPIES)]
    t = np.array([s[0] for s in picks])
    x = np.array([s[1] for s in picks])
    u = np.array([s[2] for s in picks])
    batch.step(t, x, u, period, plant.inner_step)  # warm-up (compiles the parallel kernel)
    repeats = 5 if quick else 50
    single, batched = [], []
    for _ in range(repeats):
        start = time.perf_counter_ns()
        for c in range(COPIES):
            plant.step(t[c], x[c], u[c], period)
        single.append((time.perf_counter_ns() - start) * 1e-9)
        start = time.perf_counter_ns()
        batch.step(t, x, u, period, plant.inner_step)
        batched.append((time.perf_counter_ns() - start) * 1e-9)
    single_rate = COPIES / float(np.median(single))
    batched_rate = COPIES / float(np.median(batched))
    return {
        "copies": COPIES,
        "threads": int(numba.get_num_threads()),
        "single_copy_steps_per_s": single_rate,
        "batched_copy_steps_per_s": batched_rate,
        "batched_speedup_vs_single": batched_rate / single_rate,
    }


def render_arm_fast(section: dict) -> str:
    """The section as Markdown (bench.md)."""
    lines = ["", "## 2d. The compiled fixed-base plant (plant.compiled)", ""]
    target = section["target_compiled_speedup_vs_mujoco"]
    lines.append(f"Fast setting: {section['compiled_fast_settings']}; target: compiled >= {target:g}x MuJoCo RK4 1 ms")
    for arm_row in section["arms"].values():
        lines += ["", arm_row["setting"], "", "| path | median ms | p99 ms | max ms |", "|---|---|---|---|"]
        for name, row in arm_row["step_ms"].items():
            lines.append(f"| {name} | {row['median']:.4f} | {row['p99']:.4f} | {row['max']:.4f} |")
        lines.append("")
        for key, value in arm_row.items():
            if "speedup" in key or key in ("target_met", "compiled_max_abs_diff_one_step"):
                lines.append(f"- {key}: {value:.4g}" if isinstance(value, float) else f"- {key}: {value}")
        loop = arm_row["closed_loop_10s"]
        for name in ("compiled", "compiled_fast"):
            row = loop[name]
            lines.append(f"- {name}, 10 s SMC closed loop vs reference: {row['max_abs_q_rad']:.2g} rad, "
                         f"{row['max_abs_v_rad_s']:.2g} rad/s; run {row['run_wall_s']:.3f} s against "
                         f"{loop['reference_run_wall_s']:.3f} s")  # fmt: skip
        batched = arm_row["batched"]
        lines.append(
            f"- batched ({batched['copies']} copies, {batched['threads']} threads): "
            f"{batched['batched_copy_steps_per_s']:.0f} copy-steps/s against {batched['single_copy_steps_per_s']:.0f} "
            f"single ({batched['batched_speedup_vs_single']:.2f}x)"
        )
        for name, why in arm_row["skipped"].items():
            lines.append(f"- {name}: skipped ({why})")
    return "\n".join(lines) + "\n"
