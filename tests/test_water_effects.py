"""The water effects beyond the paper's, through the one strip kernel: the energy-consistent
(Kirchhoff) added mass against a second implementation (Kirchhoff's equations per link from
Pinocchio's body velocities and accelerations) and against the conservation laws it must keep, on
the fixed-base, floating, fast and prescribed-motion plants; the axial drag against closed forms
and across the fixed-base, floating and fast paths; bad axial coefficients refused."""

from __future__ import annotations

import copy
import dataclasses
import json

import numpy as np
import pinocchio as pin
import pytest
from test_uvms_prescribed import Sines
from typer.testing import CliRunner

import hydroarm
from hydroarm.cli import app
from hydroarm.model.arm.description import ArmSpec, build_arm
from hydroarm.model.arm.loading import load_arm, load_arm_spec
from hydroarm.model.arm.plant import PlantConfig, UnderwaterPlant
from hydroarm.model.vehicle.fast import FastUVMSConfig, FastUVMSDynamics, FastUVMSPlant
from hydroarm.model.vehicle.plant import UVMSPlant, UVMSPlantConfig
from hydroarm.model.vehicle.prescribed import PrescribedUVMSPlant
from hydroarm.model.vehicle.system import UVMSDynamics, build_uvms
from hydroarm.model.water.morison import CurrentConfig, Water, WaterModel
from hydroarm.model.water.regressor import WaterRegressor

STILL = CurrentConfig(model="none")
ARMS = ["paper", "ur5", "alpha5"]


def kirchhoff_water(model: str = "kirchhoff") -> Water:
    """Only the added mass on (no drag, buoyancy or current)."""
    return Water(drag=False, buoyancy=False, added_mass_model=model, current=STILL)


# --- the Kirchhoff added mass: a second implementation -------------------------------------------


def body_added_inertia(cylinders, water: Water) -> np.ndarray:
    """M_b = int m_a G^T P G ds (6 x 6, the link frame, about its origin; G = [I, -[r]x]): the
    integrand is quadratic in s, 4 Gauss points are exact."""
    out = np.zeros((6, 6))
    nodes, weights = np.polynomial.legendre.leggauss(4)
    for c in cylinders:
        m_a = water.rho * (water.cm if c.cm is None else c.cm) * c.area
        e = c.axis
        normal = np.eye(3) - np.outer(e, e)
        for x, w in zip(nodes, weights, strict=True):
            g = np.hstack([np.eye(3), -pin.skew(c.start + 0.5 * (x + 1.0) * c.length * e)])
            out += 0.5 * c.length * w * m_a * g.T @ normal @ g
    return out


def kirchhoff_equations(arm, water: Water, q, v, a) -> np.ndarray:
    """sum over links of J_b^T w_b, w_b = -(M_b nu' + nu x* M_b nu) with the link's body twist nu
    and its derivative nu' from Pinocchio (forwardKinematics: data.v, data.a, LOCAL)."""
    model, data = arm.model, arm.create_data()
    pin.forwardKinematics(model, data, q, v, a)
    pin.computeJointJacobians(model, data, q)
    out = np.zeros(arm.n_joints)
    for joint in range(1, model.njoints):
        cylinders = [c for c in arm.cylinders if c.joint_id == joint]
        if not cylinders:
            continue
        inertia = body_added_inertia(cylinders, water)
        nu, nu_dot = data.v[joint].vector, data.a[joint].vector
        p = inertia @ nu
        cross = np.concatenate([np.cross(nu[3:], p[:3]), np.cross(nu[3:], p[3:]) + np.cross(nu[:3], p[:3])])
        out += pin.getJointJacobian(model, data, joint, pin.LOCAL).T @ -(inertia @ nu_dot + cross)
    return out


@pytest.mark.parametrize("name", ARMS)
def test_kirchhoff_added_mass_is_kirchhoffs_equations_per_link(name):
    arm = load_arm(name)
    n = arm.n_joints
    water = kirchhoff_water()
    kirchhoff, morison = WaterModel(arm, water), WaterModel(arm, kirchhoff_water("morison"))
    rng = np.random.default_rng(1)
    for _ in range(10):
        q, v, a = rng.uniform(-3.0, 3.0, n), rng.normal(0.0, 2.0, n), rng.normal(0.0, 5.0, n)
        reference = kirchhoff_equations(arm, water, q, v, a)
        scale = np.abs(reference).max()
        got = kirchhoff.torques(q, v, a).added_mass
        assert np.abs(got - reference).max() < 1e-12 * scale  # measured <= 4e-15
        # the inertia is Morison's; the velocity term is not (by 3-23 % of the force here)
        assert np.array_equal(kirchhoff.terms(q, v)[0], morison.terms(q, v)[0])
        assert np.abs(morison.torques(q, v, a).added_mass - reference).max() > 1e-3 * scale


# --- energy and momentum ------------------------------------------------------------------------


def energy_drift(name: str, model: str, inner_step: float) -> float:
    """Largest |E - E0| / |E0| over 1 s from q = 0, v = (1, -1, 1, ...) rad/s, no torque, E = the
    dry energy + 1/2 v' M_A(q) v."""
    arm = load_arm(name)
    n = arm.n_joints
    water = kirchhoff_water(model)
    plant = UnderwaterPlant(arm, water, PlantConfig(inner_step=inner_step))
    added = WaterModel(arm, water)

    def energy(x):
        return plant.energy(x) + 0.5 * x[n:] @ added.terms(x[:n], np.zeros(n))[0] @ x[n:]

    x = np.concatenate([np.zeros(n), np.resize([1.0, -1.0], n)])
    start, worst = energy(x), 0.0
    for k in range(100):
        x, _ = plant.step(0.01 * k, x, np.zeros(n), 0.01)
        worst = max(worst, abs(energy(x) - start) / abs(start))
    return worst


@pytest.mark.parametrize("name", ARMS)
def test_kirchhoff_conserves_energy_and_morison_does_not(name):
    """Drag, buoyancy, current, friction and torques off. Measured (1 ms, 0.5 ms RK4 steps):
    paper 3.7e-8, 2.0e-9; ur5 2.4e-8, 1.5e-9; alpha5 6.1e-8, 3.9e-9: the RK4 error, shrinking as
    h^4 (16x per halving); Morison swings by 137 %, 101 %, 727 % at any step."""
    coarse, fine = energy_drift(name, "kirchhoff", 1e-3), energy_drift(name, "kirchhoff", 5e-4)
    assert coarse < 1e-6
    assert 10.0 < coarse / fine < 30.0
    assert energy_drift(name, "morison", 1e-3) > 0.5


def world_invariants(dynamics: UVMSDynamics, q: np.ndarray, v: np.ndarray) -> tuple[float, np.ndarray]:
    """(kinetic energy 1/2 v' (M + M_A) v, the world momentum of body and water about the world
    origin): the base's rows of (M + M_A) v are its body-frame momentum."""
    mass, _ = dynamics.system(0.0, q, v, np.zeros(dynamics.uvms.nv), np.zeros(dynamics.uvms.vehicle.n_thrusters))
    p = mass @ v
    rot = pin.Quaternion(q[3:7]).toRotationMatrix()
    linear = rot @ p[:3]
    return 0.5 * v @ p, np.concatenate([linear, rot @ p[3:6] + np.cross(q[:3], linear)])


@pytest.mark.parametrize(
    ("plant", "inner_step", "bound"),
    [("reference", 1e-3, 1e-9), ("fast", 1e-3, 1e-9), ("fast", 5e-3, 1e-7)],
)
def test_kirchhoff_on_the_vehicle_conserves_energy_and_momentum(plant, inner_step, bound):
    """The Alpha 5 on the BlueROV2 Heavy, gravity, drag, buoyancy and current off, no thrust or
    torque, from a tumbling start: energy and the world momentum of the system and its water keep
    (measured 3e-12 at 1 ms, 2e-9 at 5 ms); with Morison's added mass they do not (10 %, 24 %)."""
    system = build_uvms("bluerov2-heavy", "alpha5", gravity=0.0)
    drifts = {}
    for model in ("kirchhoff", "morison"):
        water = kirchhoff_water(model)
        if plant == "reference":
            stepper = UVMSPlant(system, water, UVMSPlantConfig(inner_step=inner_step))
        else:
            stepper = FastUVMSPlant(system, water, FastUVMSConfig(inner_step=inner_step))
        dynamics = UVMSDynamics(system, water)
        x = stepper.initial_state(system.neutral(q_arm=[1.0, 1.5, 1.0, 0.5]))
        x[stepper.nq : stepper.nq + system.nv] = [0.05, -0.02, 0.01, 0.2, 0.1, -0.3, 1.0, -1.0, 1.0, -1.0]
        energy0, momentum0 = world_invariants(dynamics, *stepper.split(x)[:2])
        energy_drift = momentum_drift = 0.0
        for k in range(100):
            x, _ = stepper.step(0.01 * k, x, np.zeros(stepper.n_inputs), 0.01)
            energy, momentum = world_invariants(dynamics, *stepper.split(x)[:2])
            energy_drift = max(energy_drift, abs(energy - energy0) / energy0)
            momentum_drift = max(momentum_drift, np.abs(momentum - momentum0).max() / np.abs(momentum0).max())
        drifts[model] = (energy_drift, momentum_drift)
    assert max(drifts["kirchhoff"]) < bound, drifts
    assert min(drifts["morison"]) > 1e-2, drifts


def test_kirchhoff_under_a_prescribed_arm_motion_keeps_the_momentum():
    """The joint torques are internal: the world momentum of vehicle, arm and water keeps (measured
    1e-13 of 1.08 kg m/s); Morison's added mass loses 6 % of it."""
    uvms = build_uvms("bluerov2-heavy", "alpha5", gravity=0.0)
    drift = {}
    for model in ("kirchhoff", "morison"):
        plant = PrescribedUVMSPlant(uvms, Sines(uvms.n_arm, seed=4), kirchhoff_water(model),
                                    UVMSPlantConfig(inner_step=2e-3))  # fmt: skip
        x = plant.initial_state(0.0, twist=np.array([0.05, 0.0, -0.02, 0.1, 0.0, 0.05]))
        momentum0 = world_invariants(plant.dynamics, x[: uvms.nq], x[uvms.nq :])[1]
        worst, t = 0.0, 0.0
        for _ in range(100):
            x, _ = plant.step(t, x, None, 0.02)
            t += 0.02
            worst = max(
                worst, np.abs(world_invariants(plant.dynamics, x[: uvms.nq], x[uvms.nq :])[1] - momentum0).max()
            )
        drift[model] = worst / np.abs(momentum0).max()
    assert drift["kirchhoff"] < 1e-10 and drift["morison"] > 1e-2, drift


def test_kirchhoff_fast_path_equals_the_pinocchio_path():
    system = build_uvms()
    water = Water(added_mass_model="kirchhoff", current=CurrentConfig(model="uniform", mean=[0.2, -0.1, 0.05]))
    exact, fast = UVMSDynamics(system, water), FastUVMSDynamics(system, water, FastUVMSConfig(drag_points=8))
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = pin.integrate(system.model, system.neutral(), rng.normal(size=system.nv))
        v, tau, thrust = rng.normal(size=system.nv), rng.normal(size=system.nv), 10.0 * rng.normal(size=8)
        reference = exact.acceleration(0.3, q, v, tau, thrust)
        got = fast.acceleration(0.3, q, v, tau, thrust)
        assert np.abs(got - reference).max() < 1e-12 * (1.0 + np.abs(reference).max())  # measured 2e-15


def test_the_regressor_follows_the_kirchhoff_water():
    arm = load_arm("paper")
    water = Water(added_mass_model="kirchhoff", current=STILL)
    regressor = WaterRegressor(arm, water)
    plant_water = WaterModel(arm, water)
    theta = regressor.parameters(water)
    rng = np.random.default_rng(3)
    for _ in range(5):
        q, v, a = rng.normal(size=(3, 6))
        truth = plant_water.torques(q, v, a).total
        scale = np.abs(truth).max()
        np.testing.assert_allclose(regressor.basis(q, v, a) @ theta, truth, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(regressor.predict(theta, q, v, a), truth, rtol=0, atol=1e-12 * scale)
        reference = regressor.basis_reference(q, v, a)
        np.testing.assert_allclose(regressor.basis(q, v, a), reference, rtol=0, atol=1e-12 * np.abs(reference).max())


# --- axial drag ---------------------------------------------------------------------------------


def with_axial(arm, coefficient: float):
    """The arm with every cylinder's axial drag coefficient set."""
    cylinders = tuple(dataclasses.replace(c, cd_axial=coefficient) for c in arm.cylinders)
    return dataclasses.replace(arm, cylinders=cylinders)


def test_axial_drag_is_zero_on_a_link_turning_about_a_perpendicular_axis():
    """A rod along x turning about z through its end: every point moves normal to the rod."""
    spec = {"name": "rod", "links": [{"name": "l1", "a": 0.5, "alpha_deg": 0.0, "d": 0.0, "mass": 1.0,
                                     "com": [0.25, 0.0, 0.0], "inertia_axial": 1e-3, "inertia_transverse": 0.02,
                                     "cylinder_diameter": 0.08, "cd_axial": 1.0}], "torque_limit": 10.0}  # fmt: skip
    rod = build_arm(ArmSpec.model_validate(spec))
    plain = with_axial(rod, 0.0)
    water = Water(current=STILL)
    for omega in (-2.0, 0.5, 3.0):
        args = (np.array([0.3]), np.array([omega]), np.zeros(1))
        assert np.array_equal(WaterModel(rod, water).torques(*args).drag, WaterModel(plain, water).torques(*args).drag)


@pytest.mark.parametrize("speed", [0.4, -1.3])
def test_axial_drag_of_cylinders_moving_along_themselves_is_the_closed_form(speed):
    """The vehicle at rest in a current along x, the arm still: each cylinder feels
    -1/2 rho C_a A |u_a| u_a e (u_a = -V.e) at its axis; the vehicle's generalised force is the
    sum of those forces and of their moments about its origin."""
    arm = with_axial(hydroarm.load_arm("alpha5"), 0.9)
    system = build_uvms("bluerov2-heavy", arm)
    current = np.array([speed, 0.0, 0.0])
    water = Water(current=CurrentConfig(model="uniform", mean=current.tolist()))
    q = system.neutral(q_arm=[0.4, 1.1, 0.7, 0.3])
    _, _, force = UVMSDynamics(system, water).arm_water_terms(q, np.zeros(system.nv), drag=False, added_mass=False,
                                                             buoyancy=False, axial=True)  # fmt: skip
    data = system.create_data()
    pin.forwardKinematics(system.model, data, q)
    wrench = np.zeros(6)
    for cylinder in arm.cylinders:
        if cylinder.joint_id == 0:  # on the arm's base: rides on the vehicle at the mount
            placement = data.oMi[1] * system.mount
        else:
            placement = data.oMi[int(system.arm_joint_ids[cylinder.joint_id - 1])]
        e, point = placement.rotation @ cylinder.axis, placement.act(cylinder.start)
        along = -current @ e
        push = -0.5 * water.rho * 0.9 * cylinder.area * abs(along) * along * e
        wrench += np.concatenate([push, np.cross(point, push)])
    assert np.abs(wrench[:3]).max() > 1e-4  # N: there is a force to check
    np.testing.assert_allclose(force[:6], wrench, rtol=0, atol=1e-14)


def test_axial_drag_agrees_on_the_fixed_base_floating_and_fast_paths():
    arm = with_axial(hydroarm.load_arm("alpha5"), 1.2)
    current = CurrentConfig(model="uniform", mean=[0.2, -0.1, 0.3])
    water = Water(current=current)
    # fixed base = floating arm on a base held at the identity (mount at the identity): bit for bit
    system = build_uvms("bluerov2-heavy", arm, mount=pin.SE3.Identity())
    floating, fixed = UVMSDynamics(system, water), WaterModel(arm, water)
    rng = np.random.default_rng(6)
    for _ in range(5):
        q_arm, v_arm = rng.uniform(0.0, 3.0, 4), rng.normal(0.0, 2.0, 4)
        q, v = system.neutral(q_arm=q_arm), np.concatenate([np.zeros(6), v_arm])
        _, _, force = floating.arm_water_terms(q, v, 0.5)
        assert np.array_equal(force[6:], fixed.terms(q_arm, v_arm, 0.5)[2])
        without = WaterModel(with_axial(arm, 0.0), water).terms(q_arm, v_arm, 0.5)[2]
        assert np.abs(force[6:] - without).max() > 1e-6  # N m: the axial drag is in it
    # the fast path (body frames) against the Pinocchio path
    system = build_uvms("bluerov2-heavy", arm)
    exact, fast = UVMSDynamics(system, water), FastUVMSDynamics(system, water, FastUVMSConfig(drag_points=8))
    plain = FastUVMSDynamics(build_uvms("bluerov2-heavy", with_axial(arm, 0.0)), water, FastUVMSConfig(drag_points=8))
    for _ in range(5):
        q = pin.integrate(system.model, system.neutral(), rng.normal(size=system.nv))
        v, tau, thrust = rng.normal(size=system.nv), rng.normal(size=system.nv), 10.0 * rng.normal(size=8)
        reference = exact.acceleration(0.3, q, v, tau, thrust)
        got = fast.acceleration(0.3, q, v, tau, thrust)
        assert np.abs(got - reference).max() < 1e-12 * (1.0 + np.abs(reference).max())
        assert np.abs(got - plain.acceleration(0.3, q, v, tau, thrust)).max() > 1e-6


def test_arm_files_carry_the_axial_coefficient(tmp_path):
    spec = load_arm_spec("paper").model_dump()
    spec["links"][2]["cd_axial"] = 0.8
    path = tmp_path / "axial.yaml"
    path.write_text(json.dumps(spec))  # JSON is YAML
    assert [c.cd_axial for c in load_arm(path).cylinders] == [0.0, 0.0, 0.8, 0.0, 0.0, 0.0]
    assert all(c.cd_axial == 0.0 for c in load_arm("alpha5").cylinders)


RUNNER = CliRunner()


@pytest.mark.parametrize("value", [-0.5, 11.0])
def test_a_bad_axial_coefficient_exits_2_naming_the_field_and_its_range(tmp_path, value):
    spec = load_arm_spec("paper").model_dump()
    spec["links"][1]["cd_axial"] = value
    path = tmp_path / "bad.yaml"
    path.write_text(json.dumps(spec))
    result = RUNNER.invoke(app, ["export-urdf", str(path)])
    assert result.exit_code == 2, (result.output, result.exception)
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "links.1.cd_axial" in lines[0] and str(value) in lines[0], result.output
    assert ("greater than or equal to 0" if value < 0 else "less than or equal to 10") in lines[0]


def test_a_bad_axial_coefficient_in_a_hydrodynamics_file_names_its_field():
    from test_urdf_import import generated_urdf

    from hydroarm.config import ConfigError
    from hydroarm.model.arm.urdf_import import arm_from_urdf

    hydro = {"fixed_joints": {"gripper": 0.0},
             "links": [{"link": "l1", "cylinders": [{"diameter": 0.05, "length": 0.2, "axis": [0, 0, 1],
                                                     "cd_axial": 12.0}]}]}  # fmt: skip
    with pytest.raises(ConfigError, match=r"links.0.cylinders.0.cd_axial = 12.0: Input should be less than or equal"):
        arm_from_urdf(generated_urdf(4, seed=1), copy.deepcopy(hydro), source="gen.hydro.toml")
    hydro["links"][0]["cylinders"][0]["cd_axial"] = 0.7
    arm = arm_from_urdf(generated_urdf(4, seed=1), hydro, source="gen.hydro.toml")
    assert [c.cd_axial for c in arm.cylinders] == [0.7]


def test_the_reynolds_drag_runs_on_the_vehicle_paths_alike():
    """The same strip kernel everywhere: the Reynolds drag, once refused on a floating base, gives
    the same accelerations on the fast and the Pinocchio vehicle paths, and another than C_d = 1."""
    system = build_uvms()
    current = CurrentConfig(model="uniform", mean=[0.3, -0.1, 0.05])
    water = Water(drag_model="reynolds", current=current)
    exact, fast = UVMSDynamics(system, water), FastUVMSDynamics(system, water, FastUVMSConfig(drag_points=8))
    constant = UVMSDynamics(system, Water(current=current))
    rng = np.random.default_rng(8)
    for _ in range(5):
        q = pin.integrate(system.model, system.neutral(), rng.normal(size=system.nv))
        v, tau, thrust = rng.normal(size=system.nv), rng.normal(size=system.nv), 10.0 * rng.normal(size=8)
        reference = exact.acceleration(0.3, q, v, tau, thrust)
        assert np.abs(fast.acceleration(0.3, q, v, tau, thrust) - reference).max() < 1e-12 * (
            1.0 + np.abs(reference).max()
        )
        assert np.abs(constant.acceleration(0.3, q, v, tau, thrust) - reference).max() > 1e-6


@pytest.mark.parametrize("points", [2, 3, 8])
def test_kirchhoff_body_wrench_in_closed_form_is_the_gauss_sum(points):
    """The body frame's closed-form Kirchhoff wrench (the compiled arm's and the vehicle's path)
    is the Gauss sum the world frame takes, to round-off: its integrands are of degree <= 2 in s,
    which two points or more integrate exactly; with one point (the midpoint rule) they differ."""
    from hydroarm.model.water import effects

    rng = np.random.default_rng(points)

    def wrenches(count):
        nodes, weights = np.polynomial.legendre.leggauss(count)
        frame = effects.new_frame(6, True, 0.5 * (nodes + 1.0), 0.5 * weights, np.zeros(1), np.zeros(1))
        axis = rng.normal(size=3)
        frame[effects.E, :3] = axis / np.linalg.norm(axis)
        for row in (effects.P0, effects.VEL0, effects.VELR, effects.OM):
            frame[row, :3] = rng.normal(size=3)
        frame[effects.CYL, effects.LENGTH] = length = 0.37
        gauss, closed = np.zeros(6), np.zeros(6)
        effects.kirchhoff_bias(frame, -1.7 * length, gauss)
        effects._kirchhoff_wrench(1.7, length, frame, closed)
        return gauss, closed

    gauss, closed = wrenches(points)
    assert np.allclose(closed, gauss, rtol=1e-13, atol=1e-13 * np.abs(gauss).max()), (closed, gauss)
    assert np.abs(gauss).max() > 0.1
    midpoint, exact = wrenches(1)
    assert not np.allclose(midpoint, exact, rtol=1e-6)
