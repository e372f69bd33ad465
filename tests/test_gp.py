"""Tests of hydroarm.control.gp: checks against scikit-learn, gradients against finite
differences, the safeguards of the sliding-window estimator, the fault events its calls
return, and the validation of GPConfig."""

from __future__ import annotations

import math

import numpy as np
import pydantic
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

from hydroarm.config import ConfigError, validate
from hydroarm.control.gp import (
    FAULTS,
    GPConfig,
    SlidingWindowGP,
    log_marginal_likelihood,
    log_marginal_likelihood_multi,
    predict,
    predict_multi,
)
from hydroarm.control.interface import FAULT_EVENTS

# Tolerances against sklearn: both sides do the same Cholesky algebra in float64,
# so agreement is at round-off level; we require rtol = 1e-8 (relative) with an
# absolute floor of 1e-10 * scale for values that are ~0.
RTOL_SKLEARN = 1e-8


def random_problem(rng, n, d, m, anisotropic=True):
    X = rng.uniform(-2.0, 2.0, size=(n, d))
    y = np.sin(X @ rng.normal(size=d)) + 0.1 * rng.normal(size=n)
    X_star = rng.uniform(-2.5, 2.5, size=(m, d))
    lengthscales = rng.uniform(0.3, 3.0, size=d) if anisotropic else np.full(d, 1.0)
    theta = np.concatenate([[rng.uniform(0.5, 3.0), rng.uniform(0.01, 0.3)], lengthscales])
    return X, y, X_star, theta


def sklearn_gp(X, y, theta, fixed=True, noise_in_kernel=True):
    bounds = "fixed" if fixed else (1e-12, 1e12)
    kernel = ConstantKernel(theta[0], bounds) * RBF(theta[2:], bounds)
    if noise_in_kernel:
        kernel = kernel + WhiteKernel(theta[1], bounds)
        alpha = 0.0
    else:
        alpha = theta[1]
    return GaussianProcessRegressor(kernel=kernel, alpha=alpha, optimizer=None).fit(X, y)


def arm_like_stream(n_steps, n_inputs=12, n_outputs=6, noise=0.0, seed=0):
    """Smooth joint-like inputs (rad, rad/s) and torque-like targets (N*m)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_steps)[:, None] * 0.01
    omega = rng.uniform(0.5, 2.0, n_inputs)
    phase = rng.uniform(0.0, 2.0 * np.pi, n_inputs)
    X = np.where(np.arange(n_inputs) < n_inputs // 2, 3.0, 8.0) * np.sin(omega * t + phase)
    Y = 100.0 * np.tanh(X @ rng.normal(size=(n_inputs, n_outputs)) / n_inputs) + 30.0 * np.sin(X[:, :n_outputs])
    return X + noise * rng.normal(size=X.shape), Y + 100.0 * noise * rng.normal(size=Y.shape)


# --------------------------------------------------------------------------
# Pure functions against scikit-learn
# --------------------------------------------------------------------------


@pytest.mark.parametrize("n, d, m", [(1, 1, 4), (5, 1, 3), (10, 3, 7), (25, 12, 9), (40, 24, 5)])
def test_predict_matches_sklearn(n, d, m):
    rng = np.random.default_rng(100 * n + d)
    X, y, X_star, theta = random_problem(rng, n, d, m)
    mean, var = predict(X, y, X_star, theta)
    sk_mean, sk_std = sklearn_gp(X, y, theta).predict(X_star, return_std=True)
    np.testing.assert_allclose(mean, sk_mean, rtol=RTOL_SKLEARN, atol=1e-10)
    np.testing.assert_allclose(var, sk_std**2, rtol=RTOL_SKLEARN, atol=1e-10 * theta[0])


def test_predict_latent_variance_matches_sklearn_without_white_kernel():
    rng = np.random.default_rng(1)
    X, y, X_star, theta = random_problem(rng, 12, 4, 6)
    mean, var = predict(X, y, X_star, theta, include_noise=False)
    # sklearn's alpha adds sn2 to the training diagonal only: its std is then the latent one.
    sk_mean, sk_std = sklearn_gp(X, y, theta, noise_in_kernel=False).predict(X_star, return_std=True)
    np.testing.assert_allclose(mean, sk_mean, rtol=RTOL_SKLEARN, atol=1e-10)
    np.testing.assert_allclose(var, sk_std**2, rtol=RTOL_SKLEARN, atol=1e-10 * theta[0])
    _, var_noisy = predict(X, y, X_star, theta)
    np.testing.assert_allclose(var_noisy - var, theta[1], rtol=1e-12)


@pytest.mark.parametrize("n, d", [(3, 1), (10, 2), (15, 12)])
def test_log_marginal_likelihood_and_gradient_match_sklearn(n, d):
    rng = np.random.default_rng(7 * n + d)
    X, y, _, theta = random_problem(rng, n, d, 1)
    lml, grad = log_marginal_likelihood(X, y, theta)
    gp = sklearn_gp(X, y, theta, fixed=False)
    # sklearn's theta is log-scale, ordered [log sf2, log l_1..l_d, log sn2].
    sk_theta = np.log(np.concatenate([[theta[0]], theta[2:], [theta[1]]]))
    sk_lml, sk_grad_log = gp.log_marginal_likelihood(sk_theta, eval_gradient=True)
    assert lml == pytest.approx(sk_lml, rel=1e-10, abs=1e-10)
    our_grad_log = theta * grad  # dL/dlog theta = theta dL/dtheta
    our_grad_log_sklearn_order = np.concatenate([[our_grad_log[0]], our_grad_log[2:], [our_grad_log[1]]])
    np.testing.assert_allclose(our_grad_log_sklearn_order, sk_grad_log, rtol=1e-7, atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_gradient_matches_central_finite_differences(seed):
    rng = np.random.default_rng(seed)
    X, y, _, theta = random_problem(rng, 8, 3, 1)
    _, grad = log_marginal_likelihood(X, y, theta)
    fd = np.empty_like(theta)
    for i in range(theta.size):
        h = 1e-5 * theta[i]
        up, down = theta.copy(), theta.copy()
        up[i] += h
        down[i] -= h
        fd[i] = (log_marginal_likelihood(X, y, up)[0] - log_marginal_likelihood(X, y, down)[0]) / (2 * h)
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-7 * np.abs(fd).max())


def test_interpolates_training_points_with_tiny_noise():
    rng = np.random.default_rng(3)
    X = rng.uniform(-3, 3, size=(8, 2))
    y = np.cos(X[:, 0]) * X[:, 1]
    theta = np.array([2.0, 1e-10, 1.5, 0.8])
    mean, var = predict(X, y, X, theta, include_noise=False)
    np.testing.assert_allclose(mean, y, atol=1e-6)
    assert np.all(var >= 0.0)
    assert np.max(var) < 1e-6 * theta[0]


def test_multi_output_functions_equal_per_output_calls():
    rng = np.random.default_rng(4)
    n, d, o = 11, 5, 4
    X = rng.normal(size=(n, d))
    Y = rng.normal(size=(n, o))
    X_star = rng.normal(size=(6, d))
    thetas = np.column_stack([rng.uniform(0.5, 2, o), rng.uniform(0.01, 0.2, o), rng.uniform(0.3, 3, (o, d))])
    mean, var = predict_multi(X, Y, X_star, thetas)
    lml, grad = log_marginal_likelihood_multi(X, Y, thetas)
    assert mean.shape == var.shape == (6, o)
    for k in range(o):
        mean_k, var_k = predict(X, Y[:, k], X_star, thetas[k])
        lml_k, grad_k = log_marginal_likelihood(X, Y[:, k], thetas[k])
        np.testing.assert_allclose(mean[:, k], mean_k, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(var[:, k], var_k, rtol=1e-10, atol=1e-12)
        assert lml[k] == pytest.approx(lml_k, rel=1e-12)
        np.testing.assert_allclose(grad[k], grad_k, rtol=1e-9, atol=1e-12)


# --------------------------------------------------------------------------
# SlidingWindowGP
# --------------------------------------------------------------------------


def window_lml(gp: SlidingWindowGP, theta_row: np.ndarray, output: int) -> float:
    """LML of one output on gp's current window, by the pure function."""
    return log_marginal_likelihood(gp.window_inputs, gp.window_targets[:, output], theta_row, jitter=gp.config.jitter)[
        0
    ]


def test_window_drops_oldest_sample():
    gp = SlidingWindowGP(n_inputs=2, n_outputs=3, config=GPConfig(window=5, hyper_steps=0))
    X = np.arange(16.0).reshape(8, 2)
    Y = 10.0 * np.arange(24.0).reshape(8, 3)
    for k in range(8):
        gp.update(X[k], Y[k])
        assert gp.n_samples == min(k + 1, 5)
    np.testing.assert_array_equal(gp.window_inputs, X[3:])
    np.testing.assert_array_equal(gp.window_targets, Y[3:])
    gp.reset()
    assert gp.n_samples == 0


@pytest.mark.parametrize("incremental_min_window", [2, 10**6])
def test_batched_prediction_equals_per_output_predict(incremental_min_window):
    X, Y = arm_like_stream(40, n_inputs=12, n_outputs=6, noise=0.01)
    gp = SlidingWindowGP(12, 6, GPConfig(hyper_steps=1, incremental_min_window=incremental_min_window))
    for k in range(30):
        gp.update(X[k], Y[k])
        gp.update_hyperparameters()
    assert not np.allclose(gp.theta, 1.0)  # the hyperparameters did move and differ per output
    X_star = X[30:34]
    mean, var = gp.predict(X_star)
    mean_one, var_one = gp.predict(X_star[0])
    assert mean.shape == var.shape == (4, 6) and mean_one.shape == var_one.shape == (6,)
    np.testing.assert_allclose(mean_one, mean[0], rtol=1e-12)
    for k in range(6):
        mean_k, var_k = predict(gp.window_inputs, gp.window_targets[:, k], X_star, gp.theta[k], jitter=gp.config.jitter)
        np.testing.assert_allclose(mean[:, k], mean_k, rtol=1e-8, atol=1e-8 * np.abs(mean_k).max())
        np.testing.assert_allclose(var[:, k], var_k, rtol=1e-8)
    assert (gp.stats.n_incremental_updates > 0) == (incremental_min_window == 2)


def test_normalize_y_matches_sklearn_normalize_y():
    rng = np.random.default_rng(5)
    X = rng.uniform(-1, 1, size=(9, 3))
    Y = 200.0 + 50.0 * np.column_stack([np.sin(3 * X[:, 0]), X[:, 1] * X[:, 2]])
    theta = np.array([1.3, 0.05, 0.7, 1.1, 2.0])
    gp = SlidingWindowGP(3, 2, GPConfig(normalize_y=True, hyper_steps=0, jitter=0.0))
    gp.set_theta(theta)
    for x, y in zip(X, Y):
        gp.update(x, y)
    X_star = rng.uniform(-1, 1, size=(5, 3))
    mean, var = gp.predict(X_star)
    kernel = ConstantKernel(theta[0], "fixed") * RBF(theta[2:], "fixed") + WhiteKernel(theta[1], "fixed")
    for k in range(2):
        sklearn_model = GaussianProcessRegressor(kernel=kernel, alpha=0.0, optimizer=None, normalize_y=True)
        sk_mean, sk_std = sklearn_model.fit(X, Y[:, k]).predict(X_star, return_std=True)
        np.testing.assert_allclose(mean[:, k], sk_mean, rtol=RTOL_SKLEARN)
        np.testing.assert_allclose(var[:, k], sk_std**2, rtol=RTOL_SKLEARN)


def test_input_and_output_scale_are_reparametrisations():
    rng = np.random.default_rng(6)
    X = rng.uniform(-5, 5, size=(10, 2))
    Y = 300.0 * np.column_stack([np.sin(X[:, 0] / 3), np.cos(X[:, 1] / 4)])
    x_scale, y_scale = (2.0, 10.0), 150.0
    scaled = SlidingWindowGP(2, 2, GPConfig(hyper_steps=0, jitter=0.0, input_scale=x_scale, output_scale=(y_scale,)))
    scaled.set_theta([1.5, 0.01, 1.2, 0.7])
    raw = SlidingWindowGP(2, 2, GPConfig(hyper_steps=0, jitter=0.0))
    raw.set_theta([1.5 * y_scale**2, 0.01 * y_scale**2, 1.2 * x_scale[0], 0.7 * x_scale[1]])
    for x, y in zip(X, Y):
        scaled.update(x, y)
        raw.update(x, y)
    X_star = rng.uniform(-5, 5, size=(4, 2))
    for a, b in zip(scaled.predict(X_star), raw.predict(X_star)):
        np.testing.assert_allclose(a, b, rtol=1e-9)


def test_lml_never_decreases_over_an_update():
    X, Y = arm_like_stream(150, n_inputs=12, n_outputs=6, noise=0.02, seed=11)
    # A large learning rate makes many full steps overshoot, so the safeguard is exercised.
    config = GPConfig(hyper_steps=2, learning_rate=1.0, max_log_step=2.0, max_step_halvings=2)
    gp = SlidingWindowGP(12, 6, config)
    for k in range(len(X)):
        gp.update(X[k], Y[k])
        theta_before = gp.theta
        trace = gp.update_hyperparameters()
        theta_after = gp.theta
        assert np.all(np.diff(trace, axis=0) >= 0.0)
        if k % 10 == 0:  # independent check with the pure function
            for o in range(6):
                before, after = window_lml(gp, theta_before[o], o), window_lml(gp, theta_after[o], o)
                assert after >= before - 1e-9 * abs(before)
                assert trace[0, o] == pytest.approx(before, rel=1e-8, abs=1e-8)
                assert trace[-1, o] == pytest.approx(after, rel=1e-8, abs=1e-8)
    assert gp.stats.n_step_halvings > 0 and gp.stats.n_rejected_steps > 0
    assert gp.stats.n_accepted_steps > 0


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_inputs=st.integers(1, 6),
    window=st.integers(2, 12),
    learning_rate=st.floats(0.01, 5.0),
)
def test_lml_monotone_and_bounds_respected_on_random_data(seed, n_inputs, window, learning_rate):
    rng = np.random.default_rng(seed)
    config = GPConfig(
        window=window,
        hyper_steps=3,
        learning_rate=learning_rate,
        max_log_step=1.5,
        log_sf2_bounds=(math.log(1e-2), math.log(1e2)),
        log_sn2_bounds=(math.log(1e-4), math.log(1e1)),
        log_lengthscale_bounds=(math.log(0.1), math.log(10.0)),
    )
    gp = SlidingWindowGP(n_inputs, 2, config)
    lower, upper = gp.log_bounds
    for _ in range(window + 5):
        gp.update(rng.normal(size=n_inputs) * rng.choice([0.01, 1.0, 100.0]), rng.normal(size=2) * 10.0)
        trace = gp.update_hyperparameters()
        finite = np.isfinite(trace)
        assert np.all(np.diff(np.where(finite, trace, 0.0), axis=0) >= 0.0)
        assert np.all(gp.log_theta >= lower) and np.all(gp.log_theta <= upper)
        assert np.all(gp.theta > 0.0)
        mean, var = gp.predict(rng.normal(size=n_inputs))
        assert np.all(np.isfinite(mean)) and np.all(var > 0.0)


def test_bounds_respected_with_aggressive_steps():
    X, Y = arm_like_stream(80, n_inputs=4, n_outputs=2, noise=0.05, seed=2)
    config = GPConfig(
        hyper_steps=3,
        learning_rate=50.0,
        max_log_step=5.0,
        log_sf2_bounds=(math.log(0.5), math.log(2.0)),
        log_sn2_bounds=(math.log(1e-3), math.log(1.0)),
        log_lengthscale_bounds=(math.log(0.5), math.log(5.0)),
    )
    gp = SlidingWindowGP(4, 2, config)
    lower, upper = gp.log_bounds
    hit_bound = np.zeros_like(gp.log_theta, dtype=bool)
    for x, y in zip(X, Y):
        gp.update(x, y)
        gp.update_hyperparameters()
        assert np.all(gp.log_theta >= lower) and np.all(gp.log_theta <= upper)
        hit_bound |= np.isclose(gp.log_theta, lower) | np.isclose(gp.log_theta, upper)
    assert hit_bound.any()  # the steps were large enough to reach the box


def fresh_inverse_factor(gp: SlidingWindowGP) -> np.ndarray:
    """Inverse Cholesky factors of gp's window at its current theta, computed afresh."""
    X, theta, noise = gp.window_inputs, gp.theta, gp.config.jitter
    factors = []
    for row in theta:
        K = row[0] * np.exp(-0.5 * (((X[:, None, :] - X[None, :, :]) / row[2:]) ** 2).sum(axis=-1))
        K[np.diag_indices_from(K)] += row[1] + noise
        factors.append(np.linalg.inv(np.linalg.cholesky(K)))
    return np.array(factors)


@pytest.mark.parametrize("window", [3, 8, 25])
def test_incremental_window_update_equals_full_refactorisation(window):
    X, Y = arm_like_stream(window + 40, n_inputs=5, n_outputs=3, noise=0.01, seed=window)
    config = GPConfig(window=window, hyper_steps=0, incremental_min_window=2, refactor_every=10**6)
    gp = SlidingWindowGP(5, 3, config)
    gp.set_theta(np.column_stack([[50.0, 200.0, 5.0], [0.5, 2.0, 0.01], np.full((3, 5), 2.5)]))
    full = SlidingWindowGP(5, 3, GPConfig(window=window, hyper_steps=0, incremental_min_window=10**6))
    full.set_theta(gp.theta)
    for k in range(len(X)):
        gp.update(X[k], Y[k])
        full.update(X[k], Y[k])
        mean, var = gp.predict(X[k] + 0.1)
        mean_full, var_full = full.predict(X[k] + 0.1)
        np.testing.assert_allclose(mean, mean_full, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(var, var_full, rtol=1e-9)
        np.testing.assert_allclose(gp._linv, fresh_inverse_factor(gp), rtol=1e-8, atol=1e-10)
    assert gp.stats.n_incremental_updates >= len(X) - 2
    assert full.stats.n_incremental_updates == 0


def test_incremental_update_refactorises_periodically():
    X, Y = arm_like_stream(30, n_inputs=3, n_outputs=2, seed=3)
    config = GPConfig(window=6, hyper_steps=0, incremental_min_window=2, refactor_every=5)
    gp = SlidingWindowGP(3, 2, config)
    for x, y in zip(X, Y):
        gp.update(x, y)
        gp.predict(x)
    assert gp.stats.n_incremental_updates > 0
    assert gp.stats.n_full_factorizations >= len(X) // 6


def test_identical_samples_need_jitter_but_do_not_raise():
    config = GPConfig(
        window=10,
        hyper_steps=2,
        jitter=0.0,
        theta0=(1.0, 1e-30, 1.0, 1.0),
        log_sn2_bounds=(math.log(1e-30), math.log(1.0)),
    )
    gp = SlidingWindowGP(2, 2, config)
    for _ in range(10):
        gp.update([0.3, -0.2], [1.0, 2.0])
        gp.update_hyperparameters()
        mean, var = gp.predict([0.3, -0.2])
        assert np.all(np.isfinite(mean)) and np.all(np.isfinite(var))
    assert gp.stats.n_jittered_factorizations > 0
    assert gp.stats.n_cholesky_fallbacks == 0
    np.testing.assert_allclose(mean, [1.0, 2.0], rtol=1e-3)


def test_failed_factorisation_falls_back_and_is_counted():
    config = GPConfig(
        window=10,
        hyper_steps=2,
        jitter=0.0,
        max_jitter_retries=0,
        theta0=(1.0, 1e-30, 1.0, 1.0),
        log_sn2_bounds=(math.log(1e-30), math.log(1.0)),
    )
    gp = SlidingWindowGP(2, 2, config)
    gp.update([0.3, -0.2], [1.0, 2.0])  # one sample: K is 1 x 1 and factorisable
    gp.update_hyperparameters()
    theta_one_sample = gp.theta
    for _ in range(10):  # from two identical samples on, K = sf2 * ones exactly: singular
        gp.update([0.3, -0.2], [1.0, 2.0])
        trace = gp.update_hyperparameters()  # must not raise LinAlgError
        mean, var = gp.predict([0.3, -0.2])
        assert np.all(np.isfinite(mean)) and np.all(np.isfinite(var))
    assert np.isnan(trace).all()  # no LML for outputs without a factor
    np.testing.assert_array_equal(gp.theta, theta_one_sample)  # previous hyperparameters kept
    assert gp.stats.n_cholesky_fallbacks >= 10 * 2
    assert gp.stats.n_prior_predictions >= 10 * 2
    np.testing.assert_array_equal(mean, 0.0)  # the prior mean
    np.testing.assert_allclose(var, theta_one_sample[:, 0] + theta_one_sample[:, 1])  # the prior variance


def degenerate_config(hyper_steps: int, max_jitter_retries: int) -> GPConfig:
    """Identical samples and sn2 = 1e-30: K = sf2 * ones, singular without jitter."""
    return GPConfig(
        window=10,
        hyper_steps=hyper_steps,
        jitter=0.0,
        max_jitter_retries=max_jitter_retries,
        theta0=(1.0, 1e-30, 1.0, 1.0),
        log_sn2_bounds=(math.log(1e-30), math.log(1.0)),
    )


def fault_counts(stats) -> dict[str, int]:
    return {
        "gp_jittered": stats.n_jittered_factorizations,
        "gp_cholesky_fallback": stats.n_cholesky_fallbacks,
        "gp_prior_prediction": stats.n_prior_predictions,
    }


@pytest.mark.parametrize("hyper_steps", [0, 2])
@pytest.mark.parametrize("max_jitter_retries", [0, 4])
def test_calls_return_the_fault_events_they_meet(hyper_steps, max_jitter_retries):
    """Each call returns its own events, grouped in FAULTS order; they add up to the counters."""
    assert set(FAULTS) <= set(FAULT_EVENTS)
    gp = SlidingWindowGP(2, 2, degenerate_config(hyper_steps, max_jitter_retries))
    returned = dict.fromkeys(FAULTS, 0)
    for _ in range(6):
        assert gp.update([0.3, -0.2], [1.0, 2.0]) is True  # update meets no fault
        before = fault_counts(gp.stats)
        trace, update_events = gp.update_hyperparameters(return_events=True)
        between = fault_counts(gp.stats)
        mean, var, predict_events = gp.predict([0.3, -0.2], return_events=True)
        after = fault_counts(gp.stats)
        for events, start, stop in ((update_events, before, between), (predict_events, between, after)):
            assert events == tuple(sorted(events, key=FAULTS.index))
            assert {name: events.count(name) for name in FAULTS} == {k: stop[k] - start[k] for k in FAULTS}
            for name in events:
                returned[name] += 1
        assert "gp_prior_prediction" not in update_events
        if hyper_steps:  # the update left its factor: predict meets no factorisation fault
            assert set(predict_events) <= {"gp_prior_prediction"}
        assert trace.shape[1] == 2 and (trace.shape[0] == 0) == (hyper_steps == 0)
        assert mean.shape == var.shape == (2,)
    assert returned == fault_counts(gp.stats)
    if max_jitter_retries:
        assert returned["gp_jittered"] > 0 and returned["gp_cholesky_fallback"] == 0
    else:
        assert returned["gp_cholesky_fallback"] > 0 and returned["gp_prior_prediction"] > 0


def test_without_return_events_the_calls_return_what_they_always_did():
    gp = SlidingWindowGP(2, 2, degenerate_config(2, 0))
    gp.update([0.3, -0.2], [1.0, 2.0])
    gp.update([0.3, -0.2], [1.0, 2.0])
    trace = gp.update_hyperparameters()
    assert isinstance(trace, np.ndarray) and trace.shape == (1, 2)
    prediction = gp.predict([0.3, -0.2])
    assert len(prediction) == 2 and prediction[0].shape == (2,)
    assert gp.stats.n_prior_predictions == 2  # still counted


@pytest.mark.parametrize("lengthscale", [1e-6, 1e6])
def test_extreme_lengthscales_do_not_raise(lengthscale):
    wide = (math.log(1e-8), math.log(1e8))
    config = GPConfig(
        window=8,
        hyper_steps=2,
        theta0=(1.0, 1e-12, lengthscale, lengthscale),
        log_sn2_bounds=(math.log(1e-14), math.log(1.0)),
        log_lengthscale_bounds=wide,
    )
    gp = SlidingWindowGP(2, 1, config)
    rng = np.random.default_rng(8)
    for _ in range(12):
        gp.update(rng.normal(size=2), rng.normal(size=1))
        gp.update_hyperparameters()
        mean, var = gp.predict(rng.normal(size=2))
        assert np.all(np.isfinite(mean)) and np.all(np.isfinite(var)) and np.all(var >= 0)
    assert gp.stats.n_updates == 12 and gp.stats.n_full_factorizations > 0


def test_empty_window_predicts_prior():
    gp = SlidingWindowGP(3, 2)
    mean, var = gp.predict(np.zeros(3))
    np.testing.assert_array_equal(mean, 0.0)
    np.testing.assert_allclose(var, 2.0)  # sf2 + sn2 = 1 + 1 (paper's initial theta)
    assert gp.update_hyperparameters().shape == (0, 2)


# --------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------


def test_pure_functions_reject_bad_inputs_naming_the_argument():
    X, y, X_star, theta = random_problem(np.random.default_rng(9), 6, 2, 3)
    with pytest.raises(ValueError, match="X must be 2-D"):
        predict(X[:, 0], y, X_star, theta)
    with pytest.raises(ValueError, match=r"y must have shape \(6,\)"):
        predict(X, y[:-1], X_star, theta)
    with pytest.raises(ValueError, match=r"X_star must have shape \(n, 2\)"):
        predict(X, y, X_star[:, :1], theta)
    with pytest.raises(ValueError, match=r"theta must have shape \(d\+2,\) = \(4,\)"):
        predict(X, y, X_star, theta[:3])
    with pytest.raises(ValueError, match="lengthscales"):
        predict(X, y, X_star, np.array([1.0, 0.1, -1.0, 1.0]))
    with pytest.raises(ValueError, match="sf2"):
        log_marginal_likelihood(X, y, np.array([0.0, 0.1, 1.0, 1.0]))
    bad_y = y.copy()
    bad_y[0] = np.nan
    with pytest.raises(ValueError, match="y must contain only finite"):
        log_marginal_likelihood(X, bad_y, theta)
    with pytest.raises(ValueError, match="jitter"):
        predict(X, y, X_star, theta, jitter=-1.0)
    with pytest.raises(ValueError, match=r"thetas must have shape \(n_outputs, d\+2\)"):
        predict_multi(X, np.column_stack([y, y]), X_star, theta[None])


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"window": 1}, "window"),
        ({"window": 2.5}, "window"),
        ({"hyper_steps": -1}, "hyper_steps"),
        ({"learning_rate": 0.0}, "learning_rate"),
        ({"max_log_step": float("inf")}, "max_log_step"),
        ({"max_step_halvings": -2}, "max_step_halvings"),
        ({"jitter": -1e-3}, "jitter"),
        ({"log_sn2_bounds": (1.0, -1.0)}, "log_sn2_bounds"),
        ({"log_sf2_bounds": (1.0, 2.0)}, "log_sf2_bounds"),  # excludes theta0 = 1
        ({"theta0": (1.0, 1.0, 1e9)}, "theta0"),
        ({"input_scale": (1.0, 0.0)}, "input_scale"),
        ({"normalize_y": True, "output_scale": (2.0,)}, "output_scale"),
        ({"incremental_min_window": 1}, "incremental_min_window"),
        ({"refactor_every": 0}, "refactor_every"),
    ],
)
def test_config_rejects_bad_values_naming_the_field(kwargs, field):
    with pytest.raises(pydantic.ValidationError, match=rf"(?s)GPConfig.*\b{field}\b") as error:
        GPConfig(**kwargs)
    assert error.value.error_count() == 1
    with pytest.raises(ConfigError, match=rf"^gp: {field}(\.\d+)? = "):
        validate(GPConfig, kwargs, "gp")


@pytest.mark.parametrize(
    "kwargs, expected",
    [
        ({"window": 1}, "gp: window = 1: Input should be greater than or equal to 2"),
        ({"window": 1001}, "gp: window = 1001: Input should be less than or equal to 1000"),
        ({"learning_rate": 0.0}, "gp: learning_rate = 0.0: Input should be greater than 0"),
        ({"max_jitter_retries": 21}, "gp: max_jitter_retries = 21: Input should be less than or equal to 20"),
        (
            {"log_sf2_bounds": [-200.0, 1.0]},
            "gp: log_sf2_bounds.0 = -200.0: Input should be greater than or equal to -100",
        ),
        (
            {"log_sn2_bounds": [1.0, -1.0]},
            "gp: log_sn2_bounds = (1.0, -1.0): must be (low, high) natural-log values with low < high",
        ),
        (
            {"log_sf2_bounds": [1.0, 2.0]},
            "gp: log_sf2_bounds = (1.0, 2.0): must contain 0 (theta0=None initialises theta to 1)",
        ),
        ({"theta0": [1.0, 1.0]}, "gp: theta0 = (1.0, 1.0): must be None or d+2 >= 3 values [sf2, sn2, l_1..l_d]"),
        ({"theta0": [1.0, 0.0, 1.0]}, "gp: theta0.1 = 0.0: Input should be greater than 0"),
        (
            {"theta0": [1.0, 1.0, 1e9]},
            "gp: theta0 = (1.0, 1.0, 1000000000.0): entry l_1 = 1000000000.0 must lie within "
            "exp(log_lengthscale_bounds = (-4.605170185988091, 6.907755278982137)) = [0.01, 1e+03]",
        ),
        ({"input_scale": [1.0, 2e6]}, "gp: input_scale.1 = 2000000.0: Input should be less than or equal to 1000000"),
        ({"output_scale": []}, "gp: output_scale = (): must be None or at least one value"),
        (
            {"normalize_y": True, "output_scale": [2.0]},
            "gp: output_scale = (2.0,): must be None when normalize_y is True (choose one target scaling)",
        ),
    ],
)
def test_config_errors_name_the_field_the_value_and_the_range(kwargs, expected):
    with pytest.raises(ConfigError) as error:
        validate(GPConfig, kwargs, "gp")
    assert str(error.value) == expected


def test_config_takes_lists_for_tuples_and_keeps_the_defaults():
    config = validate(GPConfig, {"theta0": [1, 2.0, 3], "log_sf2_bounds": [-1, 2]}, "gp")
    assert config.theta0 == (1.0, 2.0, 3.0) and config.log_sf2_bounds == (-1.0, 2.0)
    default = GPConfig()
    assert (default.window, default.hyper_steps, default.learning_rate, default.max_log_step) == (10, 1, 0.1, 1.0)
    assert default.log_sf2_bounds == (math.log(1e-4), math.log(1e8))
    assert default.log_sn2_bounds == (math.log(1e-6), math.log(1e6))
    assert default.log_lengthscale_bounds == (math.log(1e-2), math.log(1e3))
    assert (default.jitter, default.max_jitter_retries, default.incremental_min_window) == (1e-10, 4, 30)
    assert all(field.description for field in GPConfig.model_fields.values())


def test_config_is_frozen():
    config = GPConfig()
    with pytest.raises(pydantic.ValidationError, match="frozen"):
        config.window = 3  # type: ignore[misc]


def test_estimator_rejects_bad_inputs_naming_the_argument():
    with pytest.raises(ValueError, match="theta0"):
        SlidingWindowGP(3, 2, GPConfig(theta0=(1.0, 1.0, 1.0)))
    with pytest.raises(ValueError, match="input_scale"):
        SlidingWindowGP(3, 2, GPConfig(input_scale=(1.0, 1.0)))
    with pytest.raises(ValueError, match="n_outputs"):
        SlidingWindowGP(3, 0)
    gp = SlidingWindowGP(3, 2)
    with pytest.raises(ValueError, match=r"x must have shape \(3,\)"):
        gp.update(np.zeros(4), np.zeros(2))
    with pytest.raises(ValueError, match="y must contain only finite"):
        gp.update(np.zeros(3), np.array([0.0, np.inf]))
    with pytest.raises(ValueError, match="x_star"):
        gp.predict(np.zeros((2, 4)))
    with pytest.raises(ValueError, match="theta must lie within"):
        gp.set_theta(np.array([1e20, 1.0, 1.0, 1.0, 1.0]))
    assert gp.n_samples == 0  # failed calls changed nothing
