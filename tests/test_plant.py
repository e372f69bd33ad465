"""The plant: energy, dissipation, RK4 order, noise, the nominal model, the disturbance record."""

from __future__ import annotations

import numpy as np
import pytest

import hydroarm
from hydroarm.model.arm.plant import PlantConfig, UnderwaterPlant
from hydroarm.model.dynamics.nominal import NominalModel
from hydroarm.model.water.morison import CurrentConfig, Water, paper_current_acceleration


@pytest.fixture(scope="session")
def arm(paper_arm):
    return paper_arm


X0 = np.concatenate([[0.3, -0.8, 1.2, 0.4, -0.6, 0.2], [1.0, -0.5, 0.8, 2.0, -1.5, 3.0]])
STILL = CurrentConfig(model="none")


def test_energy_conserved_with_the_water_off(arm):
    """Dry arm, no torque, 5 s at the default 1 ms RK4 step: |E - E0| < 1e-6 relative.

    Relative to the energy the motion carries, max(|E0|, peak kinetic energy)
    (78 J here; the light wrist whirls at up to 60 rad/s). The drift is RK4's
    truncation error: measured 5.4e-7 at 1 ms and 2.4e-8 at 0.5 ms.
    """
    plant = UnderwaterPlant(arm, Water().off())
    x = X0.copy()
    energy0 = plant.energy(x)
    peak_kinetic = 0.0
    worst = 0.0
    for k in range(500):
        x, _ = plant.step(0.01 * k, x, np.zeros(6), 0.01)
        worst = max(worst, abs(plant.energy(x) - energy0))
        peak_kinetic = max(peak_kinetic, arm.kinetic_energy(x[:6], x[6:]))
    assert worst / max(abs(energy0), peak_kinetic) < 1e-6


def test_drag_never_increases_energy(arm):
    plant = UnderwaterPlant(arm, Water(added_mass=False, buoyancy=False, current=STILL))
    x = X0.copy()
    energy = plant.energy(x)
    start = energy
    for k in range(300):
        x, _ = plant.step(0.01 * k, x, np.zeros(6), 0.01)
        new = plant.energy(x)
        assert new <= energy + 1e-9 * abs(start)
        energy = new
    assert energy < start - 1.0  # it really dissipates


def test_rk4_is_fourth_order(arm):
    """Full water model: halving the step cuts the error about 16x."""
    water = Water(
        current=CurrentConfig(model="uniform", mean=[0.2, -0.1, 0.0], amplitude=[0.1, 0, 0], frequency_hz=1.0)
    )
    u = np.array([20.0, -40.0, 10.0, 2.0, -1.0, 0.5])

    def run(step):
        plant = UnderwaterPlant(arm, water, PlantConfig(inner_step=step))
        return plant.step(0.0, X0, u, 0.2)[0]

    reference = run(0.2 / 512)
    errors = [np.linalg.norm(run(0.2 / k) - reference) for k in (8, 16, 32)]
    ratios = [errors[0] / errors[1], errors[1] / errors[2]]
    for ratio in ratios:
        assert 12.0 < ratio < 20.0, (errors, ratios)


def test_nominal_model_is_the_plant_without_water(arm):
    nominal = NominalModel(arm)
    dry = UnderwaterPlant(arm, Water().off())
    u = np.linspace(-30, 30, 6)
    x_nominal, info_nominal = nominal.step(0.0, X0, u, 0.01)
    x_dry, info_dry = dry.step(0.0, X0, u, 0.01)
    np.testing.assert_allclose(x_nominal, x_dry, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(info_nominal.disturbance, 0.0)
    np.testing.assert_allclose(info_dry.disturbance, 0.0, atol=1e-9)


def test_disturbance_is_the_water_torque(arm):
    """Still water: the recorded disturbance equals drag + added mass + buoyancy at the
    true acceleration, i.e. what the dry model lacks."""
    water = Water(current=STILL)
    plant = UnderwaterPlant(arm, water)
    u = np.array([50.0, -80.0, 30.0, 5.0, -2.0, 1.0])
    q, v = X0[:6], X0[6:]
    acc = plant.acceleration(0.0, q, v, u)
    total = hydroarm.hydrodynamic_torques(arm, water, q, v, acc).total
    np.testing.assert_allclose(plant.disturbance(0.0, q, v, u), total, rtol=1e-9, atol=1e-9)
    # ... and M q'' + C v + G = tau + water
    rebuilt = arm.inverse_dynamics(q, v, acc) - u
    np.testing.assert_allclose(rebuilt, total, rtol=1e-9, atol=1e-9)
    _, info = plant.step(0.0, X0, u, 0.01)
    np.testing.assert_allclose(info.disturbance_start, total, rtol=1e-9, atol=1e-9)


def test_paper_current_is_an_added_joint_acceleration(arm):
    water = Water().off().model_copy(update={"current": CurrentConfig(model="paper")})
    plant = UnderwaterPlant(arm, water)
    q, v, u = X0[:6], X0[6:], np.ones(6)
    t = 2.7
    expected = arm.forward_dynamics(q, v, u) + paper_current_acceleration(water.current, t, 6)
    np.testing.assert_allclose(plant.acceleration(t, q, v, u), expected, rtol=1e-10, atol=1e-10)


def test_measurement_noise_is_seeded_and_leaves_the_truth(arm):
    plant = UnderwaterPlant(arm, Water(), PlantConfig(noise_variance=0.001))
    x = X0.copy()
    y1 = plant.measure(x, np.random.default_rng(3))
    y2 = plant.measure(x, np.random.default_rng(3))
    np.testing.assert_array_equal(y1, y2)
    np.testing.assert_array_equal(x, X0)
    samples = np.stack([plant.measure(x, np.random.default_rng(s)) - x for s in range(4000)])
    # variance 0.001 per entry: the sample variance of 4000 draws is within ~5 % (4.5 sigma).
    assert np.var(samples) == pytest.approx(0.001, rel=0.05)
    quiet = UnderwaterPlant(arm, Water())
    np.testing.assert_array_equal(quiet.measure(x, np.random.default_rng(0)), x)


def test_plant_config_rejects_bad_values():
    with pytest.raises(ValueError, match="inner_step"):
        PlantConfig(inner_step=0.0)
    with pytest.raises(ValueError, match="noise_variance"):
        PlantConfig(noise_variance=-1.0)
    with pytest.raises(ValueError, match="unknown|extra"):
        PlantConfig(noise=0.1)
