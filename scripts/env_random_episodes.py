"""How long does a random policy last on each built-in arm? ``hydroarm/UnderwaterArm-v0`` with
uniform random normalised actions over the whole range [-1, 1] (the action space seeded with 0,
episode k reset with seed k), on the paper arm, the UR5, the Alpha 5, the iiwa14 and the tutorial's
URDF arm of ``examples/urdf``: each episode's length in steps and whether it ended early
(``terminated``: the arm diverged). The env's default water has the energy-consistent (Kirchhoff)
added mass; ``--set water.added_mass_model=morison`` gives the paper's. Dotted settings (as
``hydroarm run --set`` takes them) go to every env, so water models can be compared.

    python scripts/env_random_episodes.py --episodes 100 --duration 10 \
        --out docs/data/env_random_episodes.json
    python scripts/env_random_episodes.py --episodes 100 --duration 10 \
        --set water.added_mass_model=morison --out docs/data/env_random_episodes_morison.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from datetime import date
from pathlib import Path

import gymnasium
import numpy as np

import hydroarm.envs  # noqa: F401  (registers the environment)

ROOT = Path(__file__).resolve().parents[1]
ENV_ID = "hydroarm/UnderwaterArm-v0"
ARMS = {
    "paper": "paper",
    "ur5": "ur5",
    "alpha5": "alpha5",
    "iiwa14": str(ROOT / "examples" / "urdf" / "iiwa14.urdf"),
    "myarm.urdf": str(ROOT / "examples" / "urdf" / "myarm.urdf"),
}


def parse_setting(text: str) -> tuple[str, object]:
    key, _, value = text.partition("=")
    try:
        parsed = json.loads(value)
    except json.JSONDecodeError:
        parsed = value
    return key, parsed


def episodes(arm: str, count: int, duration: float, settings: dict) -> dict:
    env = gymnasium.make(ENV_ID, arm=arm, duration=duration, settings=settings)
    env.action_space.seed(0)
    lengths, ended = [], []
    for k in range(count):
        env.reset(seed=k)
        steps, terminated, truncated = 0, False, False
        while not (terminated or truncated):
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            steps += 1
        lengths.append(steps)
        ended.append(bool(terminated))
    env.close()
    lengths_array = np.array(lengths)
    return {
        "steps_per_episode": env.unwrapped.steps,
        "episodes": count,
        "ended_early": int(np.sum(ended)),
        "median_length": float(np.median(lengths_array)),
        "shortest": int(lengths_array.min()),
        "lengths": lengths,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--duration", type=float, default=10.0, help="episode length (s)")
    parser.add_argument("--arms", nargs="*", default=list(ARMS), choices=list(ARMS))
    parser.add_argument("--set", dest="settings", action="append", default=[], help="a dotted setting, key=value")
    parser.add_argument("--out", type=Path, help="write the results here (JSON)")
    args = parser.parse_args(argv)
    settings = dict(parse_setting(text) for text in args.settings)
    results = {}
    for name in args.arms:
        started = time.perf_counter()
        results[name] = episodes(ARMS[name], args.episodes, args.duration, settings)
        row = results[name]
        print(
            f"{name}: {row['ended_early']} of {row['episodes']} episodes ended early; median length "
            f"{row['median_length']:.0f} of {row['steps_per_episode']} steps, shortest {row['shortest']} "
            f"({time.perf_counter() - started:.0f} s)",
            flush=True,
        )
    if args.out is not None:
        document = {
            "what": "uniform random normalised actions on hydroarm/UnderwaterArm-v0 (scripts/env_random_episodes.py)",
            "date": date.today().isoformat(),
            "machine": f"{platform.machine()}, {os.cpu_count()} CPUs, Python {sys.version.split()[0]}",
            "duration_s": args.duration,
            "settings": settings,
            "added_mass_model": gymnasium.make(
                ENV_ID, arm="alpha5", duration=0.1, settings=settings
            ).unwrapped.config.water.added_mass_model,
            "arms": results,
        }
        args.out.write_text(json.dumps(document, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
