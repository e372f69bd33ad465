"""How much of one Gymnasium env step is the plant? (issue 30: the single env's own overhead)

For each arm, the compiled-plant env (:func:`hydroarm.envs.batched.make_compiled_arm_env`, the
batched vector env's copy) steps ``--steps`` small random actions (seeded, resets on episode end),
then its plant's control step alone is timed as many times in the same process; the env's steps
per second, the plant's share of a step and cProfile's top functions by own time are printed.
Absolute times depend on the machine's load; the share is what this measures.

    python scripts/env_step_profile.py [--arms alpha5,paper] [--steps 1000] [--top 12]
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time

import numpy as np

from hydroarm.envs.batched import make_compiled_arm_env


def profile(arm: str, steps: int, top: int) -> None:
    """Print ``arm``'s env step rate, the plant's share and the profile's top ``top`` rows."""
    env = make_compiled_arm_env(arm=arm)
    actions = np.random.default_rng(0).uniform(-0.2, 0.2, (steps, env.n))

    def run() -> None:
        env.reset(seed=0)
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()

    run()  # warm-up
    start = time.perf_counter()
    run()
    step = (time.perf_counter() - start) / steps
    x, zero = env.state, np.zeros(env.n)
    start = time.perf_counter()
    for _ in range(steps):
        env.plant.step(0.0, x, zero, env.period)
    plant = (time.perf_counter() - start) / steps
    print(f"{arm}: {1.0 / step:.0f} env steps/s; the plant's step {plant * 1e6:.0f} us of {step * 1e6:.0f} us "
          f"({100.0 * plant / step:.0f} %)")  # fmt: skip
    profiler = cProfile.Profile()
    profiler.enable()
    run()
    profiler.disable()
    pstats.Stats(profiler).sort_stats("tottime").print_stats(top)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arms", default="alpha5,paper")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--top", type=int, default=12)
    args = parser.parse_args()
    for arm in args.arms.split(","):
        profile(arm, args.steps, args.top)


if __name__ == "__main__":
    main()
