"""Describing the hardware as tested: ballast and floats, passive vehicles, mounts off the hull,
URDF joint zeros and signs, a link's own centre of buoyancy (issue 22)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from hydroarm.config import ConfigError, validate
from hydroarm.model.arm.loading import load_arm
from hydroarm.model.arm.urdf_import import arm_from_urdf
from hydroarm.model.vehicle.description import VehicleSpec, build_vehicle, load_vehicle_spec
from hydroarm.model.vehicle.system import UVMSDynamics, build_uvms
from hydroarm.model.water.morison import Water

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "hinsdale"
VEHICLE = EXAMPLES / "bluerov2_hinsdale.toml"
ARM = EXAMPLES / "alpha_hinsdale.hydro.toml"


def _base(**update) -> dict:
    data = {
        "name": "box",
        "mass": 10.0,
        "inertia": [0.2, 0.3, 0.4],
        "cg": [0.0, 0.0, -0.01],
        "cb": [0.0, 0.0, 0.02],
        "displaced_volume": 0.01,
        "added_mass": [1.0] * 6,
        "linear_damping": [1.0] * 6,
        "quadratic_damping": [1.0] * 6,
        "hull": {"length": 0.4, "width": 0.3, "height": 0.2},
        "mount": {"arm": "alpha5", "position": [0.1, 0.0, -0.05]},
    }
    data.update(update)
    return data


def test_ballast_and_floats_lump_exactly():
    ballast = [{"mass": 0.5, "position": [0.1, 0.05, -0.08]}, {"mass": 0.2, "position": [-0.15, 0.0, 0.0]}]
    floats = [{"volume": 8e-4, "position": [0.0, 0.1, 0.05]}]
    vehicle = build_vehicle(VehicleSpec.model_validate(_base(ballast=ballast, float=floats)))
    masses = [10.0, 0.5, 0.2]
    points = np.array([[0.0, 0.0, -0.01], [0.1, 0.05, -0.08], [-0.15, 0.0, 0.0]])
    cg = (np.array(masses)[:, None] * points).sum(0) / sum(masses)
    inertia = np.diag([0.2, 0.3, 0.4])
    for m, p in zip(masses, points, strict=True):  # parallel axes, by hand
        d = p - cg
        inertia = inertia + m * (d @ d * np.eye(3) - np.outer(d, d))
    assert vehicle.mass == pytest.approx(10.7)
    np.testing.assert_allclose(vehicle.cg, cg, atol=1e-14)
    np.testing.assert_allclose(vehicle.inertia, inertia, atol=1e-14)
    assert vehicle.displaced_volume == pytest.approx(0.0108)
    np.testing.assert_allclose(vehicle.cb, (0.01 * np.array([0, 0, 0.02]) + 8e-4 * np.array([0, 0.1, 0.05])) / 0.0108)


def test_no_loads_keeps_the_numbers():
    spec = VehicleSpec.model_validate(_base())
    vehicle = build_vehicle(spec)
    assert vehicle.mass == 10.0 and vehicle.displaced_volume == 0.01
    np.testing.assert_array_equal(vehicle.cg, [0.0, 0.0, -0.01])
    np.testing.assert_array_equal(vehicle.inertia, np.diag([0.2, 0.3, 0.4]))


@pytest.mark.parametrize(
    ("update", "field"),
    [
        ({"ballast": [{"mass": 0.0, "volume": 1e-4, "position": [0, 0, 0]}]}, "ballast.0.mass"),
        ({"float": [{"mass": 1.0, "position": [0, 0, 0]}]}, "float.0.volume"),
    ],
)
def test_bad_loads_name_the_field(update, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        validate(VehicleSpec, _base(**update), "vehicle")


def test_mount_outside_the_hull_warns():
    with pytest.warns(UserWarning, match="outside the hull"):
        VehicleSpec.model_validate(_base(mount={"arm": "alpha5", "position": [0.25, 0.0, 0.0]}))


def test_passive_vehicle_runs():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        spec = load_vehicle_spec(VEHICLE)
    vehicle = build_vehicle(spec)
    assert vehicle.n_thrusters == 0 and vehicle.allocation.shape == (6, 0)
    uvms = build_uvms(vehicle, "mount")
    dynamics = UVMSDynamics(uvms, Water(rho=997.0))
    q = uvms.neutral(q_arm=np.array([3.07, 1.5, 1.5, 2.879]))
    a = dynamics.acceleration(0.0, q, np.zeros(uvms.nv), np.zeros(uvms.nv), np.zeros(0))
    assert np.all(np.isfinite(a))


def test_tested_vehicle_numbers():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        vehicle = build_vehicle(load_vehicle_spec(VEHICLE))
    extras = (3.24 + 1.62 + 1.62 + 0.69 + 1.01) / 9.81
    assert vehicle.mass == pytest.approx(13.17 + extras)
    assert 997.0 * vehicle.displaced_volume == pytest.approx(13.082 + (8.46 + 8.86) / 9.81)


def _urdf(origin_rpy="0 0 0", axis="0 0 1") -> str:
    return f"""<robot name="two">
  <link name="base"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.1" rpy="{origin_rpy}"/><axis xyz="{axis}"/>
    <limit effort="5" lower="-1" upper="2" velocity="1"/></joint>
  <link name="l1"><inertial><mass value="1"/><origin xyz="0.1 0 0"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
    <collision><geometry><cylinder length="0.2" radius="0.02"/></geometry>
      <origin xyz="0.1 0 0" rpy="0 1.5707963267948966 0"/></collision></link>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.2 0 0" rpy="0.3 0 0"/><axis xyz="0 1 0"/>
    <limit effort="5" lower="-1" upper="1" velocity="1"/></joint>
  <link name="l2"><inertial><mass value="0.5"/><origin xyz="0.1 0 0"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
    <collision><geometry><cylinder length="0.2" radius="0.02"/></geometry>
      <origin xyz="0.1 0 0" rpy="0 1.5707963267948966 0"/></collision></link>
</robot>"""


def _tip(arm, q):
    data = arm.model.createData()
    pin.forwardKinematics(arm.model, data, q)
    return data.oMi[arm.model.njoints - 1]


@pytest.mark.parametrize("sign", [1, -1])
def test_joint_offset_and_sign(sign):
    plain = arm_from_urdf(_urdf(), {"all_collision_cylinders": True})
    hydro = {"all_collision_cylinders": True, "joint_offsets": {"j1": 0.7, "j2": -0.4}, "joint_signs": {"j2": sign}}
    shifted = arm_from_urdf(_urdf(), hydro)
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.uniform(-1.0, 1.0, 2)
        theta = np.array([q[0] - 0.7, sign * (q[1] + 0.4)])
        a, b = _tip(plain, theta), _tip(shifted, q)
        np.testing.assert_allclose(b.homogeneous, a.homogeneous, atol=1e-12)
    lower, upper = shifted.position_limit.T
    np.testing.assert_allclose(lower[0], -1 + 0.7)
    np.testing.assert_allclose(upper[0], 2 + 0.7)
    np.testing.assert_allclose(sorted([sign * -1 - 0.4, sign * 1 - 0.4]), shifted.position_limit[1])


def test_joint_offset_names_a_real_joint():
    with pytest.raises(ConfigError, match="joint_offsets.nope"):
        arm_from_urdf(_urdf(), {"all_collision_cylinders": True, "joint_offsets": {"nope": 0.1}})


def test_buoyancy_center_is_a_point_force():
    """The arm's buoyancy on the floating system equals sum J^T F of point forces rho g V at the
    links' own centres (no drag, no added mass from the buoyancy elements)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        uvms = build_uvms(build_vehicle(load_vehicle_spec(VEHICLE)), "mount")
    water = Water(rho=997.0)
    dynamics = UVMSDynamics(uvms, water)
    q = uvms.neutral(q_arm=np.array([3.3, 1.2, 2.0, 2.5]))
    q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.1, -0.2, 0.3)).coeffs()
    _, _, buoyancy = dynamics.arm_water_terms(q, np.zeros(uvms.nv), drag=False, added_mass=False, buoyancy=True)
    model, data = uvms.model, uvms.model.createData()
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    expected = np.zeros(uvms.nv)
    centres = {
        "r5m_base_link": ([-0.075, -0.006, -0.003], 2.02e-4),
        "r5m_shoulder_link": ([-0.001, -0.003, 0.032], 1.8e-5),
        "r5m_upper_arm_link": ([0.073, 0.0, -0.002], 2.03e-4),
        "r5m_forearm_link": ([0.003, 0.001, -0.017], 2.5e-5),
        "r5m_wrist_link": ([0.0, 0.0, -0.098], 1.55e-4),
        "r5m_jaw": ([0.0, 0.0, 0.0], 2.0e-5),
    }
    for link, (centre, volume) in centres.items():
        frame = model.frames[model.getFrameId(link)]
        point = frame.placement.act(np.asarray(centre))
        jac = pin.getFrameJacobian(model, data, model.getFrameId(link), pin.LOCAL_WORLD_ALIGNED)
        offset = data.oMi[frame.parentJoint].act(point) - data.oMf[model.getFrameId(link)].translation
        jac_point = jac[:3] - pin.skew(offset) @ jac[3:]
        expected += jac_point.T @ np.array([0.0, 0.0, 997.0 * 9.81 * volume])
    np.testing.assert_allclose(buoyancy, expected, atol=1e-6)
    added, _, _ = dynamics.arm_water_terms(q, np.zeros(uvms.nv), drag=False, added_mass=True, buoyancy=False)
    assert np.all(np.isfinite(added))


def test_tested_arm_weighs_its_published_weight():
    arm = load_arm(ARM)
    mass = sum(inertia.mass for inertia in arm.model.inertias)
    volume = sum(c.displaced_volume for c in arm.cylinders)
    assert mass == pytest.approx(1.462)
    assert mass - 997.0 * volume == pytest.approx(0.84, abs=0.005)


def test_a_passive_vehicle_cannot_keep_station():
    from hydroarm.sim.experiment import ExperimentConfig, build_experiment

    config = ExperimentConfig.model_validate({"vehicle": {"name": str(VEHICLE)}})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(ConfigError, match="passive vehicle"):
            build_experiment(config, "pid")
