"""The one loop (hydroarm.sim.loop): every real-loop setting reaches every path where it applies
(the runner, the Gymnasium arm env) or is refused with one message naming the field (the vehicle
run, the vehicle env), as the issue on one closed loop asks."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("gymnasium")

from hydroarm.config import ConfigError  # noqa: E402
from hydroarm.envs.underwater_arm import ControllerPolicy, UnderwaterArmEnv  # noqa: E402
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, run_experiment, with_overrides  # noqa: E402


def test_the_arm_env_delivers_the_delayed_quantised_measurement():
    """sensor.delay = 5 periods and sensor.resolution = 0.1 rad: the env's observed q at step j is
    0.1 round(q_true(j - 5) / 0.1) (the first sample until then); on main the env ignored both."""
    delay, quantum = 5, 0.1
    settings = {"sensor.delay": delay, "sensor.resolution": quantum, "plant.noise_variance": 0.0}
    env = UnderwaterArmEnv(arm="paper", duration=0.3, settings=settings)
    n = env.n
    obs, _ = env.reset(seed=0)
    true_states = [env.state]
    observed = [obs[:n]]
    rng = np.random.default_rng(1)
    for _ in range(20):
        obs, *_ = env.step(rng.uniform(-0.5, 0.5, n))
        true_states.append(env.state)
        observed.append(obs[:n])
    for j, q_seen in enumerate(observed):
        q_true = true_states[max(0, j - delay)][:n]
        np.testing.assert_array_equal(q_seen, quantum * np.round(q_true / quantum))
    # the delay is real: the arm moved while the observation still showed its start
    assert not np.allclose(true_states[4][:n], true_states[0][:n])


def test_the_arm_env_applies_the_torque_through_the_drives():
    """actuator.delay = 1: the torque applied in step k is the command of step k - 1 (0 N m first)."""
    env = UnderwaterArmEnv(arm="paper", duration=0.1, action_mode="torque", settings={"actuator.delay": 1})
    env.reset(seed=0)
    commands, applied = [], []
    for k in range(5):
        command = np.full(env.n, 0.1 * (k + 1))
        *_, info = env.step(command)
        commands.append(command)
        applied.append(info["applied_torque"])
    np.testing.assert_array_equal(applied[0], np.zeros(env.n))
    np.testing.assert_array_equal(np.array(applied[1:]), np.array(commands[:-1]))


def test_a_controller_in_the_env_is_the_runner_in_the_real_loop():
    """Encoder-only, quantised, delayed, with dropout, late drives and joint friction: a controller
    driven through the env gives the runner's states and commands bit for bit on the same seed."""
    settings = {
        "arm": "paper",
        "duration": 0.4,
        "sensor.velocity": "differenced",
        "sensor.resolution": 1e-3,
        "sensor.delay": 2,
        "sensor.dropout": 0.1,
        "actuator.delay": 1,
        "friction.scale": 1.0,
        "estimator.kind": "kalman",
    }
    config = with_overrides(ExperimentConfig(), settings)
    env = UnderwaterArmEnv(config=config, action_mode="torque")
    policy = ControllerPolicy.from_name("MPC", env)  # runs to the end in this loop on main's defaults
    obs, _ = env.reset(seed=4)
    states, commands = [], []
    for _ in range(env.steps):
        action = policy(obs)
        obs, _, terminated, truncated, info = env.step(action)
        policy.observe(obs)
        states.append(info["x"])
        commands.append(action)
        assert not terminated
    traj = run_experiment(config, "MPC", seed=4)
    assert traj.meta["sensor"]["dropped"] > 0
    np.testing.assert_array_equal(np.array(states), traj.x)
    np.testing.assert_array_equal(np.array(commands), traj.extra["u_command"])


@pytest.mark.parametrize(
    "key, value",
    [
        ("sensor.delay", 2),
        ("sensor.resolution", 0.05),
        ("sensor.velocity", "differenced"),
        ("sensor.dropout", 0.1),
        ("actuator.delay", 1),
        ("actuator.rate_limit", 100.0),
        ("friction.scale", 1.0),
        ("plant.noise_variance", 0.01),
    ],
)
def test_a_vehicle_run_refuses_the_fixed_base_real_loop_settings(key, value):
    """The floating plant measures its true state and applies the arm's torques as commanded: a
    real-loop setting on a vehicle run is refused naming the field (was: validated, then ignored)."""
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):  # when the settings are validated
        build_experiment(with_overrides(ExperimentConfig(), {"vehicle.name": "bluerov2-heavy", key: value}), "idmpc")


def test_a_learning_arm_controller_learns_on_the_vehicle_env():
    """The vehicle env passes every transition to the arm controller's observe, as the runner does:
    PI-IDMPC's water model takes samples and moves its estimate over an episode (on main it never
    saw one)."""
    from hydroarm.envs.vehicle import UVMSEnv

    env = UVMSEnv(arm_controller="pi-idmpc", duration=0.5)
    controller = env.arm_controller.controller  # PI-IDMPC behind its state filter
    env.reset(seed=0)
    prior = controller.model.theta.copy()
    for _ in range(env.steps):
        env.step(np.zeros(env.n_thr))
    assert controller.model.samples > 0
    assert not np.array_equal(controller.model.theta, prior)


@pytest.mark.parametrize("key, value", [("sensor.delay", 2), ("actuator.delay", 1), ("friction.scale", 1.0)])
def test_the_vehicle_env_refuses_the_fixed_base_real_loop_settings(key, value):
    from hydroarm.envs.vehicle import UVMSEnv

    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):  # when the settings are validated
        UVMSEnv(
            config=with_overrides(ExperimentConfig(), {"vehicle.name": "bluerov2-heavy", "arm": "mount", key: value})
        )
