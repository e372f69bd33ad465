"""The Gymnasium environment's speed: environment steps per second of one ``UnderwaterArm-v0``
and of an 8-copy ``gymnasium.make_vec`` vector environment (``"async"``: one process per copy),
random normalised actions, the compile cost and the processes' start paid at make (timed apart).

An environment step of the vector env is one copy's step: its rate is 8 x vector steps / s.
"""

from __future__ import annotations

import os
import time

import numpy as np

COPIES = 8
ENV_ID = "hydroarm.envs:hydroarm/UnderwaterArm-v0"


def _rate(step, steps: int) -> float:
    started = time.perf_counter()
    for _ in range(steps):
        step()
    return steps / (time.perf_counter() - started)


def bench_envs(quick: bool, arm: str = "alpha5") -> dict:
    """``single_steps_per_s``, ``vector_env_steps_per_s`` (environment steps), ``speedup``, the
    make times (s) and the load average at the start."""
    try:
        import gymnasium
    except ImportError as error:
        return {"skipped": f"{error.name} is missing (pip install -e '.[gym]')"}
    steps = 300 if quick else 2000
    load = os.getloadavg()
    started = time.perf_counter()
    env = gymnasium.make(ENV_ID, arm=arm)
    single_make = time.perf_counter() - started
    env.reset(seed=0)
    env.action_space.seed(0)
    single = _rate(lambda: env.step(env.action_space.sample()), steps)
    env.close()
    started = time.perf_counter()
    envs = gymnasium.make_vec(ENV_ID, num_envs=COPIES, vectorization_mode="async", arm=arm)
    envs.reset(seed=0)
    vector_make = time.perf_counter() - started
    envs.action_space.seed(0)
    envs.step(envs.action_space.sample())  # the first step after the processes' start
    vector = COPIES * _rate(lambda: envs.step(envs.action_space.sample()), max(steps // COPIES, 20))
    envs.close()
    return {
        "arm": arm,
        "copies": COPIES,
        "vectorization_mode": "async",
        "autoreset_mode": "next_step",
        "steps": steps,
        "single_steps_per_s": single,
        "vector_env_steps_per_s": vector,
        "speedup": vector / single,
        "single_make_s": single_make,
        "vector_make_s": vector_make,
        "cpus": os.cpu_count(),
        "load_average_start": list(np.round(load, 2)),
    }


def render_envs(section: dict) -> str:
    """The environment's section of bench.md."""
    if "skipped" in section:
        return f"\n## Gymnasium environment\n\nSkipped: {section['skipped']}\n"
    return (
        "\n## Gymnasium environment\n\n"
        f"`UnderwaterArm-v0` on {section['arm']}, random normalised actions: one environment "
        f"{section['single_steps_per_s']:.0f} steps/s; an {section['copies']}-copy async vector environment "
        f"{section['vector_env_steps_per_s']:.0f} environment steps/s ({section['speedup']:.2f}x) on "
        f"{section['cpus']} CPUs (load average at the start {section['load_average_start'][0]:.1f}). "
        f"Made in {section['single_make_s']:.1f} s and {section['vector_make_s']:.1f} s (the compiled step "
        "and the processes' start are paid there).\n"
    )
