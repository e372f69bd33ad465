"""The real loop (issue 23): sensor, drives, joint friction, and the filter that survives them.

Each effect is checked against what it must do exactly (the count grid, a shift of k samples,
the rate bound, the dropout rate, Coulomb's breakaway), and the idealised loop against the
numbers it gave before these settings existed.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from typer.testing import CliRunner

from hydroarm.cli import app
from hydroarm.config import ConfigError
from hydroarm.control.estimator import EstimatorConfig, FilteredController, JointKalmanFilter
from hydroarm.control.filter_design import FilterDesign
from hydroarm.control.interface import ControlOutput
from hydroarm.model.arm.loading import load_arm
from hydroarm.model.arm.plant import PlantConfig, UnderwaterPlant
from hydroarm.model.dynamics.nominal import NominalModel
from hydroarm.model.real_loop.friction import PUBLISHED_COULOMB, PUBLISHED_WIDTH, FrictionConfig
from hydroarm.model.real_loop.sensing import Actuator, ActuatorConfig, Sensor, SensorConfig
from hydroarm.model.water.morison import Water
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides

RUNNER = CliRunner()
PERIOD = 0.01
N = 6


@pytest.fixture(scope="module")
def arm():
    return load_arm("paper")


def states(count: int, seed: int = 1) -> np.ndarray:
    """A smooth joint trajectory [q, v] (count, 2n) to sample."""
    t = np.arange(count)[:, None] * PERIOD
    phase = np.random.default_rng(seed).uniform(0, 2 * np.pi, N)
    return np.hstack([np.sin(2.0 * t + phase), 2.0 * np.cos(2.0 * t + phase)])


def sampled(config: SensorConfig, xs: np.ndarray, noise: float = 0.0, seed: int = 0) -> tuple[np.ndarray, Sensor]:
    sensor = Sensor(config, N, PERIOD, noise, np.random.default_rng(seed), seed)
    return np.array([sensor.sample(x) for x in xs]), sensor


# --- sensing --------------------------------------------------------------------------------


def test_quantisation_gives_the_exact_count_grid():
    resolution = 2 * np.pi / 2**12
    xs = states(500)
    ys, _ = sampled(SensorConfig(resolution=resolution), xs)
    counts = np.round(ys[:, :N] / resolution)
    np.testing.assert_array_equal(ys[:, :N], resolution * counts)  # a whole number of counts, exactly
    assert np.max(np.abs(ys[:, :N] - xs[:, :N])) <= resolution / 2  # the nearest count
    np.testing.assert_array_equal(ys[:, N:], xs[:, N:])  # a measured velocity is not quantised
    assert len(np.unique(counts)) > 100


def test_encoder_only_velocity_is_the_difference_of_the_quantised_positions():
    resolution = 2 * np.pi / 2**16
    xs = states(300)
    ys, _ = sampled(SensorConfig(velocity="differenced", resolution=resolution), xs)
    np.testing.assert_array_equal(ys[0, N:], np.zeros(N))
    np.testing.assert_array_equal(ys[1:, N:], (ys[1:, :N] - ys[:-1, :N]) / PERIOD)
    # the difference lags the true velocity by half a period, within a count per period
    midpoint = 0.5 * (xs[1:, N:] + xs[:-1, N:])
    assert np.max(np.abs(ys[1:, N:] - midpoint)) < resolution / PERIOD + 1e-3


@pytest.mark.parametrize("delay", [1, 2, 5])
def test_a_delay_of_k_periods_shifts_the_measured_series_by_k_samples(delay):
    xs = states(200)
    prompt, _ = sampled(SensorConfig(velocity="differenced", resolution=1e-4), xs, noise=1e-4, seed=4)
    late, _ = sampled(SensorConfig(velocity="differenced", resolution=1e-4, delay=delay), xs, noise=1e-4, seed=4)
    np.testing.assert_array_equal(late[delay:], prompt[:-delay])
    np.testing.assert_array_equal(late[:delay], np.repeat(prompt[:1], delay, axis=0))  # the first sample until then


def test_dropout_repeats_samples_at_the_drawn_rate():
    count, rate = 20_000, 0.1
    xs = np.repeat(states(1), count, axis=0)
    ys, sensor = sampled(SensorConfig(dropout=rate), xs, noise=1e-3, seed=7)
    repeats = np.all(ys[1:] == ys[:-1], axis=1)
    assert repeats.sum() == sensor.dropped
    sigma = np.sqrt(rate * (1 - rate) / (count - 1))
    assert abs(repeats.mean() - rate) < 4 * sigma
    fresh, _ = sampled(SensorConfig(), xs, noise=1e-3, seed=7)
    assert not np.any(np.all(fresh[1:] == fresh[:-1], axis=1))  # without dropout, never
    # dropout draws from its own stream: the noise of the samples that arrive is unchanged
    arrived = np.flatnonzero(~np.concatenate([[False], repeats]))
    np.testing.assert_array_equal(ys[arrived], fresh[arrived])


def test_the_ideal_sensor_is_the_papers_draw_for_draw(arm):
    plant = UnderwaterPlant(arm, Water(), PlantConfig(noise_variance=1e-3))
    xs = states(50)
    ideal, _ = sampled(SensorConfig(), xs, noise=1e-3, seed=11)
    rng = np.random.default_rng(11)
    np.testing.assert_array_equal(ideal, np.array([plant.measure(x, rng) for x in xs]))


# --- actuation ------------------------------------------------------------------------------


def test_the_rate_limit_bounds_the_torque_slope_and_the_lag_is_first_order():
    rate = 200.0  # N m/s: 2 N m per 10 ms period
    drives = Actuator(ActuatorConfig(rate_limit=rate), N, PERIOD)
    commands = np.where((np.arange(300) // 50) % 2 == 0, 30.0, -30.0)[:, None] * np.ones(N)
    applied = np.array([drives.apply(u) for u in commands])
    slopes = np.abs(np.diff(np.vstack([np.zeros(N), applied]), axis=0)) / PERIOD
    assert slopes.max() <= rate * (1 + 1e-12)
    assert np.isclose(slopes.max(), rate)  # the limit is met, so it was what bounded the step
    lag = Actuator(ActuatorConfig(bandwidth=5.0), N, PERIOD)
    step = np.array([lag.apply(np.ones(N)) for _ in range(40)])[:, 0]
    expected = 1.0 - np.exp(-2 * np.pi * 5.0 * PERIOD * np.arange(1, 41))
    np.testing.assert_allclose(step, expected, rtol=1e-12)


def test_the_actuator_delay_shifts_the_applied_torque_and_the_plant_holds_the_limits(arm):
    drives = Actuator(ActuatorConfig(delay=2, torque_limit=5.0), N, PERIOD)
    commands = np.arange(1.0, 11.0)[:, None] * np.ones(N)
    applied = np.array([drives.apply(u) for u in commands])
    np.testing.assert_array_equal(applied[:2], 0.0)
    np.testing.assert_array_equal(applied[2:], np.minimum(commands[:-2], 5.0))
    config = with_overrides(ExperimentConfig(duration=0.5), {"actuator.rate_limit": 100.0})
    traj = build_experiment(config, "SMC").run(0)
    slopes = np.abs(np.diff(traj.u, axis=0)) / PERIOD
    assert slopes.max() <= 100.0 * (1 + 1e-12)
    assert np.abs(np.diff(traj.extra["u_command"], axis=0)).max() / PERIOD > 1000.0  # the command is not limited


# --- friction -------------------------------------------------------------------------------


def held_torque(plant: UnderwaterPlant, q: np.ndarray, extra: np.ndarray, seconds: float) -> np.ndarray:
    """Joint positions after ``seconds`` s from rest at q, gravity compensated plus ``extra``."""
    tau = pin.computeGeneralizedGravity(plant.arm.model, plant.arm.create_data(), q) + extra
    x = np.concatenate([q, np.zeros(N)])
    for k in range(int(round(seconds / PERIOD))):
        x, _ = plant.step(k * PERIOD, x, tau, PERIOD)
    return x


def test_coulomb_friction_holds_a_joint_below_breakaway_and_lets_it_move_above(arm):
    width = [1e-3, 0.5, 0.5, 0.5, 0.5, 0.5]  # rad/s: a stiff tanh on joint 1, whose inertia allows it
    friction = FrictionConfig(scale=1.0, coulomb=0.3, breakaway=0.45, stribeck_velocity=0.05, width=width)
    plant = UnderwaterPlant(arm, Water().off(), PlantConfig(inner_step=2e-4), friction=friction)
    q = np.array([0.0, -0.5, 0.5, 0.0, 0.3, 0.0])
    inertia = arm.mass_matrix(q)[0, 0]
    for torque in (0.15, 0.4):  # below the Coulomb level, and between it and breakaway
        x = held_torque(plant, q, np.eye(N)[0] * torque, 1.0)
        creep = 1e-3 * np.arctanh(torque / 0.45)  # rad/s: the regularisation's creep, w atanh(tau / F_s)
        assert abs(x[0] - q[0]) <= 1.05 * creep * 1.0 and abs(x[N]) <= 1.05 * creep, torque  # still, but for it
        assert abs(x[0] - q[0]) < 0.05 * 0.5 * torque / inertia  # 5 % of the frictionless joint's travel
    x = held_torque(plant, q, np.eye(N)[0] * 0.9, 1.0)
    slid = 0.5 * (0.9 - 0.3) / inertia * 1.0**2  # once sliding, the friction is F_c
    assert x[0] - q[0] > 0.5 * slid and abs(x[0] - q[0] - slid) < 0.15 * slid
    frictionless = UnderwaterPlant(arm, Water().off(), PlantConfig(inner_step=2e-4))
    moved = held_torque(frictionless, q, np.eye(N)[0] * 0.15, 1.0)
    assert moved[0] - q[0] > 0.5 * 0.5 * 0.15 / inertia  # the same small torque moves a frictionless joint


def test_the_published_friction_and_its_disturbance(arm):
    coulomb, _, _, _, width = FrictionConfig(scale=1.0).arrays(N)
    np.testing.assert_array_equal(coulomb, PUBLISHED_COULOMB[:N])
    np.testing.assert_array_equal(width, PUBLISHED_WIDTH[:N])
    plant = UnderwaterPlant(arm, Water().off(), PlantConfig(inner_step=1e-4), friction=FrictionConfig(scale=2.0))
    v = np.linspace(-1.0, 1.0, N)
    expected = 2.0 * np.array(PUBLISHED_COULOMB[:N]) * np.tanh(v / np.array(PUBLISHED_WIDTH[:N]))
    np.testing.assert_allclose(plant.friction_torque(v), expected, rtol=1e-14)
    # the dry model lacks the friction: in still, dry water the disturbance is exactly -f(v)
    q, tau = np.zeros(N), np.ones(N)
    np.testing.assert_allclose(plant.disturbance(0.0, q, v, tau), -expected, atol=1e-9)
    stiff = UnderwaterPlant(arm, Water(), PlantConfig(), friction=FrictionConfig(scale=1.0))
    slopes = np.diag(FrictionConfig(scale=1.0).max_slope(N))
    rate = np.linalg.eigvals(np.linalg.solve(stiff._inertia(), slopes)).real.max()
    assert stiff.inner_step < 1e-3 and np.isclose(stiff.inner_step * rate, 2.5)  # RK4-stable, no longer
    with pytest.raises(ConfigError, match="friction.breakaway"):
        FrictionConfig(scale=1.0, coulomb=0.5, breakaway=0.2).arrays(N)


def test_the_compiled_friction_is_the_numpy_twins_bit_for_bit(arm):
    plant = UnderwaterPlant(arm, Water(), PlantConfig(inner_step=2e-4), friction=FrictionConfig(scale=1.0))
    x = np.concatenate([np.linspace(-1, 1, N), np.linspace(0.3, -0.2, N)])
    tau = np.linspace(-5, 5, N)
    fast, fast_info = plant.step(0.1, x, tau, PERIOD)
    slow, slow_info = plant.step_numpy(0.1, x, tau, PERIOD)
    np.testing.assert_array_equal(fast, slow)
    np.testing.assert_array_equal(fast_info.disturbance, slow_info.disturbance)


# --- the filter -----------------------------------------------------------------------------


def test_the_position_only_filter_estimates_the_velocity():
    design = FilterDesign(position_only=True, position_variance=(1e-4) ** 2 / 12, delay=0)
    kalman = JointKalmanFilter(N, PERIOD, EstimatorConfig(acceleration_variance=1.0), design)
    assert kalman.gain.shape == (2, 1)
    acceleration = np.linspace(-2.0, 2.0, N)
    q, v = np.zeros(N), np.linspace(-1, 1, N)
    errors = []
    for _ in range(300):
        y = np.concatenate([1e-4 * np.round(q / 1e-4), np.full(N, 99.0)])  # the velocity channel is ignored
        estimate = kalman.update(y)
        errors.append(np.abs(estimate[N:] - v).max())
        kalman.predict(acceleration)
        q, v = q + PERIOD * v + 0.5 * PERIOD**2 * acceleration, v + PERIOD * acceleration
    assert errors[0] > 0.9  # it starts from v = 0
    assert max(errors[100:]) < 0.02  # then the velocity is known within a few counts per period


def test_a_repeated_sample_is_bridged_by_the_prediction_not_taken_as_new():
    kalman = JointKalmanFilter(N, PERIOD, EstimatorConfig(measurement_variance=0.0))  # exact: L = I
    y = np.concatenate([np.zeros(N), np.ones(N)])
    np.testing.assert_array_equal(kalman.update(y), y)
    kalman.predict(np.full(N, 2.0))
    bridged = kalman.update(y.copy())  # the same sample again: a dropout
    np.testing.assert_allclose(bridged[:N], PERIOD * 1.0 + 0.5 * PERIOD**2 * 2.0)
    np.testing.assert_allclose(bridged[N:], 1.0 + PERIOD * 2.0)
    assert kalman.skipped == 1
    used = JointKalmanFilter(N, PERIOD, EstimatorConfig(measurement_variance=0.0, repeated="use"))
    used.update(y)
    used.predict(np.full(N, 2.0))
    np.testing.assert_array_equal(used.update(y.copy()), y)


class Stub:
    """A controller that commands a known acceleration and records the state it is given."""

    name = "stub"
    control_period = PERIOD

    def __init__(self):
        self.seen: list[np.ndarray] = []
        self.observed: list[np.ndarray] = []

    def reset(self):
        self.seen.clear()
        self.observed.clear()

    def compute(self, t, y, reference):
        self.seen.append(np.array(y))
        acceleration = np.sin(3.0 * t + np.arange(N))
        return ControlOutput(tau=np.zeros(N), acceleration=acceleration)

    def observe(self, t, y, u, y_next):
        self.observed.append(np.array(y_next))


def test_a_learning_controller_does_not_learn_from_a_bridged_sample(arm):
    stub = Stub()
    kalman = JointKalmanFilter(N, PERIOD, EstimatorConfig(measurement_variance=0.0))
    wrapped = FilteredController(stub, kalman, NominalModel(arm, inner_step=None))
    samples = [np.full(2 * N, k, dtype=float) for k in (0, 1, 1, 2, 3)]  # the third is a repeat: lost
    for k in range(4):
        wrapped.compute(k * PERIOD, samples[k], None)
        wrapped.observe(k * PERIOD, samples[k], np.zeros(N), samples[k + 1])
    # transitions 0->1 and 2->3 are real; 1->1' (into the bridged sample) and 1'->2 (out of it) are not
    assert [o[0] for o in stub.observed] == [1.0, 3.0]
    # with a sensor delay the first sample is held: its repeats are not lost samples
    delayed = EstimatorConfig(measurement_variance=0.0)
    design = delayed.design(0.0, SensorConfig(delay=1), loop_delay=1)
    stub = Stub()
    wrapped = FilteredController(
        stub, JointKalmanFilter(N, PERIOD, delayed, design), NominalModel(arm, inner_step=None)
    )
    samples = [np.full(2 * N, k, dtype=float) for k in (0, 0, 1, 2)]  # sample 0 held for one period
    for k in range(3):
        wrapped.compute(k * PERIOD, samples[k], None)
        wrapped.observe(k * PERIOD, samples[k], np.zeros(N), samples[k + 1])
    assert [o[0] for o in stub.observed] == [1.0, 2.0]  # 0 -> 1 is observed once the delay line is full


@pytest.mark.parametrize(("sensor_delay", "actuator_delay"), [(1, 0), (2, 0), (0, 2), (2, 1)])
def test_the_filter_predicts_across_the_loop_delay(arm, sensor_delay, actuator_delay):
    """On a double-integrator plant that does what is commanded, the controller behind the
    filter is given the state at which its command will act, exactly."""
    d = sensor_delay + actuator_delay
    config = EstimatorConfig(measurement_variance=0.0)
    design = config.design(0.0, SensorConfig(delay=sensor_delay), loop_delay=d)
    stub = Stub()
    wrapped = FilteredController(stub, JointKalmanFilter(N, PERIOD, config, design), NominalModel(arm, inner_step=None))
    sensor = Sensor(SensorConfig(delay=sensor_delay), N, PERIOD, 0.0, np.random.default_rng(0), 0)
    drives = Actuator(ActuatorConfig(delay=actuator_delay), N, PERIOD)
    x = np.concatenate([np.zeros(N), np.linspace(-1, 1, N)])
    truth, commanded = [], []
    y = sensor.sample(x)
    for k in range(60):
        truth.append(x.copy())
        out = wrapped.compute(k * PERIOD, y, None)
        commanded.append(out.acceleration)
        applied = drives.apply(out.acceleration)  # the "torque" is the acceleration here
        x = np.concatenate([x[:N] + PERIOD * x[N:] + 0.5 * PERIOD**2 * applied, x[N:] + PERIOD * applied])
        y_next = sensor.sample(x)
        wrapped.observe(k * PERIOD, y, np.zeros(N), y_next)
        y = y_next
    # the state the stub saw at step k is x_{k + d_a}: from the first step on without a drive delay
    # (while the sensor holds its first sample the filter's state is x_0, stepped k periods, not
    # d), else once no step before the first command arrives is in the prediction (the filter
    # steps those on the dry arm unforced, this plant holds still)
    for k in range(0 if actuator_delay == 0 else d, 55):
        np.testing.assert_allclose(stub.seen[k], truth[k + actuator_delay], atol=1e-12)


def test_every_controller_runs_behind_the_filter_in_the_real_loop():
    resolution = 2 * np.pi / 2**16
    config = with_overrides(
        ExperimentConfig(duration=1.0),
        {"sensor.velocity": "differenced", "sensor.resolution": resolution, "sensor.delay": 1,
         "estimator.kind": "kalman", "estimator.acceleration_variance": 0.1},
    )  # fmt: skip
    for name in ("SMC", "MPC", "GP-MPC", "IDMPC", "GP-IDMPC"):
        experiment = build_experiment(config, name)
        assert experiment.controller.kalman.position_only and experiment.controller.delay == 1
        traj = experiment.run(0)
        assert not traj.diverged, name


# --- the idealised loop and bad settings ----------------------------------------------------


def test_default_real_loop_settings_leave_the_settings_digest_alone():
    default = ExperimentConfig()
    assert {"sensor", "actuator", "friction"}.isdisjoint(default.canonical())
    assert {"measures", "delay", "repeated"}.isdisjoint(default.canonical()["estimator"])
    assert with_overrides(default, {"sensor.delay": 0}).digest() == default.digest()
    assert with_overrides(default, {"sensor.delay": 1}).digest() != default.digest()


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("sensor.delay", "-1", "sensor.delay = -1: Input should be greater than or equal to 0"),
        ("actuator.delay", "-2", "actuator.delay = -2: Input should be greater than or equal to 0"),
        ("sensor.resolution", "3.5", "sensor.resolution = 3.5: Input should be less than or equal to 3.14159"),
        ("sensor.dropout", "1.0", "sensor.dropout = 1.0: Input should be less than 1"),
        ("sensor.dropout", "-0.1", "sensor.dropout = -0.1: Input should be greater than or equal to 0"),
        ("friction.coulomb", "-0.1", "friction.coulomb = -0.1: Input should be greater than or equal to 0"),
        ("friction.scale", "-1", "friction.scale = -1: Input should be greater than or equal to 0"),
        ("actuator.rate_limit", "0", "actuator.rate_limit = 0: Input should be greater than 0"),
        ("estimator.delay", "-1", "estimator.delay = -1: must be 'plant' or a whole number of periods"),
    ],
)
def test_bad_real_loop_settings_exit_2_naming_the_field_and_its_range(tmp_path, key, value, message):
    result = RUNNER.invoke(app, ["run", "--controller", "smc", "--set", f"{key}={value}", "--out", str(tmp_path)])
    assert result.exit_code == 2, result.output
    assert message in " ".join(result.output.split()), result.output
    assert "Traceback" not in result.output
