"""Section ``batched_env``: environment steps per second of the arm env, single and batched.

For the paper arm and Alpha 5, in one process, interleaved over ``repeats`` rounds (each round
times every path over the same random normalised actions, so that a load change on a shared
machine hits them alike):

* ``single_reference``: one ``UnderwaterArmEnv`` as ``gymnasium.make("hydroarm/UnderwaterArm-v0")``
  gives it (the reference plant): what a user has today;
* ``single_compiled``: one env on the compiled plant (``hydroarm/UnderwaterArmBatched-v0``'s
  ``gymnasium.make``, :func:`hydroarm.envs.batched.make_compiled_arm_env`) at the reference's
  accuracy (1 ms RK4, 8 Gauss points);
* ``batched_64``: :class:`hydroarm.envs.batched.BatchedArmVectorEnv` with 64 copies, on every core
  this process may use (numba's threads) and on one (``batched_64_one_thread``: a core's rate);
  an env step is one copy's step (autoreset steps, which only reset, are not counted);
* the same single and batched paths at each of :data:`FAST_SETTINGS` (``single_compiled[name]``,
  ``batched_64[name]``, ``batched_64_one_thread[name]``): longer RK4 steps and fewer drag
  points, and beside them that setting's error in the env: one control period from each state
  the reference-accuracy env visits under the timed actions, both plants under the same torque
  (:func:`_fast_error`).

Reported: the medians over the rounds of environment steps per wall second and per CPU second
(this process's user + system time), the ratios, and the targets, per accuracy: the compiled
single env >= 5x the reference one; the batched env >= 2e4 env steps/s per core, a core's rate
being the one-thread batched rate (with every core, numba's idle threads spin and count as CPU
time, so the CPU-second rate of the threaded run understates a core's).
"""

from __future__ import annotations

import time

import numpy as np

from hydroarm_bench.arm_fast import FAST

ARMS = ("paper", "alpha5")
COPIES = 64
TARGET_PER_CORE = 2e4
TARGET_SINGLE_SPEEDUP = 5.0
FAST_SETTINGS = {
    "fast": FAST,  # the arm_fast section's fast setting: 2.5 ms RK4, 3 drag points
    "fast_5ms": {"plant.inner_step": 5e-3, "plant.drag_points": 3},  # the vehicle's compiled step and points
}


def _single(env, actions: np.ndarray) -> tuple[float, float, int]:
    """(wall s, CPU s, env steps) of ``env`` over the rows of ``actions``."""
    cpu, wall = time.process_time(), time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return time.perf_counter() - wall, time.process_time() - cpu, len(actions)


def _batched(envs, actions: np.ndarray, threads: int | None = None) -> tuple[float, float, int]:
    """(wall s, CPU s, env steps) of the vector env over the batches of ``actions``, on
    ``threads`` of numba's threads (None: all)."""
    import numba

    steps, done = 0, np.zeros(envs.num_envs, dtype=bool)
    every = numba.config.NUMBA_NUM_THREADS
    numba.set_num_threads(every if threads is None else threads)
    try:
        cpu, wall = time.process_time(), time.perf_counter()
        for batch in actions:
            _, _, terminated, truncated, _ = envs.step(batch)
            steps += envs.num_envs - int(np.count_nonzero(done))
            done = terminated | truncated
        return time.perf_counter() - wall, time.process_time() - cpu, steps
    finally:
        numba.set_num_threads(every)


def _fast_error(arm: str, settings: dict, actions: np.ndarray) -> dict:
    """The one-step error of ``settings`` against the reference's accuracy: from every state
    the reference-accuracy compiled env visits under ``actions`` (seed 0; reset where an episode
    ends), one control period under the same torque on both plants; the largest joint-angle and
    joint-speed differences (rad, rad/s) and the largest step the angles took (rad), for scale.
    (Not the difference of whole episodes: under random torques the wrists spin up and two
    episodes that differ in the last bit part within a second, the arm being chaotic there.)"""
    from hydroarm.envs.batched import make_compiled_arm_env

    exact, fast = make_compiled_arm_env(arm=arm), make_compiled_arm_env(arm=arm, settings=settings)
    exact.reset(seed=0)
    n, worst_q, worst_v, largest = exact.n, 0.0, 0.0, 0.0
    for action in actions:
        _, _, terminated, truncated, info = exact.step(action)
        t, x, tau = float(info["t"]), info["x"], info["torque"]
        x_exact = exact.plant.step(t, x, tau, exact.period)[0]
        x_fast = fast.plant.step(t, x, tau, exact.period)[0]
        if np.all(np.isfinite(x_exact)):
            worst_q = max(worst_q, float(np.max(np.abs(x_fast[:n] - x_exact[:n]))))
            worst_v = max(worst_v, float(np.max(np.abs(x_fast[n:] - x_exact[n:]))))
            largest = max(largest, float(np.max(np.abs(x_exact[:n] - x[:n]))))
        if terminated or truncated:
            exact.reset()
    return {"one_step_max_abs_q_rad": worst_q, "one_step_max_abs_v_rad_s": worst_v, "largest_step_q_rad": largest}


def _paths(arm: str) -> dict:
    """name -> (kind, env): every path of the module's docstring."""
    from hydroarm.envs.batched import BatchedArmVectorEnv, make_compiled_arm_env
    from hydroarm.envs.underwater_arm import UnderwaterArmEnv

    paths = {
        "single_reference": ("single", UnderwaterArmEnv(arm=arm)),
        "single_compiled": ("single", make_compiled_arm_env(arm=arm)),
    }
    batched = {"batched_64": BatchedArmVectorEnv(COPIES, arm=arm)}
    for name, settings in FAST_SETTINGS.items():
        paths[f"single_compiled[{name}]"] = ("single", make_compiled_arm_env(arm=arm, settings=settings))
        batched[f"batched_64[{name}]"] = BatchedArmVectorEnv(COPIES, arm=arm, settings=settings)
    for name, envs in batched.items():
        paths[name] = ("batched", envs)
        paths[name.replace("batched_64", "batched_64_one_thread")] = ("one_thread", envs)
    return paths


def _rates(samples: list[tuple[float, float, int]]) -> dict:
    return {
        "env_steps_per_s": float(np.median([s / w for w, _, s in samples])),
        "env_steps_per_cpu_s": float(np.median([s / c for _, c, s in samples if c > 0])),
        "env_steps": int(samples[0][2]),
    }


def _bench_arm(arm: str, quick: bool) -> dict:
    import numba

    single_steps = 200 if quick else 1000
    batches = 10 if quick else 50
    repeats = 3 if quick else 7
    rng = np.random.default_rng(0)
    paths = _paths(arm)
    n = paths["single_reference"][1].n
    actions = rng.uniform(-1, 1, (single_steps, n))
    batch_actions = rng.uniform(-1, 1, (batches, COPIES, n))
    for kind, env in paths.values():
        env.reset(seed=0)
        if kind != "single":
            _batched(env, batch_actions[:2])  # warm-up: the parallel kernel's threads
    rows: dict[str, list[tuple[float, float, int]]] = {name: [] for name in paths}
    for _ in range(repeats):
        for name, (kind, env) in paths.items():
            if kind == "single":
                rows[name].append(_single(env, actions))
            else:
                rows[name].append(_batched(env, batch_actions, 1 if kind == "one_thread" else None))
    out: dict = {"threads": int(numba.config.NUMBA_NUM_THREADS), "copies": COPIES, "repeats": repeats}
    out.update({name: _rates(samples) for name, samples in rows.items()})
    out["accuracy"] = {"reference": {}, **{name: {"settings": FAST_SETTINGS[name]} for name in FAST_SETTINGS}}
    for suffix, name in [("", "reference")] + [(f"[{k}]", k) for k in FAST_SETTINGS]:
        row = out["accuracy"][name]
        pairs = zip(rows["single_reference"], rows[f"single_compiled{suffix}"], strict=True)
        row["single_speedup_vs_reference"] = float(np.median([r[0] / c[0] for r, c in pairs]))
        row["batched_per_core"] = out[f"batched_64_one_thread{suffix}"]["env_steps_per_s"]
        row["target_single_met"] = bool(row["single_speedup_vs_reference"] >= TARGET_SINGLE_SPEEDUP)
        row["target_batched_per_core_met"] = bool(row["batched_per_core"] >= TARGET_PER_CORE)
        if name != "reference":
            row.update(_fast_error(arm, FAST_SETTINGS[name], actions))
    return out


def bench_batched_env(quick: bool) -> dict:
    """The section: one row per arm of :data:`ARMS` (see the module's docstring)."""
    return {
        "target_batched_env_steps_per_core": TARGET_PER_CORE,
        "target_single_speedup": TARGET_SINGLE_SPEEDUP,
        "arms": {arm: _bench_arm(arm, quick) for arm in ARMS},
    }


def render_batched_env(section: dict) -> str:
    """The section as Markdown (bench.md)."""
    lines = ["", "## Env steps: single env (reference, compiled plant) and the batched vector env", ""]
    lines += ["| arm | path | env steps/s | env steps per CPU s |", "|---|---|---|---|"]
    for arm, row in section["arms"].items():
        for name, rates in row.items():
            if isinstance(rates, dict) and "env_steps_per_s" in rates:
                lines.append(
                    f"| {arm} | {name} | {rates['env_steps_per_s']:.0f} | {rates['env_steps_per_cpu_s']:.0f} |"
                )
    lines.append("")
    target = section["target_batched_env_steps_per_core"]
    for arm, row in section["arms"].items():
        for name, acc in row["accuracy"].items():
            error = ""
            if "one_step_max_abs_q_rad" in acc:
                error = (
                    f" (one period off the reference accuracy by at most {acc['one_step_max_abs_q_rad']:.2g} rad "
                    f"in a step of up to {acc['largest_step_q_rad']:.2g} rad, "
                    f"{acc['one_step_max_abs_v_rad_s']:.2g} rad/s)"
                )
            lines.append(
                f"- {arm}, {name} accuracy{error}: compiled single env {acc['single_speedup_vs_reference']:.2f}x the "
                f"reference one (target {section['target_single_speedup']:g}x: {acc['target_single_met']}); batched "
                f"per core (one thread) {acc['batched_per_core']:.0f} (target {target:.0f}: "
                f"{acc['target_batched_per_core_met']}); {row['threads']} threads at most"
            )
    return "\n".join(lines) + "\n"
