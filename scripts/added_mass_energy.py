"""Does the water's added mass conserve energy? The paper arm with drag, buoyancy, the current
and the torques off, from rest at q = 0 with joint rates (1, -1, 1, -1, 1, -1) rad/s: the rigid
body alone keeps E = T + V to 1e-6; with the Morison added mass on, E + 1/2 v' M_A(q) v is
printed for two inner RK4 steps (the same drift for both: the model, not the integrator).

    python scripts/added_mass_energy.py
"""

from __future__ import annotations

import numpy as np

import hydroarm
from hydroarm.model.plant import PlantConfig, UnderwaterPlant
from hydroarm.model.water import CurrentConfig, Water


def energy_ratio(added_mass: bool, inner_step: float, steps: int = 100) -> tuple[float, float]:
    """(E at the end / E0, max E / E0) over ``steps`` control periods of 10 ms."""
    arm = hydroarm.load_arm("paper")
    n = arm.n_joints
    water = Water(drag=False, buoyancy=False, added_mass=added_mass, current=CurrentConfig(model="none"))
    plant = UnderwaterPlant(arm, water, PlantConfig(inner_step=inner_step))

    def energy(x: np.ndarray) -> float:
        q, v = x[:n], x[n:]
        extra = 0.5 * v @ hydroarm.added_mass_matrix(arm, water, q) @ v if added_mass else 0.0
        return plant.energy(x) + extra

    x = np.concatenate([np.zeros(n), np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0])])
    e0, values = energy(x), []
    for k in range(steps):
        x, _ = plant.step(k * 0.01, x, np.zeros(n), 0.01)
        values.append(energy(x))
    return values[-1] / e0, max(values) / e0


if __name__ == "__main__":
    for added, inner in ((False, 1e-3), (True, 1e-3), (True, 1e-4)):
        end, peak = energy_ratio(added, inner)
        state = "on " if added else "off"
        print(f"added mass {state}, RK4 step {inner * 1e3:g} ms: E(1 s)/E0 = {end:.6f}, max {peak:.4f}")
