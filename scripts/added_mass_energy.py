"""Does the water's added mass conserve energy? Morison's (the paper's) against Kirchhoff's
(``water.added_mass_model = "kirchhoff"``, the Lagrangian of the water's kinetic energy).

Each arm with drag, buoyancy, the current and the torques off, from rest at q = 0 with joint rates
(1, -1, 1, ...) rad/s: E = the dry energy + 1/2 v' M_A(q) v over 1 s, for two inner RK4 steps (the
rigid body alone keeps E to 1e-6). Morison's E swings by the same amount at both steps (the model,
not the integrator); Kirchhoff's drifts by the RK4 error only, 16x less per halved step.

With ``--episodes N``: a uniform random policy at the Gymnasium env's default action scale, N
episodes of 1 s on the paper and UR5 arms, under each model; how many end early (the plant
diverges).

    python scripts/added_mass_energy.py [--episodes 100]
"""

from __future__ import annotations

import argparse

import numpy as np

import hydroarm
from hydroarm.model.arm.plant import PlantConfig, UnderwaterPlant
from hydroarm.model.water.morison import CurrentConfig, Water, WaterModel

MODELS = ("morison", "kirchhoff")


def energy_drift(arm_name: str, model: str | None, inner_step: float, steps: int = 100) -> tuple[float, float]:
    """(E at the end / E0, largest |E - E0| / |E0|) over ``steps`` control periods of 10 ms;
    ``model`` None: the added mass off."""
    arm = hydroarm.load_arm(arm_name)
    n = arm.n_joints
    water = Water(drag=False, buoyancy=False, added_mass=model is not None,
                  added_mass_model=model or "morison", current=CurrentConfig(model="none"))  # fmt: skip
    plant = UnderwaterPlant(arm, water, PlantConfig(inner_step=inner_step))
    added = WaterModel(arm, water)

    def energy(x: np.ndarray) -> float:
        extra = 0.5 * x[n:] @ added.terms(x[:n], np.zeros(n))[0] @ x[n:] if model else 0.0
        return plant.energy(x) + extra

    x = np.concatenate([np.zeros(n), np.resize([1.0, -1.0], n)])
    e0, worst = energy(x), 0.0
    for k in range(steps):
        x, _ = plant.step(k * 0.01, x, np.zeros(n), 0.01)
        worst = max(worst, abs(energy(x) - e0) / abs(e0))
    return energy(x) / e0, worst


def early_endings(arm_name: str, model: str, episodes: int) -> list[int]:
    """Episodes (of ``episodes`` seeded 0..N-1, 1 s each) that a uniform random policy ends early."""
    import gymnasium

    from hydroarm.sim.experiment import ExperimentConfig

    config = ExperimentConfig(water=Water(added_mass_model=model))
    env = gymnasium.make("hydroarm.envs:hydroarm/UnderwaterArm-v0", arm=arm_name, duration=1.0, config=config)
    env.action_space.seed(0)
    ended = []
    for episode in range(episodes):
        env.reset(seed=episode)
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            done = terminated or truncated
        if terminated:
            ended.append(episode)
    return ended


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=0, help="random-policy episodes per arm and model (0: none)")
    args = parser.parse_args()
    print("arm     added mass   RK4 step   E(1 s)/E0   max |E - E0|/|E0|")
    for arm in ("paper", "ur5", "alpha5"):
        for model in (None, *MODELS):
            for inner in (1e-3, 5e-4):
                end, worst = energy_drift(arm, model, inner)
                print(f"{arm:7s} {model or 'off':11s} {inner * 1e3:5.1f} ms  {end:10.6f}   {worst:.3g}")
    for arm in ("paper", "ur5") if args.episodes > 0 else ():
        for model in MODELS:
            ended = early_endings(arm, model, args.episodes)
            print(f"random policy, {arm}, {model}: {len(ended)} of {args.episodes} episodes ended early {ended[:10]}")


if __name__ == "__main__":
    main()
