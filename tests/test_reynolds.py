"""The Reynolds-dependent drag (water.drag_model = "reynolds"): the curve, closed forms, the plant."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.integrate

from hydroarm.model.arm.description import ArmSpec, build_arm
from hydroarm.model.arm.loading import load_arm
from hydroarm.model.arm.plant import PlantConfig, UnderwaterPlant
from hydroarm.model.water.morison import Water, WaterModel
from hydroarm.model.water.reynolds import CD_SMOOTH, aspect_factor, drag_coefficient


def rod(length=0.5, diameter=0.08):
    """One joint about the vertical axis; its cylinder runs out from the axis along x."""
    link = {"name": "rod", "a": length, "alpha_deg": 0.0, "d": 0.0, "mass": 2.0, "com": [0.0, 0.0, 0.0],
            "inertia_axial": 1e-3, "inertia_transverse": 0.04, "cylinder_diameter": diameter}  # fmt: skip
    return build_arm(ArmSpec(name="rod", torque_limit=100.0, links=[link]))


def test_the_curve_has_the_plateau_the_crisis_and_the_recovery():
    assert drag_coefficient(1.5e5) == pytest.approx(1.2)
    assert drag_coefficient(10**5.7) == pytest.approx(0.3)  # the drag crisis (Re = 5e5)
    assert drag_coefficient(1e8) == pytest.approx(0.65)  # smooth post-critical
    assert drag_coefficient(0.0) == pytest.approx(CD_SMOOTH[0])
    assert aspect_factor(5.0) == pytest.approx(0.62) and aspect_factor(1e5) == pytest.approx(1.0)


@pytest.mark.parametrize("speed", [0.5, 2.0, 4.0, 6.0, 9.0])
def test_a_uniform_current_past_a_still_rod_is_the_constant_cd_drag_at_its_reynolds_number(speed):
    """Normal speed the same all along the rod: the drag is the constant-C_d drag with
    C_d = C_d(Re) kappa(L/D), Re = V D / nu (exact: both integrands are then the same)."""
    arm = rod()
    current = {"model": "uniform", "mean": [0.0, speed, 0.0]}
    water = Water(drag_model="reynolds", current=current, added_mass=False, buoyancy=False)
    cylinder = arm.cylinders[0]
    reynolds = speed * cylinder.diameter / water.kinematic_viscosity
    equivalent = float(drag_coefficient(reynolds) * aspect_factor(cylinder.length / cylinder.diameter))
    constant = water.model_copy(update={"drag_model": "constant", "cd": equivalent})
    q, v = np.zeros(1), np.zeros(1)
    got = WaterModel(arm, water).torques(q, v, np.zeros(1)).drag
    expected = WaterModel(arm, constant).torques(q, v, np.zeros(1)).drag
    np.testing.assert_allclose(got, expected, rtol=1e-12)
    # and by hand: force 1/2 rho C_d D V^2 per length, along +y, at the rod's middle
    force = 0.5 * water.rho * equivalent * cylinder.diameter * speed**2 * cylinder.length
    np.testing.assert_allclose(got, [force * 0.5 * cylinder.length], rtol=1e-12)


@pytest.mark.parametrize("omega", [3.0, 20.0, -60.0])
def test_a_spinning_rod_matches_an_independent_quadrature(omega):
    """v_n(s) = omega s: the torque int_0^L s 1/2 rho D kappa C_d(|omega| s D / nu) (omega s)^2 ds
    by scipy's adaptive quad on the curve, against the kernel's Gauss-Legendre rule (64 points:
    the curve has kinks in log Re, so the rule converges slower than on a polynomial)."""
    arm = rod()
    water = Water(drag_model="reynolds", current={"model": "none"}, added_mass=False, buoyancy=False,
                  quadrature_points=64)  # fmt: skip
    cylinder = arm.cylinders[0]
    kappa = float(aspect_factor(cylinder.length / cylinder.diameter))
    d, nu = cylinder.diameter, water.kinematic_viscosity

    def integrand(s):
        return s * 0.5 * water.rho * d * kappa * drag_coefficient(abs(omega) * s * d / nu) * (omega * s) ** 2

    breaks = [x * nu / (abs(omega) * d) for x in 10.0 ** np.array([1, 2, 3, 4, 5, 5.3, 5.5, 5.7, 6, 6.5, 7])]
    breaks = [b for b in breaks if 0.0 < b < cylinder.length]
    value, _ = scipy.integrate.quad(integrand, 0.0, cylinder.length, points=breaks or None, limit=200)
    got = WaterModel(arm, water).torques(np.zeros(1), np.array([omega]), np.zeros(1)).drag
    np.testing.assert_allclose(got, [-np.sign(omega) * value], rtol=2e-3)


def test_the_plant_with_reynolds_drag_steps_like_its_numpy_twin_and_differs_from_constant_cd():
    arm = load_arm("paper")
    plant = UnderwaterPlant(arm, Water(drag_model="reynolds"), PlantConfig())
    constant = UnderwaterPlant(arm, Water(), PlantConfig())
    x = np.concatenate([np.full(6, 0.3), np.full(6, 1.5)])
    tau = np.ones(6)
    fast, info = plant.step(0.2, x, tau, 0.01)
    slow, info_slow = plant.step_numpy(0.2, x, tau, 0.01)
    np.testing.assert_allclose(fast, slow, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(info.disturbance, info_slow.disturbance, rtol=1e-12, atol=1e-12)
    _, info_constant = constant.step(0.2, x, tau, 0.01)
    assert np.max(np.abs(info.disturbance - info_constant.disturbance)) > 1.0  # N m: another water
