"""The floating vehicle-manipulator system: momentum, the fixed-base limit of the arm's water,
an independent per-point path on a moving base, the Lie-group integrator."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

import hydroarm
from hydroarm.model.vehicle.plant import UVMSPlant, integrate_configuration
from hydroarm.model.vehicle.system import ROOT_JOINT, UVMSDynamics, build_uvms
from hydroarm.model.water.morison import CurrentConfig, Water, WaterModel

GAINS_P = np.array([0.3, 0.3, 0.1, 0.002])
GAINS_D = np.array([0.05, 0.05, 0.02, 0.0003])
CURRENT = CurrentConfig(model="uniform", mean=[0.2, -0.1, 0.05])


@pytest.fixture(scope="module")
def alpha5():
    return hydroarm.load_arm("alpha5")


@pytest.fixture(scope="module")
def system(alpha5):
    return build_uvms("bluerov2_heavy", alpha5)


def _pd(q_arm, v_arm, t):
    """Joint torques toward a moving target (internal forces of the system); gains soft enough
    for a 10 ms zero-order hold on the wrist's 6e-5 kg m^2."""
    target = np.array([1.5 + 0.8 * math.sin(2.0 * t), 1.0 + 0.5 * math.sin(3.0 * t), 1.0, 0.5 * math.sin(t)])
    return GAINS_P * (target - q_arm) - GAINS_D * v_arm


def test_integrate_configuration_is_pinocchios(system):
    rng = np.random.default_rng(3)
    q = pin.integrate(system.model, system.neutral(), rng.normal(size=system.nv))
    for scale in (1.0, 1e-3, 1e-7):
        xi = rng.normal(size=system.nv) * scale
        out = np.empty(system.nq)
        integrate_configuration(q, xi, out)
        assert np.max(np.abs(out - pin.integrate(system.model, q, xi))) < 1e-14


def test_dry_dynamics_is_pinocchios_aba(alpha5):
    system = build_uvms("bluerov2_heavy", alpha5, gravity=9.81)
    dynamics = UVMSDynamics(system, Water().off())
    rng = np.random.default_rng(4)
    for _ in range(5):
        q = pin.integrate(system.model, system.neutral(), rng.normal(size=system.nv))
        v, tau = rng.normal(size=system.nv), rng.normal(size=system.nv)
        tau[:6] = 0.0
        acc = dynamics.acceleration(0.0, q, v, tau, np.zeros(8))
        assert np.allclose(acc, pin.aba(system.model, system.create_data(), q, v, tau), rtol=0, atol=1e-10)


def test_free_floating_system_conserves_momentum(alpha5):
    """Water and gravity off: the arm moves under joint torques, the base counter-moves, and the
    spatial momentum (Pinocchio's centroidal momentum) stays put."""
    system = build_uvms("bluerov2_heavy", alpha5, gravity=0.0)
    plant = UVMSPlant(system, Water().off())
    data = system.create_data()
    x = plant.initial_state(system.neutral(q_arm=[1.0, 1.5, 1.0, 0.5]))
    x[plant.nq : plant.nq + 6] = [0.05, -0.02, 0.01, 0.02, 0.01, -0.03]

    def momentum(x):
        q, v, _ = plant.split(x)
        return pin.computeCentroidalMomentum(system.model, data, q, v).vector.copy()

    start = momentum(x)
    drift = 0.0
    for k in range(200):
        t = 0.01 * k
        q, v, _ = plant.split(x)
        x, _ = plant.step(t, x, np.concatenate([_pd(q[7:], v[6:], t), np.zeros(8)]), 0.01)
        drift = max(drift, float(np.max(np.abs(momentum(x) - start))))
    q, v, _ = plant.split(x)
    assert drift < 1e-9, drift  # measured 5e-13 (linear momentum ~0.8 kg m/s)
    assert np.max(np.abs(v[6:])) > 0.1  # the arm moved ...
    assert np.max(np.abs(v[:6] - [0.05, -0.02, 0.01, 0.02, 0.01, -0.03])) > 1e-3  # ... and the base answered


def test_fixed_base_arm_water_equals_the_fixed_base_model_exactly(alpha5):
    """Base held at the identity, mount at the identity, base velocity zero: the arm's rows and
    columns of the floating strip integrals are the fixed-base WaterModel's, bit for bit."""
    system = build_uvms("bluerov2_heavy", alpha5, mount=pin.SE3.Identity())
    water = Water(current=CURRENT)
    floating = UVMSDynamics(system, water)
    fixed = WaterModel(alpha5, water)
    rng = np.random.default_rng(5)
    for _ in range(20):
        q_arm, v_arm, a_arm = rng.uniform(0.0, 3.0, 4), rng.normal(0.0, 2.0, 4), rng.normal(0.0, 5.0, 4)
        t = float(rng.uniform(0.0, 10.0))
        q, v = system.neutral(q_arm=q_arm), np.concatenate([np.zeros(6), v_arm])
        mass, bias, force = floating.arm_water_terms(q, v, t)
        mass0, bias0, force0 = fixed.terms(q_arm, v_arm, t)
        assert np.array_equal(mass[6:, 6:], mass0)
        assert np.array_equal(bias[6:], bias0)
        assert np.array_equal(force[6:], force0)
        torques = fixed.torques(q_arm, v_arm, a_arm, t)
        _, _, drag = floating.arm_water_terms(q, v, t, drag=True, added_mass=False, buoyancy=False)
        _, _, buoyancy = floating.arm_water_terms(q, v, t, drag=False, added_mass=False, buoyancy=True)
        assert np.array_equal(drag[6:], torques.drag) and np.array_equal(buoyancy[6:], torques.buoyancy)
        assert np.array_equal(-(mass[6:, 6:] @ a_arm) - bias[6:], torques.added_mass)


def _per_point(system, water, q, v, a, t, points=4000):
    """The arm's water generalised forces by a composite midpoint rule over points whose
    velocity, classical acceleration and Jacobian come from Pinocchio's joint quantities."""
    model, data = system.model, system.create_data()
    pin.forwardKinematics(model, data, q, v, a)
    pin.computeJointJacobians(model, data, q)
    current = np.asarray(CURRENT.mean) if water.current.model == "uniform" else np.zeros(3)
    out = np.zeros(system.nv)
    for cylinder in system.arm.cylinders:
        if cylinder.joint_id == 0:  # fixed to the arm's base: rides on the vehicle
            joint, offset = ROOT_JOINT, system.mount
        else:
            joint, offset = int(system.arm_joint_ids[cylinder.joint_id - 1]), pin.SE3.Identity()
        placement = data.oMi[joint]
        rot = placement.rotation
        vel, acc = data.v[joint], data.a[joint]
        jac = pin.getJointJacobian(model, data, joint, pin.ReferenceFrame.LOCAL)
        axis_local = offset.rotation @ cylinder.axis
        e = rot @ axis_local
        normal = np.eye(3) - np.outer(e, e)
        length, width = cylinder.length, cylinder.length / points
        drag_coefficient = 0.5 * water.rho * water.cd * cylinder.diameter
        mass_coefficient = water.rho * water.cm * cylinder.area
        for s in (np.arange(points) + 0.5) * width:
            p = offset.act(cylinder.start) + s * axis_local
            point_velocity = rot @ (vel.linear + np.cross(vel.angular, p))
            point_acc = rot @ (
                acc.linear + np.cross(acc.angular, p) + np.cross(vel.angular, vel.linear + np.cross(vel.angular, p))
            )
            jac_point = rot @ (jac[:3] - pin.skew(p) @ jac[3:])
            relative = normal @ (point_velocity - current)
            force = -drag_coefficient * np.linalg.norm(relative) * relative
            force -= mass_coefficient * (normal @ point_acc)
            out += jac_point.T @ force * width
        middle = offset.act(cylinder.start) + 0.5 * length * axis_local
        jac_middle = rot @ (jac[:3] - pin.skew(middle) @ jac[3:])
        out += jac_middle.T @ np.array([0.0, 0.0, water.rho * water.gravity * cylinder.displaced_volume])
    return out


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_moving_base_strips_equal_a_per_point_path(system, seed):
    water = Water(current=CURRENT)
    dynamics = UVMSDynamics(system, water)
    rng = np.random.default_rng(seed)
    q = pin.integrate(system.model, system.neutral(), rng.normal(size=system.nv))
    v = np.concatenate([rng.normal(0.0, 0.5, 6), rng.normal(0.0, 2.0, 4)])
    a = rng.normal(0.0, 3.0, system.nv)
    mass, bias, force = dynamics.arm_water_terms(q, v, 0.0)
    kernel = force - mass @ a - bias
    reference = _per_point(system, water, q, v, a, 0.0)
    # measured 5e-11 to 1.1e-10 relative (4000 midpoints against 8 Gauss points split at the kink)
    assert np.max(np.abs(kernel - reference)) < 1e-8 * np.max(np.abs(reference)), (kernel, reference)
    assert np.max(np.abs(kernel[:6])) > 1e-3  # the base rows carry the arm's water too


def test_floating_system_in_current_stays_finite_and_drifts_downstream(system):
    """Full water on arm and vehicle, a 0.2 m/s current along x, no thrust: the added mass is
    in the solved matrix, so 1 ms RK4 steps are stable; the system drifts with the current."""
    water = Water(current=CurrentConfig(model="uniform", mean=[0.2, 0.0, 0.0]))
    plant = UVMSPlant(system, water)
    x = plant.initial_state(system.neutral(q_arm=[1.5, 1.0, 1.0, 0.5]))
    for k in range(100):
        t = 0.01 * k
        q, v, _ = plant.split(x)
        x, _ = plant.step(t, x, np.concatenate([_pd(q[7:], v[6:], t), np.zeros(8)]), 0.01)
    q, v, _ = plant.split(x)
    assert np.all(np.isfinite(x))
    assert q[0] > 0.005 and v[0] > 0.0  # pushed downstream (body x is world x: small attitude change)
