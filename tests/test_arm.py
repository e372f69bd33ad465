"""The arm model: arm files, Pinocchio dynamics identities, hand-computed values, URDF."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pinocchio as pin
import pytest

import hydroarm
from hydroarm.config import ConfigError, validate
from hydroarm.model.arm.description import ArmSpec
from hydroarm.model.arm.loading import builtin_arm_path, load_arm_spec
from hydroarm.model.arm.urdf_export import arm_to_urdf

RNG = np.random.default_rng(20231641)
CONFIGS = RNG.uniform(-math.pi, math.pi, size=(25, 6))


@pytest.fixture(scope="session")
def arm(paper_arm):
    return paper_arm


def _paper_table():
    with builtin_arm_path("paper").open("rb") as handle:
        return tomllib.load(handle)


# --- arm files -----------------------------------------------------------------


def test_builtin_arms_load():
    paper = hydroarm.load_arm("paper")
    ur5 = hydroarm.load_arm("ur5")
    assert paper.n_joints == ur5.n_joints == 6
    np.testing.assert_allclose(paper.torque_limit, 500.0)
    np.testing.assert_allclose(ur5.torque_limit, [150, 150, 150, 28, 28, 28])
    # The documented differences between the paper's table and UR's numbers.
    assert paper.spec.links[0].d == 0.089459 and ur5.spec.links[0].d == 0.089159
    assert paper.spec.links[1].mass == 9.393 and ur5.spec.links[1].mass == 8.393


def test_buoyancy_column_is_the_cylinder_volume():
    """paper reading, section 1: rho pi/4 D^2 L reproduces Table A1's buoyancy to four digits."""
    table = _paper_table()
    for link in table["links"]:
        length = math.hypot(link["a"], link["d"])
        displaced = 1000.0 * math.pi / 4.0 * link["cylinder_diameter"] ** 2 * length
        assert displaced == pytest.approx(link["buoyancy_kg"], abs=5e-4 * max(1.0, link["buoyancy_kg"])), link["name"]
        # ... and to 0.15 % relative, which is four significant digits for every row.
        assert displaced == pytest.approx(link["buoyancy_kg"], rel=1.5e-3), link["name"]


def _broken(**changes):
    data = _paper_table()
    for path, value in changes.items():
        target = data
        keys = path.split("__")
        for key in keys[:-1]:
            target = target[int(key)] if key.isdigit() else target[key]
        last = keys[-1]
        if value is _DELETE:
            del target[last]
        else:
            target[last] = value
    return data


_DELETE = object()


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"links__2__mass": -1.0}, "links.2.mass"),
        ({"links__0__cylinder_diameter": 0.0}, "links.0.cylinder_diameter"),
        ({"links__1__colour": "red"}, "links.1.colour"),
        ({"torque_limit": [500.0] * 5}, "torque_limit"),
        ({"links__3__com": [0.0, 0.0]}, "links.3.com"),
        ({"links__4__inertia_axial": 1.0}, "links.4"),
        ({"links__5__mass": float("nan")}, "links.5.mass"),
        ({"links__0__a": 0.0, "links__0__d": 0.0}, "links.0"),
    ],
)
def test_bad_arm_file_names_the_field(changes, field):
    with pytest.raises(ConfigError) as error:
        validate(ArmSpec, _broken(**changes), "paper.toml")
    assert field in str(error.value)


def test_non_spd_inertia_is_rejected():
    data = _paper_table()
    link = data["links"][2]
    del link["inertia_axial"], link["inertia_transverse"]
    link["inertia"] = [[1e-3, 0.0, 0.0], [0.0, -1e-3, 0.0], [0.0, 0.0, 1e-3]]
    with pytest.raises(ConfigError, match=r"links\.2.*positive definite"):
        validate(ArmSpec, data, "arm.toml")


def test_wrong_row_count_and_unknown_arm(tmp_path):
    data = _paper_table()
    data["links"] = []
    with pytest.raises(ConfigError, match="links"):
        validate(ArmSpec, data, "arm.toml")
    with pytest.raises(ConfigError, match="neither a built-in arm"):
        hydroarm.load_arm("no-such-arm")
    bad = tmp_path / "arm.toml"
    bad.write_text("name = 'x'\n[[links]]\nmass = 'heavy'\n")
    with pytest.raises(ConfigError, match="links.0.mass"):
        load_arm_spec(bad)


# --- dynamics identities --------------------------------------------------------


@pytest.mark.parametrize("q", CONFIGS[:10])
def test_mass_matrix_symmetric_positive_definite(arm, q):
    mass = arm.mass_matrix(q)
    np.testing.assert_array_equal(mass, mass.T)
    assert np.linalg.eigvalsh(mass)[0] > 0.0


@pytest.mark.parametrize("q", CONFIGS[:8])
def test_mass_derivative_minus_twice_coriolis_is_skew(arm, q):
    v = RNG.normal(size=6)
    eps = 1e-6
    mdot = (arm.mass_matrix(q + eps * v) - arm.mass_matrix(q - eps * v)) / (2 * eps)
    skew = mdot - 2.0 * arm.coriolis_matrix(q, v)
    np.testing.assert_allclose(skew, -skew.T, atol=1e-7)


@pytest.mark.parametrize("q", CONFIGS[:8])
def test_rnea_inverts_aba(arm, q):
    v = RNG.normal(size=6) * 3.0
    tau = RNG.normal(size=6) * 50.0
    a = arm.forward_dynamics(q, v, tau)
    np.testing.assert_allclose(arm.inverse_dynamics(q, v, a), tau, rtol=1e-10, atol=1e-9)
    # inverse dynamics = M a + C v + G
    rebuilt = arm.mass_matrix(q) @ a + arm.coriolis_matrix(q, v) @ v + arm.gravity(q)
    np.testing.assert_allclose(rebuilt, tau, rtol=1e-10, atol=1e-9)


def test_aba_derivatives_match_finite_differences(arm):
    q, v, tau = CONFIGS[0], RNG.normal(size=6), RNG.normal(size=6) * 20
    _, dq, dv, minv = arm.forward_dynamics_derivatives(q, v, tau)
    eps = 1e-6
    eye = np.eye(6)
    fd_q = np.column_stack(
        [
            (arm.forward_dynamics(q + eps * e, v, tau) - arm.forward_dynamics(q - eps * e, v, tau)) / (2 * eps)
            for e in eye
        ]
    )
    fd_v = np.column_stack(
        [
            (arm.forward_dynamics(q, v + eps * e, tau) - arm.forward_dynamics(q, v - eps * e, tau)) / (2 * eps)
            for e in eye
        ]
    )
    np.testing.assert_allclose(dq, fd_q, rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(dv, fd_v, rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(minv, np.linalg.inv(arm.mass_matrix(q)), rtol=1e-9, atol=1e-9)


# --- numbers computed by hand from the DH table -----------------------------------

G = 9.81
M2, M3, M4, M5, M6 = 9.393, 2.33, 1.1219, 1.1219, 0.1897
A2, A3, D5 = -0.425, -0.39225, 0.09465
D6 = 0.0823


def test_gravity_arm_stretched_horizontally(arm):
    """q = 0: links 2-6 stretch along -x0 at shoulder height; joint 2's axis is -y0.

    World CoG x-coordinates (m): link 2 at a2 + 0.2125, link 3 at a2 + a3 + 0.15,
    links 4-6 at a2 + a3 (their CoG offsets are vertical or along y0). The
    holding torque about -y0 is G_i = g * sum m x for the links beyond joint i.
    """
    x2 = A2 + 0.2125
    x3 = A2 + A3 + 0.15
    x456 = A2 + A3
    g2 = G * (M2 * x2 + M3 * x3 + (M4 + M5 + M6) * x456)
    g3 = G * (M3 * (x3 - A2) + (M4 + M5 + M6) * (x456 - A2))
    gravity = arm.gravity(np.zeros(6))
    assert gravity[1] == pytest.approx(g2, rel=1e-12)  # -54.342 N m
    assert gravity[2] == pytest.approx(g3, rel=1e-12)  # -14.901 N m
    assert gravity[0] == pytest.approx(0.0, abs=1e-12)  # vertical axis
    assert g2 == pytest.approx(-54.342, abs=1e-3)


def test_gravity_forearm_hanging_down(arm):
    """q3 = pi/2: link 2 horizontal along -x0, link 3 hangs down from the elbow.

    Elbow at x = a2. Link 3's CoG offset (0.15, 0, 0.0265) is then vertical and
    along the joint axis: x = a2. Link 4's CoG z-offset 0.01634 points along
    +x0 (z4 = -y3 = +x0); joint 5 sits d5 further along +x0, its CoG y-offset
    -0.0018 along y5 = -x0 adds +0.0018; link 6's CoG lies on z6 = -y0.
    """
    q = np.array([0.0, 0.0, math.pi / 2, 0.0, 0.0, 0.0])
    x2 = A2 + 0.2125
    x3 = A2
    x4 = A2 + 0.01634
    x5 = A2 + D5 + 0.0018
    x6 = A2 + D5
    g2 = G * (M2 * x2 + M3 * x3 + M4 * x4 + M5 * x5 + M6 * x6)
    g3 = G * (M4 * (x4 - A2) + M5 * (x5 - A2) + M6 * (x6 - A2))
    gravity = arm.gravity(q)
    assert gravity[1] == pytest.approx(g2, rel=1e-12)
    assert gravity[2] == pytest.approx(g3, rel=1e-12)
    assert gravity[3] == pytest.approx(g3, rel=1e-12)  # joint 4's axis is parallel to joint 3's


def test_kinematics_stretched(arm):
    """q = 0: flange at (a2 + a3, -(d4 + d6), d1 - d5), from the DH table by hand."""
    placements = arm.joint_placements(np.zeros(6))
    model, data = arm.model, arm.create_data()
    pin.framesForwardKinematics(model, data, np.zeros(6))
    flange = data.oMf[model.getFrameId("flange")].translation
    np.testing.assert_allclose(flange, [A2 + A3, -(0.10915 + D6), 0.089459 - D5], atol=1e-12)
    np.testing.assert_allclose(placements[2].translation, [A2, 0.0, 0.089459], atol=1e-12)


# --- URDF export ----------------------------------------------------------------


@pytest.mark.parametrize("name", ["paper", "ur5"])
def test_urdf_round_trip_pinocchio(name):
    arm = hydroarm.load_arm(name)
    model = pin.buildModelFromXML(arm_to_urdf(arm))
    data = model.createData()
    assert model.nv == arm.n_joints
    for q in CONFIGS[:10]:
        m_urdf = pin.crba(model, data, q)
        m_urdf = np.triu(m_urdf) + np.triu(m_urdf, 1).T
        np.testing.assert_allclose(m_urdf, arm.mass_matrix(q), rtol=0, atol=1e-10)
        np.testing.assert_allclose(pin.computeGeneralizedGravity(model, data, q), arm.gravity(q), atol=1e-10)


def test_urdf_loads_in_mujoco_with_same_mass_matrix(arm):
    mujoco = pytest.importorskip("mujoco")
    model = mujoco.MjModel.from_xml_string(arm_to_urdf(arm))
    data = mujoco.MjData(model)
    assert model.nv == 6
    np.testing.assert_allclose(model.body_mass[1:], [link.mass for link in arm.spec.links], rtol=1e-12)
    for q in CONFIGS[:5]:
        data.qpos[:] = q
        mujoco.mj_forward(model, data)
        full = np.zeros((6, 6))
        mujoco.mj_fullM(model, data, full)
        np.testing.assert_allclose(full, arm.mass_matrix(q), rtol=1e-8, atol=1e-10)
        # MuJoCo's qfrc_bias at v = 0 is the gravity torque.
        np.testing.assert_allclose(data.qfrc_bias, arm.gravity(q), rtol=1e-8, atol=1e-9)


# --- reflected rotor inertia (armature) ------------------------------------------------------


def _paper_with_armature(armature):
    from hydroarm.model.arm.description import build_arm
    from hydroarm.model.arm.loading import load_arm_spec

    data = load_arm_spec("paper").model_dump()
    data["armature"] = armature
    return build_arm(validate(ArmSpec, data, "paper.toml"))


def test_armature_adds_exactly_itself_to_the_mass_matrix_diagonal_in_the_plant_and_the_model():
    import pinocchio as pin

    from hydroarm.model.arm.loading import load_arm
    from hydroarm.model.arm.plant import PlantConfig, UnderwaterPlant
    from hydroarm.model.dynamics.nominal import NominalModel
    from hydroarm.model.water.morison import Water

    plain = load_arm("paper")
    armature = np.array([0.4, 0.3, 0.2, 0.05, 0.02, 0.01])  # kg m^2
    geared = _paper_with_armature(armature.tolist())
    assert np.all(plain.model.armature == 0.0)  # the paper arm in paper mode: none
    rng = np.random.default_rng(3)
    q, v, tau = rng.uniform(-2, 2, 6), rng.uniform(-1, 1, 6), rng.uniform(-5, 5, 6)
    with_armature = pin.crba(geared.model, geared.model.createData(), q)
    without = pin.crba(plain.model, plain.model.createData(), q)
    np.testing.assert_allclose(np.triu(with_armature - without), np.diag(armature), rtol=0, atol=1e-14)
    # the controllers' model solves (M(q) + diag(armature)) a = tau - h(q, v), and the plant the same
    # with the water's generalised force w (no added mass here: w does not depend on a)
    mass = np.triu(without) + np.triu(without, 1).T + np.diag(armature)
    bias = pin.nonLinearEffects(plain.model, plain.model.createData(), q, v)
    expected = np.linalg.solve(mass, tau - bias)
    np.testing.assert_allclose(NominalModel(geared).forward_dynamics(q, v, tau), expected, rtol=1e-10, atol=1e-12)
    assert not np.allclose(NominalModel(plain).forward_dynamics(q, v, tau), expected, rtol=1e-3)
    plant = UnderwaterPlant(geared, Water(added_mass=False), PlantConfig())
    acceleration, water = plant.dynamics(0.0, q, v, tau)
    np.testing.assert_allclose(mass @ acceleration, tau - bias + water, rtol=1e-10, atol=1e-10)


def test_armature_is_one_value_or_one_per_joint_in_arm_and_hydrodynamics_files():
    from hydroarm.config import ConfigError
    from hydroarm.model.arm.urdf_export import arm_to_urdf
    from hydroarm.model.arm.urdf_import import arm_from_urdf, hydro_spec_of

    assert np.all(_paper_with_armature(0.1).model.armature == 0.1)
    with pytest.raises(ConfigError, match="armature"):
        _paper_with_armature([0.1, 0.2])
    with pytest.raises(ConfigError, match="armature"):
        _paper_with_armature(-0.1)
    geared = _paper_with_armature([0.4, 0.3, 0.2, 0.05, 0.02, 0.01])
    urdf = arm_to_urdf(geared)
    assert "armature" in urdf  # said where URDF drops it
    again = arm_from_urdf(urdf, hydro_spec_of(geared, use_collision=False))
    np.testing.assert_array_equal(again.model.armature, geared.model.armature)
    spec = hydro_spec_of(geared, use_collision=False)
    spec["armature"] = [0.1, 0.2]
    with pytest.raises(ConfigError, match="armature has 2 values for 6 joints"):
        arm_from_urdf(urdf, spec)


def test_built_in_arms_carry_no_armature_and_a_vehicle_refuses_one():
    from hydroarm.config import ConfigError
    from hydroarm.model.arm.loading import load_arm
    from hydroarm.model.vehicle.system import build_uvms

    for name in ("paper", "ur5", "alpha5", "examples/urdf/iiwa14.urdf"):
        assert np.all(load_arm(name).model.armature == 0.0), name  # no published figure: see the arm files
    with pytest.raises(ConfigError, match="armature"):
        build_uvms(arm=_paper_with_armature(0.1))
