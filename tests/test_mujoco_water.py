"""MuJoCo's ellipsoid fluid model as an independent check of hydroarm's Morison drag."""

from __future__ import annotations

import math

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

import hydroarm  # noqa: E402
from hydroarm.model.arm.description import ArmSpec, build_arm  # noqa: E402
from hydroarm.model.water.morison import CurrentConfig, Water  # noqa: E402
from hydroarm.model.water.mujoco_check import (  # noqa: E402
    MujocoWater,
    arm_to_mjcf,
    axial_flow_fraction,
    blunt_coefficient,
    drag_decomposition,
    ellipsoid_drag,
    hydroarm_drag,
    lumped_drag_ratio,
)

RNG = np.random.default_rng(7)
PI = math.pi
SEGMENTS = 16


@pytest.fixture(scope="module")
def paper():
    return hydroarm.load_arm("paper")


@pytest.fixture(scope="module")
def alpha5():
    return hydroarm.load_arm("alpha5")


def rod(length=0.5, diameter=0.08):
    """One joint about z; the rod runs from the axis out along x (spins about its end)."""
    link = {
        "name": "rod", "a": length, "alpha_deg": 0.0, "d": 0.0, "mass": 2.0, "com": [0.0, 0.0, 0.0],
        "inertia_axial": 1e-3, "inertia_transverse": 0.04, "cylinder_diameter": diameter,
    }  # fmt: skip
    return build_arm(ArmSpec(name="rod", torque_limit=100.0, links=[link]))


def uniform(mean):
    return Water(current=CurrentConfig(model="uniform", mean=list(mean)))


# --- the MJCF ------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["paper", "alpha5"])
def test_mjcf_structure(name):
    arm = hydroarm.load_arm(name)
    sim = MujocoWater(arm, Water(cd=1.3), segments=4)
    model = sim.model
    assert model.nv == arm.n_joints
    assert model.opt.density == 1000.0 and model.opt.viscosity == 0.0
    np.testing.assert_array_equal(model.opt.gravity, 0.0)
    # every body with a dof uses the ellipsoid model (no fall-back to the inertia box)
    for body in range(1, model.nbody):
        geoms = range(model.body_geomadr[body], model.body_geomadr[body] + model.body_geomnum[body])
        assert any(model.geom_fluid[g, 0] > 0.0 for g in geoms), model.body(body).name
    # N segments per wetted cylinder, coefficient 2 C_d / pi, semi-axes (r, r, L / 2N)
    wet = [g for g in range(model.ngeom) if model.geom_fluid[g, 1] > 0.0]
    assert len(wet) == 4 * len(arm.cylinders)
    np.testing.assert_allclose(model.geom_fluid[wet, 1], blunt_coefficient(1.3))
    np.testing.assert_allclose(model.geom_fluid[wet, 2:6], 0.0)
    first = arm.cylinders[0]
    np.testing.assert_allclose(model.geom_size[wet[0], :2], [first.diameter / 2, first.length / 8])
    # same kinematics: geom centres are the segment centres
    q = RNG.uniform(-PI, PI, arm.n_joints)
    sim.qfrc_fluid(q, np.zeros(arm.n_joints), np.zeros(3))
    ends = arm.cylinder_endpoints(q)
    np.testing.assert_allclose(sim.data.geom_xpos[wet[0]], ends[0, 0] + (ends[0, 1] - ends[0, 0]) / 8, atol=1e-12)


def test_mjcf_rejects_bad_arguments(paper):
    with pytest.raises(ValueError, match="segments"):
        arm_to_mjcf(paper, segments=0)
    with pytest.raises(ValueError, match="blunt"):
        arm_to_mjcf(paper, blunt=[True])


# --- the mapping: MuJoCo's blunt drag is the formula we derived --------------------------------


@pytest.mark.parametrize("name", ["paper", "alpha5"])
def test_mujoco_drag_is_the_derived_ellipsoid_formula(name):
    """On general states (axial flow, currents) MuJoCo's odd part equals our NumPy replay of
    F = -C_blunt rho A_proj(u) |u| u per segment: the cylinder -> ellipsoid mapping, the dof
    order, the wind and the (f(v, w) - f(-v, -w)) / 2 split are all as documented."""
    arm = hydroarm.load_arm(name)
    n = arm.n_joints
    water = Water(
        cd=0.9,
        current=CurrentConfig(model="uniform", mean=[0.2, -0.3, 0.15], amplitude=[0.1, 0.0, 0.0], frequency_hz=0.3),
    )
    sim = MujocoWater(arm, water, segments=4)
    for _ in range(4):
        q, v, t = RNG.uniform(-PI, PI, n), RNG.normal(0.0, 2.0, n), float(RNG.uniform(0, 5))
        split = sim.split(q, v, t)
        replay = ellipsoid_drag(arm, water, q, v, t, segments=4)
        np.testing.assert_allclose(split.drag, replay, rtol=1e-9, atol=1e-12 * max(1.0, np.abs(replay).max()))
        # MuJoCo's raw force is not odd: the even (virtual-mass) part is real and removed
        assert np.abs(split.even).max() > 1e-6 * np.abs(split.drag).max()


def test_blunt_coefficient_matches_morison_per_length():
    """A segment in purely normal flow: C_blunt rho (pi r h) |u| u = 1/2 rho C_d D (2h) |u| u."""
    r, h, cd, rho = 0.03, 0.02, 1.2, 1000.0
    assert blunt_coefficient(cd) * rho * PI * r * h == pytest.approx(0.5 * rho * cd * (2 * r) * (2 * h), rel=1e-15)


# --- normal flow: within 1 % at 16 segments ---------------------------------------------------

VERTICAL = np.array(
    [0.0, PI / 2, PI, PI / 2, PI, 0.0]
)  # links 1, 2 (down), 3 (folded back up), 5 along z; 4, 6 along y


def _spin(joint, omega, n=6):
    v = np.zeros(n)
    if joint is not None:
        v[joint] = omega
    return v


NORMAL_FLOW_STATES = [
    # joint 2 spinning with q = (0, 0, 0, +-pi/2, 0, 0): links 2, 3 radial, 4 parallel, 5, 6 radial
    *[
        (np.array([0.0, 0.0, 0.0, s * PI / 2, 0.0, 0.0]), _spin(1, w), (0.0, 0.0, 0.0))
        for s in (1, -1)
        for w in (1.5, -2.5)
    ],
    # links along z and y, a horizontal current along x: normal to every link; alone and with single-joint spins
    *[(VERTICAL, _spin(j, 0.8), (c, 0.0, 0.0)) for j in (None, 0, 1, 2, 4) for c in (0.6, -0.4)],
]


@pytest.mark.parametrize(("q", "v", "current"), NORMAL_FLOW_STATES)
def test_normal_flow_agrees_within_one_percent(paper, q, v, current):
    water = uniform(current)
    assert axial_flow_fraction(paper, q, v, np.asarray(current)).max() < 1e-9  # the premise
    mj = MujocoWater(paper, water, SEGMENTS).drag(q, v)
    ours = hydroarm_drag(paper, water, q, v)
    assert np.abs(ours).max() > 0.1
    assert np.abs(mj - ours).max() <= 0.01 * np.abs(ours).max()


def test_axial_flow_premise_detects_axial_flow(paper):
    """A vertical current is axial to links 1, 2, 3 and 5 in that pose: excluded above."""
    assert axial_flow_fraction(paper, VERTICAL, np.zeros(6), np.array([0.0, 0.0, 0.5])).max() == pytest.approx(1.0)


# --- lumping: 1 - 1/(2 N^2) ---------------------------------------------------------------------


def test_single_link_converges_as_lumped_theory_predicts():
    arm = rod()
    water = Water()
    ours = hydroarm_drag(arm, water, [0.3], [2.0])[0]
    assert ours == pytest.approx(-1000.0 * 1.0 * 0.08 * 4.0 * 0.5**4 / 8.0, rel=1e-12)  # closed form
    errors = []
    for segments in (1, 2, 4, 8, 16, 32):
        ratio = MujocoWater(arm, water, segments).drag([0.3], [2.0])[0] / ours
        assert ratio == pytest.approx(lumped_drag_ratio(segments), rel=1e-9)
        errors.append(1.0 - ratio)
    assert all(later < earlier for earlier, later in zip(errors, errors[1:], strict=False))
    assert errors[-1] < 1e-3


def test_single_link_in_a_current_is_exact_at_any_segment_count():
    """Uniform normal flow along the rod: lumping is exact, N = 1 already agrees."""
    arm = rod()
    water = uniform((0.0, 0.7, 0.0))
    ours = hydroarm_drag(arm, water, [0.0], [0.0])[0]
    for segments in (1, 3):
        assert MujocoWater(arm, water, segments).drag([0.0], [0.0])[0] == pytest.approx(ours, rel=1e-12)


# --- general states: measured, not asserted -------------------------------------------------


def test_drag_decomposition_reports_end_faces(paper):
    states = [(RNG.uniform(-PI, PI, 6), RNG.normal(0.0, 1.0, 6)) for _ in range(3)]
    rows = drag_decomposition(paper, Water(), states, segments=8)
    assert [row["cylinder"] for row in rows] == [c.name for c in paper.cylinders]
    for row in rows:
        assert row["replay_error"] < 1e-9
        if row["share"] > 0.0:
            # mujoco - hydroarm = end faces + lumping (triangle inequality on the RMS norms)
            assert row["mujoco_vs_hydroarm"] <= row["end_face"] + row["lumping"] + 1e-12
    link2 = rows[1]  # link 2 is radial to joint 2 and feels axial flow only from other joints
    assert link2["lumping"] < 0.02
