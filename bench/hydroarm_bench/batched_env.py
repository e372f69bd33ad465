"""Section ``batched_env``: environment steps per second of the arm env, single and batched.

For the paper arm and Alpha 5, in one process, interleaved over ``repeats`` rounds (each round
times every path over the same random normalised actions, so that a load change on a shared
machine hits them alike):

* ``single_reference``: one ``UnderwaterArmEnv`` as ``gymnasium.make("hydroarm/UnderwaterArm-v0")``
  gives it (the reference plant): what a user has today;
* ``single_compiled``: one env on the compiled plant (``hydroarm/UnderwaterArmBatched-v0``'s
  ``gymnasium.make``, :func:`hydroarm.envs.batched.make_compiled_arm_env`);
* ``batched_64``: :class:`hydroarm.envs.batched.BatchedArmVectorEnv` with 64 copies (numba's
  threads: every core this process may use); an env step is one copy's step (autoreset steps,
  which only reset, are not counted).

Reported: the medians over the rounds of environment steps per wall second and per CPU second
(this process's user + system time: on a machine that other work keeps busy the CPU rate is the
per-core rate, the wall rate what this run got), the ratios, and the targets (the batched env
>= 2e4 env steps/s per core; the compiled single env >= 5x the reference one).
"""

from __future__ import annotations

import time

import numpy as np

ARMS = ("paper", "alpha5")
COPIES = 64
TARGET_PER_CORE = 2e4
TARGET_SINGLE_SPEEDUP = 5.0


def _single(env, actions: np.ndarray) -> tuple[float, float, int]:
    """(wall s, CPU s, env steps) of ``env`` over the rows of ``actions``."""
    cpu, wall = time.process_time(), time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return time.perf_counter() - wall, time.process_time() - cpu, len(actions)


def _batched(envs, actions: np.ndarray) -> tuple[float, float, int]:
    """(wall s, CPU s, env steps) of the vector env over the batches of ``actions``."""
    steps, done = 0, np.zeros(envs.num_envs, dtype=bool)
    cpu, wall = time.process_time(), time.perf_counter()
    for batch in actions:
        _, _, terminated, truncated, _ = envs.step(batch)
        steps += envs.num_envs - int(np.count_nonzero(done))
        done = terminated | truncated
    return time.perf_counter() - wall, time.process_time() - cpu, steps


def _bench_arm(arm: str, quick: bool) -> dict:
    import numba

    from hydroarm.envs.batched import BatchedArmVectorEnv, make_compiled_arm_env
    from hydroarm.envs.underwater_arm import UnderwaterArmEnv

    single_steps = 200 if quick else 1000
    batches = 10 if quick else 50
    repeats = 3 if quick else 7
    rng = np.random.default_rng(0)
    reference, compiled = UnderwaterArmEnv(arm=arm), make_compiled_arm_env(arm=arm)
    envs = BatchedArmVectorEnv(COPIES, arm=arm)
    for env in (reference, compiled):
        env.reset(seed=0)
    envs.reset(seed=0)
    actions = rng.uniform(-1, 1, (single_steps, reference.n))
    batch_actions = rng.uniform(-1, 1, (batches, COPIES, reference.n))
    _batched(envs, batch_actions[:2])  # warm-up: the parallel kernel's threads
    rows: dict[str, list[tuple[float, float, int]]] = {"single_reference": [], "single_compiled": [], "batched_64": []}
    for _ in range(repeats):
        rows["single_reference"].append(_single(reference, actions))
        rows["single_compiled"].append(_single(compiled, actions))
        rows["batched_64"].append(_batched(envs, batch_actions))
    out: dict = {"threads": int(numba.get_num_threads()), "copies": COPIES, "repeats": repeats}
    for name, samples in rows.items():
        out[name] = {
            "env_steps_per_s": float(np.median([s / w for w, _, s in samples])),
            "env_steps_per_cpu_s": float(np.median([s / c for _, c, s in samples if c > 0])),
            "env_steps": int(samples[0][2]),
        }
    out["single_compiled_speedup_vs_reference"] = float(
        np.median([r[0] / c[0] for r, c in zip(rows["single_reference"], rows["single_compiled"], strict=True)])
    )
    out["batched_speedup_vs_single_reference_per_cpu_s"] = (
        out["batched_64"]["env_steps_per_cpu_s"] / out["single_reference"]["env_steps_per_cpu_s"]
    )
    out["target_single_met"] = bool(out["single_compiled_speedup_vs_reference"] >= TARGET_SINGLE_SPEEDUP)
    out["target_batched_per_core_met"] = bool(out["batched_64"]["env_steps_per_cpu_s"] >= TARGET_PER_CORE)
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
        for name in ("single_reference", "single_compiled", "batched_64"):
            rates = row[name]
            lines.append(f"| {arm} | {name} | {rates['env_steps_per_s']:.0f} | {rates['env_steps_per_cpu_s']:.0f} |")
    lines.append("")
    target = section["target_batched_env_steps_per_core"]
    for arm, row in section["arms"].items():
        lines.append(
            f"- {arm}: compiled single env {row['single_compiled_speedup_vs_reference']:.2f}x the reference one "
            f"(target {section['target_single_speedup']:g}x: {row['target_single_met']}); batched per CPU s "
            f"{row['batched_64']['env_steps_per_cpu_s']:.0f} (target {target:.0f}: "
            f"{row['target_batched_per_core_met']}), {row['threads']} threads"
        )
    return "\n".join(lines) + "\n"
