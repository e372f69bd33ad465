"""The filter's defaults follow the sensor it is given (issue 32): its kind, its sigma_a^2 and its
measurement variance come from the sensor and the loop, a lost sample is bridged with the grown
covariance, and the default real loop that diverged before does not."""

from __future__ import annotations

import numpy as np
import pytest

from hydroarm.control.estimator import EstimatorConfig, JointKalmanFilter
from hydroarm.control.filter_design import (
    MEASURED_VELOCITY_ACCELERATION_VARIANCE,
    TRACKING_INDEX_LIMIT,
    FilterDesign,
    derived_acceleration_variance,
    tracking_index,
)
from hydroarm.control.linear import double_integrator
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides

PERIOD = 0.01
SIXTEEN_BIT = 2 * np.pi / 2**16
REAL_LOOP = {
    "sensor.velocity": "differenced",
    "sensor.resolution": 9.5874e-05,
    "sensor.delay": 1,
    "friction.scale": 1.0,
}


def test_sigma_a_is_the_papers_with_q_and_v_measured_and_capped_by_the_tracking_index_behind_an_encoder():
    assert derived_acceleration_variance(False, 1e-3, PERIOD) == MEASURED_VELOCITY_ACCELERATION_VARIANCE
    assert derived_acceleration_variance(False, 0.0, PERIOD) == MEASURED_VELOCITY_ACCELERATION_VARIANCE
    quantum = SIXTEEN_BIT**2 / 12  # a 16-bit encoder's quantisation variance
    sixteen = derived_acceleration_variance(True, quantum, PERIOD)
    assert sixteen == pytest.approx(TRACKING_INDEX_LIMIT**2 * quantum / PERIOD**4, rel=1e-15)
    assert sixteen == pytest.approx(68.94, abs=0.01)  # below 100: a 16-bit encoder is capped
    assert tracking_index(sixteen, quantum, PERIOD) == pytest.approx(TRACKING_INDEX_LIMIT, rel=1e-12)
    assert tracking_index(100.0, quantum, PERIOD) == pytest.approx(36.1, abs=0.1)  # the old default's
    coarse = (2 * np.pi / 2**12) ** 2 / 12  # a 12-bit encoder: lambda = 2.3 at 100, kept
    assert derived_acceleration_variance(True, coarse, PERIOD) == MEASURED_VELOCITY_ACCELERATION_VARIANCE
    # the gains depend on lambda alone: a finer encoder gets the same filter
    gains = []
    for variance in (quantum, quantum / 256):
        design = FilterDesign(position_only=True, position_variance=variance)
        gains.append(JointKalmanFilter(1, PERIOD, EstimatorConfig(), design).gain)
    np.testing.assert_allclose(gains[0], gains[1], rtol=1e-8)


def test_the_experiment_builds_the_filter_for_its_sensor_and_an_explicit_value_wins():
    config = with_overrides(ExperimentConfig(duration=0.1), REAL_LOOP)
    kalman = build_experiment(config, "IDMPC").controller.kalman
    assert kalman.position_only and kalman.delay == 1
    # the quantisation's res^2 / 12 reaches the filter (it used to be dropped for the noise's 0)
    assert kalman.design.position_variance == pytest.approx(9.5874e-05**2 / 12, rel=1e-15)
    assert kalman.acceleration_variance == pytest.approx(TRACKING_INDEX_LIMIT**2 * 9.5874e-05**2 / 12 / PERIOD**4)
    explicit = with_overrides(config, {"estimator.acceleration_variance": 0.1})
    assert build_experiment(explicit, "IDMPC").controller.kalman.acceleration_variance == 0.1
    paper = build_experiment(ExperimentConfig(duration=0.1, plant={"noise_variance": 1e-3}), "IDMPC")
    assert paper.controller.kalman.acceleration_variance == 100.0


@pytest.mark.parametrize(
    ("overrides", "filtered"),
    [
        ({}, False),
        ({"plant.noise_variance": 1e-3}, False),  # the paper's noisy sensor: the paper's controllers as published
        ({"friction.scale": 1.0}, False),
        ({"sensor.velocity": "differenced"}, True),
        ({"sensor.resolution": SIXTEEN_BIT}, True),
        ({"sensor.delay": 1}, True),
        ({"actuator.delay": 1}, True),
        ({"sensor.dropout": 0.1}, True),
    ],
)
def test_auto_puts_every_controller_behind_the_filter_unless_the_sensor_is_the_ideal_one(overrides, filtered):
    config = with_overrides(ExperimentConfig(duration=0.1), overrides)
    controller = build_experiment(config, "SMC").controller
    assert controller.name == ("SMC+KF" if filtered else "SMC")
    assert build_experiment(with_overrides(config, {"estimator.kind": "none"}), "SMC").controller.name == "SMC"


def test_a_bridged_sample_is_corrected_with_the_covariance_it_grew():
    """After a lost sample the correction is the Kalman filter's for the prior grown over two
    periods (computed here step by step), not the steady one-period gain (which over-corrects the
    velocity by the second period's error: the dropout worlds diverged); then it returns to the
    steady gain."""
    variance = SIXTEEN_BIT**2 / 12
    design = FilterDesign(position_only=True, position_variance=variance)
    kalman = JointKalmanFilter(1, PERIOD, EstimatorConfig(acceleration_variance=50.0), design)
    a_mat, b_vec = double_integrator(PERIOD)
    c_mat, noise = np.array([[1.0, 0.0]]), np.array([[variance]])
    process = 50.0 * np.outer(b_vec, b_vec)
    sigma = kalman.covariance
    posterior = (np.eye(2) - kalman.gain @ c_mat) @ sigma
    np.testing.assert_allclose(a_mat @ posterior @ a_mat.T + process, sigma, rtol=1e-9)  # steady
    y = lambda q: np.array([q, 0.0])  # noqa: E731
    kalman.update(y(0.0))
    for k in range(1, 5):
        kalman.predict(np.zeros(1))
        kalman.update(y(1e-3 * k))
    kalman.predict(np.zeros(1))
    before = kalman.estimate.copy()
    kalman.update(y(4e-3))  # the same sample again: lost
    np.testing.assert_array_equal(kalman.estimate, before)
    kalman.predict(np.zeros(1))
    prior = a_mat @ sigma @ a_mat.T + process  # no correction at the lost sample
    gain = prior @ c_mat.T @ np.linalg.inv(c_mat @ prior @ c_mat.T + noise)
    # two periods of velocity error are in the innovation: the steady gain would over-correct
    assert gain[1, 0] < 0.5 * kalman.gain[1, 0] and gain[0, 0] > kalman.gain[0, 0]
    predicted = kalman.estimate.copy()
    corrected = kalman.update(y(7e-3))
    np.testing.assert_allclose(corrected, predicted + gain[:, 0] * (7e-3 - predicted[0]), rtol=1e-12, atol=1e-15)
    for k in range(200):  # back to the steady gain
        kalman.predict(np.zeros(1))
        kalman.update(y(7e-3 + 1e-4 * (k + 1)))
    assert kalman._prior is None and kalman._posterior is None


@pytest.mark.parametrize("controller", ["IDMPC", "GP-IDMPC"])
def test_the_default_real_loop_that_diverged_does_not(controller):
    """The issue's command (16-bit encoder, one period of delay, the published friction), 1.5 s:
    before, the default filter (sigma_a^2 = 100 on a variance floored at 1e-12, lambda = 1000)
    diverged at 0.32 s."""
    config = with_overrides(ExperimentConfig(duration=1.5), REAL_LOOP)
    traj = build_experiment(config, controller).run(0)
    assert not traj.diverged and not traj.meta["stopped"]
    late = traj.t >= 1.0
    assert np.max(np.abs(traj.q_ref - traj.q)[late]) < 0.5  # rad: tracking, not just bounded


def test_the_prediction_knows_the_drives_lag():
    """With a 20 Hz drive lag the acceleration the filter steps on is the command's plus what
    the lag takes off it, M(q)^-1 (a - u) with a = (1 - exp(-2 pi f T)) u after a step from rest;
    and the target world with that lag, which diverged at 0.25 s with the prediction blind to the
    drives, does not."""
    config = with_overrides(ExperimentConfig(duration=1.5), {**REAL_LOOP, "actuator.bandwidth": 20.0})
    experiment = build_experiment(config, "IDMPC")
    filtered = experiment.controller
    assert filtered.drives is not None
    state = np.concatenate([np.full(6, 0.3), np.zeros(6)])
    tau = np.linspace(-2.0, 3.0, 6)
    correction = filtered._drive_correction(state, tau)
    applied = (1.0 - np.exp(-2.0 * np.pi * 20.0 * PERIOD)) * tau
    mass = experiment.arm.mass_matrix(state[:6])
    np.testing.assert_allclose(mass @ correction, applied - tau, rtol=1e-10, atol=1e-12)
    filtered.reset()
    traj = experiment.run(0)
    assert not traj.diverged and not traj.meta["stopped"]
