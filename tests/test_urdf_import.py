"""Bring your own arm: URDF + hydrodynamics file -> Arm (round trip, built-in Alpha 5, generated arms)."""

from __future__ import annotations

import json
import math

import numpy as np
import pinocchio as pin
import pytest

import hydroarm
from hydroarm.config import ConfigError
from hydroarm.model.arm.loading import BUILTIN_ARMS, builtin_arm_path, load_arm_spec
from hydroarm.model.arm.plant import UnderwaterPlant
from hydroarm.model.arm.urdf_export import arm_to_urdf
from hydroarm.model.arm.urdf_import import arm_from_urdf, hydro_spec_of, load_urdf_arm
from hydroarm.model.task.references import SinusoidReference
from hydroarm.model.water.morison import CurrentConfig, Water, WaterModel, added_mass_matrix, hydrodynamic_torques
from hydroarm.sim.experiment import ExperimentConfig, build_controller
from hydroarm.sim.runner import run_closed_loop

RNG = np.random.default_rng(2023_1641)


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(float(value)) if isinstance(value, float) else str(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, dict):
        return "{" + ", ".join(f"{key} = {_toml_value(item)}" for key, item in value.items()) + "}"
    return "[" + ", ".join(_toml_value(item) for item in value) + "]"


def to_toml(data: dict) -> str:
    """A TOML file of inline values (the test extras carry no TOML writer)."""
    return "".join(f"{key} = {_toml_value(value)}\n" for key, value in data.items())


CURRENT = CurrentConfig(model="uniform", mean=[0.3, -0.2, 0.1], amplitude=[0.1, 0.0, 0.05], frequency_hz=0.2)


def _states(n: int, count: int, rng=RNG):
    return [(rng.uniform(-math.pi, math.pi, n), rng.normal(0.0, 2.0, n), rng.normal(0.0, 5.0, n)) for _ in range(count)]


# --- the paper arm, exported and re-loaded ----------------------------------------


@pytest.fixture(scope="module")
def paper_pair(tmp_path_factory):
    arm = hydroarm.load_arm("paper")
    folder = tmp_path_factory.mktemp("paper_urdf")
    urdf = folder / "paper.urdf"
    urdf.write_text(arm_to_urdf(arm))
    (folder / "paper.hydro.toml").write_text(to_toml(hydro_spec_of(arm)))
    return arm, hydroarm.load_arm(urdf)  # load_arm dispatches on .urdf and finds the .hydro.toml


def test_round_trip_identical_dynamics(paper_pair):
    arm, again = paper_pair
    assert again.n_joints == 6 and len(again.cylinders) == 6
    np.testing.assert_array_equal(again.torque_limit, arm.torque_limit)
    np.testing.assert_allclose(again.position_limit, [[-2 * math.pi, 2 * math.pi]] * 6, rtol=1e-15)
    for q, v, _ in _states(6, 10):
        np.testing.assert_allclose(again.mass_matrix(q), arm.mass_matrix(q), rtol=0, atol=1e-10)
        np.testing.assert_allclose(again.gravity(q), arm.gravity(q), rtol=0, atol=1e-10)
        np.testing.assert_allclose(again.coriolis_matrix(q, v), arm.coriolis_matrix(q, v), rtol=0, atol=1e-10)


def test_round_trip_identical_water(paper_pair):
    arm, again = paper_pair
    for water in (Water(), Water(current=CURRENT), Water(cd=1.3, cm=1.0, quadrature_points=5)):
        model_a, model_b = WaterModel(arm, water), WaterModel(again, water)
        for q, v, a in _states(6, 8):
            t = float(RNG.uniform(0.0, 10.0))
            wa, wb = model_a.torques(q, v, a, t), model_b.torques(q, v, a, t)
            for part in ("drag", "added_mass", "buoyancy"):
                np.testing.assert_allclose(getattr(wb, part), getattr(wa, part), rtol=0, atol=1e-10, err_msg=part)
            qdd_a, _ = model_a.dynamics(q, v, a * 10.0, t)
            qdd_b, _ = model_b.dynamics(q, v, a * 10.0, t)
            np.testing.assert_allclose(qdd_b, qdd_a, rtol=0, atol=1e-9)


def test_round_trip_with_explicit_cylinders_and_overrides():
    """The same through explicit cylinders (start/end) and per-cylinder C_d/C_m overrides."""
    import dataclasses

    base = hydroarm.load_arm("paper")
    cylinders = tuple(
        dataclasses.replace(c, cd=0.7 + 0.1 * k, cm=1.5 if k % 2 else None) for k, c in enumerate(base.cylinders)
    )
    arm = hydroarm.Arm(name="paper", model=base.model, cylinders=cylinders, torque_limit=base.torque_limit)
    again = arm_from_urdf(arm_to_urdf(arm), hydro_spec_of(arm, use_collision=False))
    for q, v, a in _states(6, 4):
        wa = hydrodynamic_torques(arm, Water(current=CURRENT), q, v, a, 1.0)
        wb = hydrodynamic_torques(again, Water(current=CURRENT), q, v, a, 1.0)
        np.testing.assert_allclose(wb.total, wa.total, rtol=0, atol=1e-10)


# --- the built-in Reach Alpha 5 -------------------------------------------------------


@pytest.fixture(scope="module")
def alpha5():
    return hydroarm.load_arm("alpha5")


def test_alpha5_is_a_builtin(alpha5):
    assert "alpha5" in BUILTIN_ARMS
    assert builtin_arm_path("alpha5").name == "alpha5.hydro.toml"
    assert alpha5.n_joints == 4
    assert [alpha5.model.names[i] for i in range(1, 5)] == ["axis_e", "axis_d", "axis_c", "axis_b"]
    np.testing.assert_allclose(alpha5.position_limit, [[0.0, 6.3], [0.0, 3.8], [0.0, 3.5], [0.0, 6.2]])
    np.testing.assert_allclose(alpha5.torque_limit, 9.0)
    # masses [M] (the jaw's push rod is massless), displaced volume matched to the datasheet (1.0e-3 m^3)
    assert sum(alpha5.model.inertias[i].mass for i in range(alpha5.model.njoints)) == pytest.approx(1.412)
    assert sum(c.displaced_volume for c in alpha5.cylinders) == pytest.approx(1.0e-3, rel=1e-6)
    assert all(c.diameter == pytest.approx(0.04) for c in alpha5.cylinders if not c.name.startswith("jaws"))
    with pytest.raises(ConfigError, match="URDF arm"):
        load_arm_spec("alpha5")


def test_alpha5_kinematics(alpha5):
    """The maker's ~0.4 m reach: the jaw tip's largest distance from the shoulder over the
    shoulder/elbow ranges is 0.38 m (0.43 m from the base origin)."""
    names = [c.name for c in alpha5.cylinders]
    jaw = names.index("jaws_base_link")
    best = 0.0
    for q_d in np.linspace(0.0, 3.8, 20):
        for q_c in np.linspace(0.0, 3.5, 20):
            q = np.array([0.0, q_d, q_c, 0.0])
            tip = alpha5.cylinder_endpoints(q)[jaw, 1]
            best = max(best, float(np.linalg.norm(tip - alpha5.joint_placements(q)[1].translation)))
    assert 0.36 < best < 0.40
    # the jaw cylinder lies along the wrist roll axis: rolling it moves nothing
    q = np.array([0.3, 1.0, 2.0, 0.0])
    rolled = q + [0.0, 0.0, 0.0, 1.0]
    np.testing.assert_allclose(alpha5.cylinder_endpoints(rolled)[jaw], alpha5.cylinder_endpoints(q)[jaw], atol=1e-12)


def test_alpha5_every_controller_runs(alpha5):
    """SMC, MPC and GP-MPC run on the 4-joint arm unchanged (a short run on a scaled reference)."""
    limits = alpha5.position_limit
    reference = SinusoidReference(
        offset=limits.mean(axis=1),
        cos_amp=np.array([[0.3, 0.0], [0.0, 0.2], [0.2, 0.0], [0.0, 0.3]]),
        sin_amp=np.array([[0.0, 0.2], [0.3, 0.0], [0.0, 0.0], [0.1, 0.0]]),
        omega=np.ones((4, 2)) * [0.5, 1.0],
    )
    config = ExperimentConfig(arm="alpha5")
    x0 = np.concatenate([reference.sample(0.0)[0], np.zeros(4)])
    for name in ("SMC", "MPC", "GP-MPC"):
        plant = UnderwaterPlant(alpha5, Water())
        traj = run_closed_loop(plant, build_controller(name, alpha5, config), reference, 0.3, x0=x0)
        assert not traj.diverged and np.all(np.isfinite(traj.x)), name
        assert np.max(np.abs(traj.q_ref - traj.q)) < 0.2, name


# --- generated URDF arms with 4 and 7 joints ---------------------------------------------


def generated_urdf(n_joints: int, seed: int) -> str:
    """A serial URDF arm: joint axes x, y, z, -z and tilted ones in turn; every other link has a
    fixed child link carrying a second collision cylinder; joint 2 is continuous; a prismatic
    'gripper' at the end (locked by the hydrodynamics file)."""
    rng = np.random.default_rng(seed)
    axes = ["1 0 0", "0 1 0", "0 0 1", "0 0 -1", "0.6 0.8 0", "0 0.28 0.96"]
    parts = ['<?xml version="1.0"?>', '<robot name="gen">', '  <link name="base"/>']
    parent = "base"
    for i in range(1, n_joints + 1):
        length = rng.uniform(0.15, 0.4)
        radius = rng.uniform(0.02, 0.05)
        mass = rng.uniform(0.5, 3.0)
        kind = "continuous" if i == 2 else "revolute"
        limit = (
            ""
            if kind == "continuous"
            else f'<limit lower="{-2.5 + 0.1 * i}" upper="{2.5 - 0.1 * i}" effort="{40 + i}" velocity="2"/>'
        )
        if kind == "continuous":
            limit = '<limit effort="42" velocity="2"/>'
        rpy = " ".join(f"{x:.6f}" for x in rng.uniform(-0.4, 0.4, 3))
        parts += [
            f'  <joint name="j{i}" type="{kind}"><parent link="{parent}"/><child link="l{i}"/>',
            f'    <origin xyz="0 0 {0.05 if i == 1 else 0.0}" rpy="{rpy}"/><axis xyz="{axes[(i - 1) % len(axes)]}"/>{limit}',
            "  </joint>",
            f'  <link name="l{i}"><inertial><origin xyz="0 0 {length / 2:.6f}"/><mass value="{mass:.6f}"/>',
            f'    <inertia ixx="{mass * length**2 / 12:.6e}" iyy="{mass * length**2 / 12:.6e}" izz="{mass * radius**2 / 2:.6e}" ixy="0" ixz="0" iyz="0"/></inertial>',
            f'    <collision><origin xyz="0 0 {length / 2:.6f}" rpy="0 0 0"/><geometry><cylinder radius="{radius:.6f}" length="{length:.6f}"/></geometry></collision>',
            '    <collision><geometry><box size="0.01 0.01 0.01"/></geometry></collision>',
            "  </link>",
        ]
        if i % 2 == 0:  # a fixed side pod with its own cylinder
            parts += [
                f'  <joint name="pod{i}_joint" type="fixed"><parent link="l{i}"/><child link="pod{i}"/>',
                f'    <origin xyz="0.03 0 {length / 2:.6f}" rpy="0 1.2 0.3"/></joint>',
                f'  <link name="pod{i}"><inertial><mass value="0.2"/><inertia ixx="1e-4" iyy="1e-4" izz="1e-4" ixy="0" ixz="0" iyz="0"/></inertial>',
                '    <collision><origin xyz="0 0 0.05" rpy="0.3 0 0"/><geometry><cylinder radius="0.015" length="0.1"/></geometry></collision></link>',
            ]
        # the next joint sits at the end of this link
        parts.append(
            f'  <link name="l{i}_end"/><joint name="l{i}_end_joint" type="fixed"><parent link="l{i}"/><child link="l{i}_end"/><origin xyz="0 0 {length:.6f}"/></joint>'
        )
        parent = f"l{i}_end"
    parts += [
        f'  <joint name="gripper" type="prismatic"><parent link="{parent}"/><child link="finger"/><axis xyz="0 0 1"/>',
        '    <limit lower="0" upper="0.02" effort="5" velocity="1"/></joint>',
        '  <link name="finger"><inertial><mass value="0.1"/><inertia ixx="1e-5" iyy="1e-5" izz="1e-5" ixy="0" ixz="0" iyz="0"/></inertial>',
        '    <collision><origin xyz="0 0 0.04"/><geometry><cylinder radius="0.01" length="0.08"/></geometry></collision></link>',
        "</robot>",
    ]
    return "\n".join(parts)


GENERATED_HYDRO = {
    "fixed_joints": {"gripper": 0.01},
    "all_collision_cylinders": True,
    "links": [{"link": "l1", "collision": [0], "cd": 1.2, "cm": 1.0, "displaced_volume": 2.0e-3}],
}


def _buoyancy_closed_form(arm: hydroarm.Arm, water: Water, q: np.ndarray) -> np.ndarray:
    """Buoyancy = G_b(q), the torque that would hold point masses rho V at the cylinder midpoints
    up against gravity (the displaced water pushes up with exactly that): an independent
    Pinocchio model of the displaced water, G from RNEA."""
    model = arm.model.copy()
    for joint_id in range(model.njoints):
        model.inertias[joint_id] = pin.Inertia.Zero()
    for c in arm.cylinders:
        point = pin.Inertia(water.rho * c.displaced_volume, 0.5 * (c.start + c.end), np.zeros((3, 3)))
        model.inertias[c.joint_id] = model.inertias[c.joint_id] + point
    model.gravity = pin.Motion(np.array([0.0, 0.0, -water.gravity]), np.zeros(3))
    return pin.computeGeneralizedGravity(model, model.createData(), q)


def _added_mass_by_points(arm: hydroarm.Arm, water: Water, q: np.ndarray, points: int = 4) -> np.ndarray:
    """M_A = sum_c int rho C_m A J_p^T (I - e e^T) J_p ds with Pinocchio's point Jacobians at
    Gauss points (an independent path: no kernel, no affine-in-s algebra; the integrand is a
    quadratic in s, so 4 points are exact)."""
    model, data = arm.model, arm.model.createData()
    pin.forwardKinematics(model, data, q)
    pin.computeJointJacobians(model, data, q)
    total = np.zeros((arm.n_joints, arm.n_joints))
    for c in arm.cylinders:
        if c.joint_id == 0:
            continue
        jac = pin.getJointJacobian(model, data, c.joint_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        rotation = data.oMi[c.joint_id].rotation
        e = rotation @ c.axis
        projector = np.eye(3) - np.outer(e, e)
        cm = water.cm if c.cm is None else c.cm
        nodes, weights = np.polynomial.legendre.leggauss(points)
        for s, weight in zip(0.5 * (nodes + 1.0), 0.5 * weights, strict=True):
            offset = rotation @ (c.start + s * (c.end - c.start))
            jp = jac[:3] - pin.skew(offset) @ jac[3:]
            total += water.rho * cm * c.area * c.length * weight * jp.T @ projector @ jp
    return total


@pytest.mark.parametrize("n_joints", [4, 7])
def test_generated_arm_loads(n_joints):
    arm = arm_from_urdf(generated_urdf(n_joints, seed=n_joints), GENERATED_HYDRO)
    assert arm.n_joints == n_joints  # the prismatic gripper is locked
    kinds = {arm.model.joints[i].shortname() for i in range(1, arm.model.njoints)}
    assert "JointModelRevoluteUnaligned" in kinds and "JointModelRX" in kinds
    assert np.all(np.isinf(arm.position_limit[1])) and np.all(np.isfinite(arm.position_limit[0]))
    np.testing.assert_allclose(arm.torque_limit, [40 + i if i != 2 else 42 for i in range(1, n_joints + 1)])
    names = [c.name for c in arm.cylinders]
    assert "l1" in names and "pod2" in names and "finger" in names
    l1 = arm.cylinders[names.index("l1")]
    assert (l1.cd, l1.cm, l1.displaced_volume) == (1.2, 1.0, 2.0e-3)
    # the pod's cylinder hangs on joint 2 through the fixed joint; the finger on the last joint
    assert arm.cylinders[names.index("pod2")].joint_id == 2
    assert arm.cylinders[names.index("finger")].joint_id == n_joints


@pytest.mark.parametrize("n_joints", [4, 7])
def test_generated_arm_water_is_physical(n_joints):
    arm = arm_from_urdf(generated_urdf(n_joints, seed=n_joints), GENERATED_HYDRO)
    still = Water()
    for q, v, a in _states(n_joints, 6):
        w = hydrodynamic_torques(arm, still, q, v, a)
        assert np.all(np.isfinite(w.total))
        assert v @ w.drag <= 1e-12  # drag dissipates
        assert v @ w.drag < 0.0
        mass_a = added_mass_matrix(arm, still, q)
        np.testing.assert_allclose(mass_a, mass_a.T, atol=1e-14)
        assert np.linalg.eigvalsh(mass_a)[0] > -1e-12
        np.testing.assert_allclose(mass_a, _added_mass_by_points(arm, still, q), rtol=1e-10, atol=1e-13)
        np.testing.assert_allclose(w.buoyancy, _buoyancy_closed_form(arm, still, q), rtol=1e-10, atol=1e-12)
        # doubling every velocity quadruples the drag (quadratic drag, no current)
        w2 = hydrodynamic_torques(arm, still, q, 2.0 * v, a)
        np.testing.assert_allclose(w2.drag, 4.0 * w.drag, rtol=1e-9, atol=1e-12)
        # the dynamics with water stay finite and (M + M_A) is positive definite
        qdd, _ = WaterModel(arm, still).dynamics(q, v, np.zeros(n_joints), 0.0)
        assert np.all(np.isfinite(qdd))


def test_alpha5_water_closed_forms(alpha5):
    water = Water()
    for q, v, a in _states(4, 5):
        w = hydrodynamic_torques(alpha5, water, q, v, a)
        assert v @ w.drag < 0.0
        np.testing.assert_allclose(w.buoyancy, _buoyancy_closed_form(alpha5, water, q), rtol=1e-10, atol=1e-13)
        np.testing.assert_allclose(
            added_mass_matrix(alpha5, water, q), _added_mass_by_points(alpha5, water, q), rtol=1e-10, atol=1e-15
        )


# --- errors name the field ----------------------------------------------------------


@pytest.mark.parametrize(
    ("hydro", "message"),
    [
        (
            {"links": [{"link": "l1", "cylinders": [{"diameter": -0.1, "length": 0.2, "axis": [0, 0, 1]}]}]},
            "links.0.cylinders.0.diameter",
        ),
        ({"links": [{"link": "nope", "collision": True}]}, r"links.0.link = 'nope'"),
        (
            {"links": [{"link": "l1", "collision": [1]}]},
            r"links.0.collision: <collision> 1 of link 'l1' is not a cylinder",
        ),
        ({"links": [{"link": "l1"}]}, r"links.0"),
        (
            {"links": [{"link": "l1", "cylinders": [{"diameter": 0.1, "start": [0, 0, 0], "end": [0, 0, 0]}]}]},
            "links.0.cylinders.0",
        ),
        ({"links": [{"link": "l1", "collision": True, "colour": "red"}]}, "unknown key 'links.0.colour'"),
        ({"fixed_joints": {"gripper": 0.0, "nope": 1.0}}, "fixed_joints.nope"),
        ({"fixed_joints": {"gripper": 0.0}, "torque_limit": [1.0, 2.0]}, "torque_limit has 2 values"),
        ({}, "joint 'gripper' is prismatic"),
        ({"fixed_joints": {"gripper": 0.0}, "links": [{"link": "l1", "collision": True, "cd": 50.0}]}, "links.0.cd"),
    ],
)
def test_bad_hydro_file_names_the_field(hydro, message):
    if "prismatic" not in message:
        hydro = {"fixed_joints": {"gripper": 0.0}, **hydro}
    with pytest.raises(ConfigError, match=message) as error:
        arm_from_urdf(generated_urdf(4, seed=1), hydro, source="gen.hydro.toml")
    assert str(error.value).startswith("gen.hydro.toml")


def test_hydro_file_paths(tmp_path):
    urdf = tmp_path / "gen.urdf"
    urdf.write_text(generated_urdf(4, seed=3))
    hydro = tmp_path / "gen.hydro.toml"
    hydro.write_text(to_toml({**GENERATED_HYDRO, "urdf": "gen.urdf", "name": "mine"}))
    by_hydro = hydroarm.load_arm(hydro)
    by_urdf = load_urdf_arm(urdf)  # finds gen.hydro.toml beside it
    assert by_hydro.name == "mine" and by_urdf.n_joints == 4
    assert [c.name for c in by_hydro.cylinders] == [c.name for c in by_urdf.cylinders]
    (tmp_path / "nourdf.hydro.toml").write_text(to_toml(GENERATED_HYDRO))
    with pytest.raises(ConfigError, match="urdf: missing"):
        hydroarm.load_arm(tmp_path / "nourdf.hydro.toml")
    with pytest.raises(ConfigError, match="no such file"):
        hydroarm.load_arm(tmp_path / "missing.urdf")
    # a URDF with no hydrodynamics file: every collision cylinder is wet, but the prismatic joint is refused
    lonely = tmp_path / "lonely.urdf"
    lonely.write_text(generated_urdf(4, seed=3))
    with pytest.raises(ConfigError, match="prismatic"):
        hydroarm.load_arm(lonely)
