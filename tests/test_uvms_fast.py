"""The compiled UVMS path (hydroarm.model.vehicle.fast) against the reference path (uvms, uvms_plant)."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from hydroarm.model.vehicle.fast import FastUVMSConfig, FastUVMSDynamics, FastUVMSPlant, cylinder_added_inertia
from hydroarm.model.vehicle.plant import UVMSPlant
from hydroarm.model.vehicle.system import UVMSDynamics, build_uvms
from hydroarm.model.water.morison import CurrentConfig, Water

CURRENT = Water(current=CurrentConfig(model="uniform", mean=[0.2, -0.1, 0.05]))


@pytest.fixture(scope="module")
def system():
    return build_uvms()


@pytest.mark.parametrize("water", [Water().off(), CURRENT], ids=["dry", "water"])
def test_acceleration_equals_the_reference_path(system, water):
    """8 drag points: the same physics as the Pinocchio + strips path, to round-off."""
    exact = UVMSDynamics(system, water)
    fast = FastUVMSDynamics(system, water, FastUVMSConfig(drag_points=8))
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = pin.integrate(system.model, system.neutral(), rng.normal(size=system.nv))
        v, tau, thrust = rng.normal(size=system.nv), rng.normal(size=system.nv), 10.0 * rng.normal(size=8)
        reference = exact.acceleration(0.3, q, v, tau, thrust)
        assert np.max(np.abs(fast.acceleration(0.3, q, v, tau, thrust) - reference)) < 1e-12 * (
            1.0 + np.max(np.abs(reference))
        )


def test_added_inertia_is_the_strips_added_mass(system):
    """J_b^T I_A J_b of each cylinder, summed: the strips' M_A (base at rest, arm anywhere)."""
    water = Water()
    exact = UVMSDynamics(system, water)
    fast = FastUVMSDynamics(system, water)
    q = system.neutral(q_arm=[0.3, 1.2, -0.4, 0.8])
    added, _, _ = exact.arm_water_terms(q, np.zeros(system.nv), drag=False, added_mass=True, buoyancy=False)
    data = system.create_data()
    pin.computeJointJacobians(system.model, data, q)
    total = np.zeros((system.nv, system.nv))
    for body in range(1, system.model.njoints):
        jac = pin.getJointJacobian(system.model, data, body, pin.ReferenceFrame.LOCAL)
        total += jac.T @ (fast.total[body] - fast.rigid[body]) @ jac
    total[:6, :6] -= system.vehicle.added_mass
    assert np.allclose(total, added, rtol=0, atol=1e-12)
    single = cylinder_added_inertia(np.zeros(3), np.array([1.0, 0.0, 0.0]), 2.0, 3.0)
    assert np.allclose(np.diag(single)[:3], [0.0, 6.0, 6.0]) and np.allclose(single, single.T)


def _run(plant, system, steps=150):
    x = plant.initial_state(system.neutral(q_arm=[1.5, 1.0, 1.0, 0.5]))
    out = []
    for k in range(steps):
        t = 0.01 * k
        target = np.array([1.5 + 0.8 * math.sin(2 * t), 1.0 + 0.5 * math.sin(3 * t), 1.0, 0.5 * math.sin(t)])
        tau = np.array([0.3, 0.3, 0.1, 0.002]) * (target - x[7:11]) - np.array([0.05, 0.05, 0.02, 3e-4]) * x[17:21]
        x, info = plant.step(t, x, np.concatenate([tau, 10.0 * np.sin(np.arange(8) + t)]), 0.01)
        out.append(x)
    return np.array(out), info


def test_step_equals_the_reference_plant_and_the_default_is_close(system):
    reference, info = _run(UVMSPlant(system, CURRENT), system)
    same, info_fast = _run(FastUVMSPlant(system, CURRENT, FastUVMSConfig(inner_step=1e-3, drag_points=8)), system)
    assert np.max(np.abs(same - reference)) < 1e-9
    assert np.allclose(info.thrust_wrench, info_fast.thrust_wrench, rtol=0, atol=1e-12)
    default, _ = _run(FastUVMSPlant(system, CURRENT), system)  # 5 ms steps, 3 drag points
    assert np.max(np.abs(default[:, :3] - reference[:, :3])) < 1e-5  # m
    assert np.max(np.abs(default[:, 7:11] - reference[:, 7:11])) < 1e-4  # rad


def test_arm_switches_only_touch_the_arm(system):
    """Arm buoyancy off: the only change of the acceleration is the buoyancy's generalised force."""
    q = system.neutral(q_arm=[0.3, 1.2, -0.4, 0.8])
    v = np.zeros(system.nv)
    water = Water(drag=False, added_mass=False)
    on = FastUVMSDynamics(system, water).acceleration(0.0, q, v, np.zeros(system.nv), np.zeros(8))
    off = FastUVMSDynamics(system, water, FastUVMSConfig(arm_buoyancy=False)).acceleration(
        0.0, q, v, np.zeros(system.nv), np.zeros(8)
    )
    _, _, buoyancy = UVMSDynamics(system, water).arm_water_terms(q, v, drag=False, added_mass=False, buoyancy=True)
    data = system.create_data()
    mass = pin.crba(system.model, data, q)
    mass = np.triu(mass) + np.triu(mass, 1).T
    assert np.allclose(mass @ (on - off), buoyancy, rtol=0, atol=1e-10)


def test_the_compiled_step_clips_the_thrust_command_as_np_clip(system):
    """The command's clip runs inside the compiled step with np.clip's arithmetic: commands beyond
    the limits, at them, signed zeros and infinities step bit for bit as the command np.clip gives;
    a u of the wrong length is refused."""
    plant = FastUVMSPlant(system, CURRENT)
    vehicle = system.vehicle
    x = plant.initial_state(system.neutral(q_arm=[1.5, 1.0, 1.0, 0.5]))
    command = np.array([1e3, -1e3, vehicle.thrust_max[2], vehicle.thrust_min[3], -0.0, 0.0, np.inf, -np.inf])
    u = np.r_[0.1, -0.1, 0.05, 0.0, command]
    clipped = np.r_[u[:4], np.clip(command, vehicle.thrust_min, vehicle.thrust_max)]
    stepped, info = plant.step(0.0, x, u, 0.01)
    expected, expected_info = plant.step(0.0, x, clipped, 0.01)
    assert np.array_equal(stepped, expected)
    assert np.array_equal(info.thrust_wrench, expected_info.thrust_wrench)
    with pytest.raises(ValueError, match="u: expected"):
        plant.step(0.0, x, u[:-1], 0.01)
