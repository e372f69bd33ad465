"""The prescribed-motion plant (issue 22): the vehicle integrated under a given arm motion."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from hydroarm.model.vehicle.plant import UVMSPlantConfig
from hydroarm.model.vehicle.prescribed import PointWrench, PrescribedUVMSPlant
from hydroarm.model.vehicle.system import UVMSDynamics, build_uvms
from hydroarm.model.water.morison import Water


class Sines:
    """q_i(t) = c_i + A_i sin(w_i t + p_i) with exact derivatives."""

    def __init__(self, n: int, seed: int = 0):
        rng = np.random.default_rng(seed)
        self.c = rng.uniform(0.5, 1.5, n)
        self.amp = rng.uniform(0.2, 0.6, n)
        self.w = rng.uniform(0.5, 2.0, n)
        self.p = rng.uniform(0.0, 2.0 * np.pi, n)

    def sample(self, t: float):
        s = np.sin(self.w * t + self.p)
        c = np.cos(self.w * t + self.p)
        return self.c + self.amp * s, self.amp * self.w * c, -self.amp * self.w**2 * s


def _state(uvms, rng):
    q = uvms.neutral(position=(0.1, -0.2, 0.3), q_arm=rng.uniform(0.3, 2.0, uvms.n_arm))
    q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(*rng.uniform(-0.3, 0.3, 3))).coeffs()
    return q, rng.normal(0.0, 0.3, uvms.nv)


def test_equals_free_floating_dynamics_under_inverse_dynamics_torques():
    """Drive the free-floating system with the torques the prescribed motion took: the same
    vehicle acceleration and the prescribed joint acceleration come back (water on)."""
    uvms = build_uvms("bluerov2-heavy", "alpha5")
    water = Water()
    plant = PrescribedUVMSPlant(uvms, Sines(uvms.n_arm), water)
    free = UVMSDynamics(uvms, water)
    rng = np.random.default_rng(7)
    for _ in range(5):
        q, v = _state(uvms, rng)
        a = rng.normal(0.0, 2.0, uvms.n_arm)
        nu_dot, tau = plant.accelerations(0.3, q, v, a)
        full = free.acceleration(0.3, q, v, np.concatenate([np.zeros(6), tau]), np.zeros(uvms.vehicle.n_thrusters))
        np.testing.assert_allclose(full[:6], nu_dot, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(full[6:], a, rtol=1e-9, atol=1e-9)


def test_body_wrench_and_tether_are_the_same_force():
    """A world force at the vehicle origin given as a tether equals the body-frame input wrench."""
    uvms = build_uvms("bluerov2-heavy", "alpha5")
    force = np.array([1.5, -2.0, 0.7])
    tether = PrescribedUVMSPlant(
        uvms, Sines(uvms.n_arm), Water(), wrenches=(PointWrench("vehicle", force=tuple(force)),)
    )
    plain = PrescribedUVMSPlant(uvms, Sines(uvms.n_arm), Water())
    q, v = _state(uvms, np.random.default_rng(2))
    a = np.ones(uvms.n_arm)
    rot = pin.Quaternion(q[3:7]).toRotationMatrix()
    body = np.concatenate([rot.T @ force, np.zeros(3)])
    np.testing.assert_allclose(tether.accelerations(0.0, q, v, a)[0], plain.accelerations(0.0, q, v, a, body)[0])
    moved = plain.accelerations(0.0, q, v, a)[0]
    assert np.abs(moved - plain.accelerations(0.0, q, v, a, body)[0]).max() > 1e-3  # the wrench acts


def test_momentum_conserved_without_water_and_gravity():
    uvms = build_uvms("bluerov2-heavy", "alpha5", gravity=0.0)
    water = Water(drag=False, added_mass=False, buoyancy=False)
    plant = PrescribedUVMSPlant(uvms, Sines(uvms.n_arm, seed=4), water, UVMSPlantConfig(inner_step=2e-3))
    x = plant.initial_state(0.0, twist=np.array([0.05, 0.0, -0.02, 0.1, 0.0, 0.05]))
    model, data = uvms.model, uvms.model.createData()

    def momentum(x):
        q, v = x[: uvms.nq], x[uvms.nq :]
        pin.computeCentroidalMomentum(model, data, q, v)
        return np.concatenate([data.hg.linear, data.hg.angular]), data.com[0].copy()

    h0, c0 = momentum(x)
    t = 0.0
    for _ in range(100):
        x, info = plant.step(t, x, None, 0.02)
        t += 0.02
    h1, c1 = momentum(x)
    np.testing.assert_allclose(h1, h0, atol=1e-7)
    # the centre of mass drifts with the constant linear momentum
    np.testing.assert_allclose(c1, c0 + h0[:3] / sum(i.mass for i in model.inertias) * t, atol=1e-7)
    qa, va, _ = plant.motion.sample(t)
    np.testing.assert_allclose(x[7 : uvms.nq], qa)  # the arm is where it was told to be
    assert np.abs(x[3:7] - [0, 0, 0, 1]).max() > 1e-2  # and the vehicle moved


@pytest.mark.parametrize("step", [0.02, 0.01])
def test_fourth_order_convergence(step):
    """Halving the step cuts the error about 16 times (RKMK4 with exact joint samples)."""
    uvms = build_uvms("bluerov2-heavy", "alpha5")

    def run(h):
        plant = PrescribedUVMSPlant(uvms, Sines(uvms.n_arm, seed=1), Water(), UVMSPlantConfig(inner_step=h))
        x = plant.initial_state(0.0)
        x, _ = plant.step(0.0, x, None, 0.4)
        return x

    reference = run(step / 8)
    coarse, fine = run(step), run(step / 2)
    ratio = np.linalg.norm(coarse - reference) / np.linalg.norm(fine - reference)
    assert ratio > 10.0, ratio
