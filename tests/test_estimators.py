"""One estimator protocol for the disturbance learners (issue 33, "control algebra once"): the
sliding-window GP, PI-IDMPC's water model and the observers all satisfy
:class:`~hydroarm.control.interface.DisturbanceEstimator` (``update``, then ``mean`` and
``variance``), each learns what it is given through it, the controllers expose theirs, and the
observer wrapper runs a controller over any of them whose input is the state."""

from __future__ import annotations

import dataclasses
import inspect

import numpy as np
import pytest

from hydroarm.control.gp import GPConfig, SlidingWindowGP
from hydroarm.control.interface import DisturbanceEstimator, estimator_of
from hydroarm.control.learned_water import PhysicsInformedModel, WaterModelConfig
from hydroarm.control.observers import DisturbanceObserver, ObservedController, ObserverConfig
from hydroarm.model.arm.loading import load_arm
from hydroarm.model.arm.plant import PlantConfig, UnderwaterPlant
from hydroarm.model.water.morison import Water
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides


@pytest.fixture(scope="module")
def arm():
    return load_arm("paper")


def learners(arm) -> dict[str, tuple[DisturbanceEstimator, int]]:
    """Every disturbance learner of hydroarm, with the size of its input."""
    n = arm.n_joints
    return {
        "TDE": (DisturbanceObserver(arm, 0.01, ObserverConfig(kind="tde")), 2 * n),
        "NDOB": (DisturbanceObserver(arm, 0.01, ObserverConfig(kind="ndob", gain=0.2)), 2 * n),
        "GP": (SlidingWindowGP(2 * n, n, GPConfig(window=40)), 2 * n),
        "water model": (PhysicsInformedModel(arm), 3 * n),
    }


class _NoVariance:
    """Has update and mean but no variance: not an estimator."""

    n_samples = 0

    def reset(self) -> None: ...

    def update(self, x, r) -> bool:
        return True

    def mean(self, x):
        return np.zeros(1)


def test_every_learner_satisfies_the_protocol(arm):
    for name, (estimator, _) in learners(arm).items():
        assert isinstance(estimator, DisturbanceEstimator), name
        for method in ("update", "mean", "variance"):
            parameters = list(inspect.signature(getattr(estimator, method)).parameters)
            assert parameters[: 2 if method == "update" else 1] == (["x", "r"] if method == "update" else ["x"]), (
                name,
                method,
            )
    assert not isinstance(_NoVariance(), DisturbanceEstimator)


def test_the_learners_learn_a_constant_disturbance_through_update_and_mean(arm):
    """A constant r at inputs near 0: the TDE's mean is the last r, the NDOB's
    ``(1 - (1 - L)^k) r``, the GP's (theta0: sf2 = sn2 = 1) just under r with a variance under the
    prior's; each counts its samples and a reset forgets them."""
    rng = np.random.default_rng(4)
    r = np.array([3.0, -2.0, 1.0, 0.5, -0.25, 0.1])
    found = learners(arm)
    for name in ("TDE", "NDOB", "GP"):
        estimator, size = found[name]
        inputs = 0.05 * rng.standard_normal((30, size))
        for x in inputs:
            assert estimator.update(x, r) is True
        assert estimator.n_samples == 30
        mean, var = estimator.mean(inputs[-1]), estimator.variance(inputs[-1])
        if name == "TDE":
            assert np.array_equal(mean, r) and np.all(np.isnan(var))
        elif name == "NDOB":
            np.testing.assert_allclose(mean, (1.0 - 0.8**30) * r, rtol=1e-12)
        else:
            # the same kernel on every output: one linear smoother, the same share of r on each,
            # at most N sf2 / (N sf2 + sn2) = 30/31 (every input the same), more than 0.9 here
            share = mean / r
            assert np.ptp(share) < 1e-9 and 0.9 < share[0] <= 30 / 31 + 1e-12
            assert np.all(var > 0) and np.all(var < 1.1)  # below the prior's sf2 + sn2 = 2
        estimator.reset()
        assert estimator.n_samples == 0
        assert np.array_equal(estimator.mean(inputs[-1]), np.zeros(arm.n_joints))


def test_the_gps_mean_and_variance_are_its_prediction_bit_for_bit(arm):
    gp = SlidingWindowGP(4, 2, GPConfig(window=20))
    rng = np.random.default_rng(5)
    for _ in range(15):
        gp.update(rng.standard_normal(4), rng.standard_normal(2))
    gp.update_hyperparameters()
    x = rng.standard_normal(4)
    mean, var = gp.predict(x)
    assert np.array_equal(gp.mean(x), mean) and np.array_equal(gp.variance(x), var)
    gp.update(x, np.ones(2))  # a new sample: a new prediction, not the cached one
    assert np.array_equal(gp.mean(x), gp.predict(x)[0])
    assert not np.array_equal(gp.mean(x), mean)


def test_the_water_model_learns_the_plants_water_through_the_protocol(arm):
    """[q, v, a] in, the plant's water force out: after 200 samples its mean is the water's
    (the basis is exact for the plant's Morison water), its variance shrank."""
    water = Water(cd=1.2, cm=1.7, current={"model": "none"})
    plant = UnderwaterPlant(arm, water, PlantConfig())
    model = PhysicsInformedModel(arm, WaterModelConfig(forgetting=1.0, prior="textbook", noise_std=1e-6))
    rng = np.random.default_rng(0)

    def sample():
        q, v, tau = rng.uniform(-np.pi, np.pi, 6), rng.normal(0.0, 2.0, 6), rng.normal(0.0, 20.0, 6)
        a = plant.acceleration(0.0, q, v, tau)
        return np.concatenate([q, v, a]), arm.mass_matrix(q) @ a + arm.nonlinear_effects(q, v) - tau

    x0, _ = sample()
    prior_variance = model.variance(x0)
    for _ in range(200):
        x, w = sample()
        assert model.update(x, w)
    assert model.n_samples == 200
    x, w = sample()
    np.testing.assert_allclose(model.mean(x), w, rtol=1e-4, atol=1e-4)
    assert np.all(model.variance(x0) < 1e-3 * prior_variance)
    assert not model.update(x, np.full(6, np.nan))  # refused, nothing learned
    assert model.n_samples == 200
    with pytest.raises(ValueError, match="q, v, a"):
        model.mean(x[:12])


@pytest.mark.parametrize(
    ("controller", "settings", "kind"),
    [
        ("GP-MPC", {}, SlidingWindowGP),
        ("GP-IDMPC", {}, SlidingWindowGP),
        ("PI-IDMPC", {}, PhysicsInformedModel),
        ("SMC", {"observer.kind": "tde"}, DisturbanceObserver),
        ("IDMPC", {"observer.kind": "ndob"}, DisturbanceObserver),
        ("MPC", {}, type(None)),
    ],
)
def test_each_controller_exposes_its_learner(controller, settings, kind):
    """``estimator_of`` finds the learner through the wrappers (the Kalman filter's too)."""
    config = with_overrides(ExperimentConfig(duration=0.05), settings)
    found = estimator_of(build_experiment(config, controller).controller)
    assert type(found) is kind
    assert found is None or isinstance(found, DisturbanceEstimator)


@pytest.mark.parametrize("learner", ["TDE", "GP"])
def test_a_controller_runs_over_any_state_input_learner(learner, arm):
    """SMC over the TDE or over a GP on the state (2n inputs): the same wrapper feeds either one's
    mean forward, and either one estimates the plant's true water disturbance: over the second
    half of 1.5 s its estimate's error is under half the disturbance (the plain SMC's zero
    estimate: all of it)."""
    config = with_overrides(ExperimentConfig(duration=1.5), {"observer.kind": "tde"})
    experiment = build_experiment(config, "SMC")
    observed = experiment.controller
    assert isinstance(observed, ObservedController)
    estimator, _ = learners(experiment.arm)[learner]
    controller = ObservedController(observed.controller, estimator, experiment.arm, label=learner)
    traj = dataclasses.replace(experiment, controller=controller).run(0)
    assert not traj.diverged and controller.name == f"SMC+{learner}"
    assert estimator.n_samples == (traj.t.shape[0] if learner == "TDE" else 40)  # one sample a step
    half = traj.t.shape[0] // 2
    true, estimate = traj.disturbance[half:], traj.disturbance_estimate[half:]
    assert np.abs(true).mean() > 0.1
    assert np.abs(estimate - true).mean() < 0.5 * np.abs(true).mean()
