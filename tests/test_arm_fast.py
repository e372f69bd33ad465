"""The compiled fixed-base plant (``plant.compiled``, hydroarm.model.arm.fast): its rigid body
against Pinocchio, its water against the reference path, its steps against the reference
plant's, and the batched kernel against single steps bit for bit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin
import pydantic
import pytest
from numba.typed import List

from hydroarm.model.arm.fast import BatchedArm, FastArmDynamics
from hydroarm.model.arm.fast_kernels import batch_step_kernel
from hydroarm.model.arm.loading import load_arm
from hydroarm.model.arm.plant import PlantConfig, UnderwaterPlant
from hydroarm.model.dynamics.integrator import inner_steps
from hydroarm.model.real_loop.friction import FrictionConfig
from hydroarm.model.water.morison import CurrentConfig, Water, added_mass_matrix
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides

ARMS = ("paper", "alpha5")


@pytest.fixture(scope="module", params=ARMS)
def arm(request):
    return load_arm(request.param)


def _states(n, count=20, seed=0):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        yield rng.uniform(-3, 3, n), rng.uniform(-2, 2, n), rng.uniform(-5, 5, n), float(rng.uniform(0, 10))


def test_rigid_body_matches_pinocchio(arm):
    """Dry: M(q) = pin.crba, C v + G = pin.nonLinearEffects, q'' = pin.aba, to 1e-12 (measured
    <= 3e-15 on M, 1.5e-14 on nle)."""
    fast = FastArmDynamics(arm, Water().off())
    model, data = arm.model, arm.create_data()
    for q, v, tau, t in _states(arm.n_joints):
        mass, nle, force, drag = fast.terms(q, v, t)
        reference = pin.crba(model, data, q)
        reference = np.triu(reference) + np.triu(reference, 1).T
        np.testing.assert_allclose(mass, reference, rtol=0, atol=1e-12)
        np.testing.assert_allclose(nle, pin.nonLinearEffects(model, data, q, v), rtol=0, atol=1e-12)
        assert not force.any() and not drag.any()
        acc, _ = fast.dynamics(t, q, v, tau)
        np.testing.assert_allclose(acc, pin.aba(model, data, q, v, tau), rtol=1e-12, atol=1e-12)


def test_added_mass_matches_the_reference(arm):
    """With the water: M + M_A = pin.crba + the strips' M_A (world-frame Jacobians) to 1e-12."""
    water = Water()
    fast = FastArmDynamics(arm, water)
    model, data = arm.model, arm.create_data()
    for q, v, _, t in _states(arm.n_joints, 10, seed=1):
        mass = fast.terms(q, v, t)[0]
        reference = pin.crba(model, data, q)
        reference = np.triu(reference) + np.triu(reference, 1).T + added_mass_matrix(arm, water, q)
        np.testing.assert_allclose(mass, reference, rtol=0, atol=1e-12)


WATERS = {
    "paper": Water(),
    "reynolds": Water(drag_model="reynolds"),
    "kirchhoff_axial": Water(added_mass_model="kirchhoff", axial_drag=True),
    "uniform_current": Water(current=CurrentConfig(model="uniform", mean=[0.3, -0.2, 0.1], amplitude=[0.1, 0.0, 0.05])),
}


@pytest.mark.parametrize("name", list(WATERS))
def test_dynamics_match_the_reference_plant(arm, name):
    """q'' and the disturbance of every water setting and the joint friction model against
    UnderwaterPlant.dynamics (Pinocchio + world-frame strips): relative 1e-11 (measured ~1e-14;
    the disturbance differs by round-off of M q'' at up to 1e4 rad/s^2)."""
    water = WATERS[name]
    friction = FrictionConfig(scale=1.0) if name == "paper" else FrictionConfig()
    reference = UnderwaterPlant(arm, water, PlantConfig(friction=0.05), friction)
    fast = FastArmDynamics(arm, water, 0.05, friction)
    for q, v, tau, t in _states(arm.n_joints, 10, seed=2):
        acc, dist = fast.dynamics(t, q, v, tau)
        acc_ref, dist_ref = reference.dynamics(t, q, v, tau)
        scale = max(1.0, float(np.abs(acc_ref).max()))
        np.testing.assert_allclose(acc, acc_ref, rtol=0, atol=1e-11 * scale)
        np.testing.assert_allclose(dist, dist_ref, rtol=0, atol=1e-11 * max(1.0, float(np.abs(dist_ref).max())))


def test_compiled_closed_loop_matches_the_reference():
    """The paper scenario's first 2 s under SMC, plant.compiled against the reference path:
    states within 1e-12 (rad, rad/s; 10 s measured by scripts/arm_fast_accuracy.py: 1.0e-14 rad,
    2.1e-13 rad/s) and the same disturbance record to 1e-9 N m."""
    base = ExperimentConfig(duration=2.0)
    reference = build_experiment(base, "SMC").run(0)
    compiled = build_experiment(with_overrides(base, {"plant.compiled": True}), "SMC").run(0)
    assert np.abs(compiled.x - reference.x).max() < 1e-12
    assert np.abs(compiled.u - reference.u).max() < 1e-9


def test_fast_setting_is_not_the_reference():
    """drag_points and a longer inner step change the numbers (the setting is applied), by a
    small amount on a 0.1 s run (the 10 s error is in docs/model.md)."""
    arm = load_arm("paper")
    x = np.concatenate([[0.3, -0.8, 1.2, 0.4, -0.6, 0.2], [1.0, -0.5, 0.8, 2.0, -1.5, 3.0]])
    paper = UnderwaterPlant(arm, Water(), PlantConfig(compiled=True))
    fast = UnderwaterPlant(arm, Water(), PlantConfig(compiled=True, drag_points=3, inner_step=2.5e-3))
    a, b = x.copy(), x.copy()
    for k in range(10):
        a, _ = paper.step(0.01 * k, a, np.zeros(6), 0.01)
        b, _ = fast.step(0.01 * k, b, np.zeros(6), 0.01)
    assert 0.0 < np.abs(a - b).max() < 1e-2


def test_drag_points_without_the_compiled_plant_is_refused():
    with pytest.raises(pydantic.ValidationError, match="plant.drag_points"):
        PlantConfig(drag_points=3)


def test_diverging_state_gives_nan():
    arm = load_arm("alpha5")
    plant = UnderwaterPlant(arm, Water(), PlantConfig(compiled=True))
    x = np.full(2 * arm.n_joints, 1e300)
    x_next, info = plant.step(0.0, x, np.zeros(arm.n_joints), 0.01)
    assert np.isnan(x_next).all() and np.isnan(info.disturbance).all()


def test_batched_steps_equal_single_steps_bit_for_bit():
    """N copies (different states, torques, times; two water and mass settings) in one parallel
    call: every copy's state and disturbances are its single step's, bit for bit."""
    arm = load_arm("alpha5")
    heavy = arm.model.copy()
    heavy.inertias[2] = pin.Inertia(2.0 * heavy.inertias[2].mass, heavy.inertias[2].lever, heavy.inertias[2].inertia)
    heavy_arm = dataclasses.replace(arm, model=heavy)
    settings = [FastArmDynamics(arm, Water()), FastArmDynamics(heavy_arm, Water(drag_model="reynolds", cd=1.5))]
    n = arm.n_joints
    rng = np.random.default_rng(3)
    count = 9
    x = np.hstack([rng.uniform(-2, 2, (count, n)), rng.uniform(-1, 1, (count, n))])
    tau = rng.uniform(-3, 3, (count, n))
    t = rng.uniform(0, 5, count)
    which = np.arange(count) % 2
    batch = BatchedArm(settings, which)
    x_next, dist, start = batch.step(t, x, tau, 0.01, 1e-3)
    for c in range(count):
        single = settings[which[c]].step(t[c], x[c], tau[c], 0.01, 1e-3)
        assert np.array_equal(x_next[c], single[0])
        assert np.array_equal(dist[c], single[1])
        assert np.array_equal(start[c], single[2])
    assert not np.array_equal(x_next[0], x_next[1])
    # the kernel's runs of copies per thread, each stepping its own replica of the settings it
    # meets (made again where ``which`` changes along a run): any split gives the same numbers
    steps, h = inner_steps(0.01, 1e-3)
    arms = List([s.compiled for s in settings])
    for chunks in (1, 4, count):
        split = batch_step_kernel(t, x, tau, steps, h, arms, which.astype(np.int64), chunks)
        for got, want in zip(split, (x_next, dist, start), strict=True):
            assert np.array_equal(got, want)


def test_plant_keys_left_out_of_run_ids_at_their_defaults():
    """plant.compiled / plant.drag_points at their defaults leave the digest (run ids) of runs made
    before them unchanged; set, they are part of it."""
    default = ExperimentConfig()
    assert {"compiled", "drag_points"}.isdisjoint(default.canonical()["plant"])
    compiled = with_overrides(default, {"plant.compiled": True, "plant.drag_points": 3})
    assert compiled.canonical()["plant"]["drag_points"] == 3
    assert compiled.digest() != default.digest()
