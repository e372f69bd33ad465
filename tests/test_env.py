"""The Gymnasium environment: API check, seeding, and the same E_p as the runner."""

from __future__ import annotations

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

import hydroarm  # noqa: E402  (registers the environment)
from hydroarm.envs.underwater_arm import ControllerPolicy, UnderwaterArmEnv  # noqa: E402
from hydroarm.studies.experiment import ExperimentConfig, run_experiment, with_overrides  # noqa: E402
from hydroarm.studies.runner import tracking_metrics  # noqa: E402


def test_passes_gymnasium_env_checker():
    from gymnasium.utils.env_checker import check_env

    env = gymnasium.make("hydroarm/UnderwaterArm-v0", arm="paper", duration=0.2)
    check_env(env.unwrapped, skip_render_check=True)
    assert env.observation_space.shape == (24,)
    np.testing.assert_array_equal(env.action_space.high, hydroarm.load_arm("paper").torque_limit)


def rollout(seed: int, steps: int = 30):
    env = UnderwaterArmEnv(noise_variance=0.001, duration=1.0)
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(0)  # the same actions for both rollouts
    observations, rewards = [obs], []
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(rng.uniform(-50, 50, 6))
        observations.append(obs)
        rewards.append(reward)
    return np.array(observations), np.array(rewards)


def test_same_seed_same_rollout():
    a, b, c = rollout(7), rollout(7), rollout(8)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert not np.array_equal(a[0], c[0])


def test_truncates_at_the_end_of_the_task():
    env = UnderwaterArmEnv(duration=0.05)
    env.reset(seed=0)
    flags = [env.step(np.zeros(6))[3] for _ in range(5)]
    assert flags == [False, False, False, False, True]


@pytest.mark.parametrize("name", ["SMC", "GP-MPC"])
def test_controller_rollout_gives_the_runner_e_p(name):
    """The env's rollout of a built-in controller equals run_experiment's on the same seed."""
    config = with_overrides(ExperimentConfig(), {"duration": 1.0, "plant.noise_variance": 0.001})
    env = UnderwaterArmEnv(config=config)
    policy = ControllerPolicy.from_name(name, env)
    obs, _ = env.reset(seed=3)
    errors = []
    truncated = terminated = False
    while not (truncated or terminated):
        obs, _, terminated, truncated, info = env.step(policy(obs))
        policy.observe(obs)
        errors.append(info["error"])
    ep_env = np.mean(np.square(errors), axis=0)
    ep_runner = tracking_metrics(run_experiment(config, name, seed=3))["Ep"]
    np.testing.assert_allclose(ep_env, ep_runner, rtol=1e-12)


@pytest.mark.parametrize("action", [np.full(6, np.nan), np.array([0, 0, 0, np.inf, 0, 0]), np.zeros(5)])
def test_bad_action_is_a_clear_error(action):
    env = UnderwaterArmEnv(duration=0.2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action must be 6 finite joint torques"):
        env.step(action)
