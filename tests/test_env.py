"""The Gymnasium environment on every built-in arm and a URDF arm: API check, the arm's own
task, seeding, the same trajectory and E_p as the runner, and a light ``import hydroarm``."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

import hydroarm.envs  # noqa: E402  (registers the environment)
from hydroarm.envs import ENV_ID  # noqa: E402
from hydroarm.envs.underwater_arm import ControllerPolicy, UnderwaterArmEnv  # noqa: E402
from hydroarm.model.loading import load_arm  # noqa: E402
from hydroarm.model.task import task_for_arm  # noqa: E402
from hydroarm.sim.experiment import ExperimentConfig, run_experiment, with_overrides  # noqa: E402
from hydroarm.sim.runner import tracking_metrics  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
URDF_ARM = str(ROOT / "examples" / "urdf" / "myarm.urdf")
ARMS = [
    pytest.param("paper", id="paper"),
    pytest.param("ur5", id="ur5"),
    pytest.param("alpha5", id="alpha5"),
    pytest.param(URDF_ARM, id="myarm.urdf"),
]


@pytest.mark.parametrize("arm", ARMS)
def test_passes_gymnasium_env_checker(arm):
    from gymnasium.utils.env_checker import check_env

    env = gymnasium.make(ENV_ID, arm=arm, duration=0.1)
    check_env(env.unwrapped, skip_render_check=True)
    n = load_arm(arm).n_joints
    assert env.observation_space.shape == (4 * n,)
    assert env.action_space.shape == (n,)
    np.testing.assert_array_equal(env.action_space.high, load_arm(arm).torque_limit)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (4 * n,) and obs.dtype == np.float64
    obs, *_ = env.step(env.action_space.sample())
    assert env.observation_space.contains(obs)


@pytest.mark.parametrize("arm", ARMS)
def test_tracks_the_arms_own_task_from_its_start(arm):
    env = UnderwaterArmEnv(arm=arm, duration=0.1)
    n = env.n
    reference, x0 = task_for_arm(load_arm(arm))
    obs, info = env.reset(seed=0)
    np.testing.assert_array_equal(info["x"], x0)
    np.testing.assert_array_equal(obs[: 2 * n], x0)  # no noise by default
    np.testing.assert_array_equal(obs[2 * n :], reference.state(0.0))
    obs, _, _, _, info = env.step(np.zeros(n))
    np.testing.assert_array_equal(obs[2 * n :], reference.state(env.period))
    np.testing.assert_array_equal(info["error"], reference.sample(0.0)[0] - x0[:n])


def test_the_settings_arm_is_used_when_no_arm_is_given():
    env = UnderwaterArmEnv(config=with_overrides(ExperimentConfig(), {"arm": "alpha5"}))
    assert env.config.arm == "alpha5" and env.n == 4
    assert UnderwaterArmEnv().config.arm == "paper"


def rollout(arm: str, seed: int, steps: int = 20):
    env = UnderwaterArmEnv(arm=arm, noise_variance=0.001, duration=0.3)
    obs, info = env.reset(seed=seed)
    rng = np.random.default_rng(0)  # the same actions for every rollout
    high = 1e-3 * env.action_space.high  # small torques: the paper's light arm would diverge
    records = [(obs, 0.0, info["x"])]
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(rng.uniform(-1.0, 1.0, env.n) * high)
        assert not terminated
        records.append((obs, reward, info["x"]))
    return records


@pytest.mark.parametrize("arm", ARMS)
def test_same_seed_same_rollout(arm):
    a, b, c = rollout(arm, 7), rollout(arm, 7), rollout(arm, 8)
    for (obs_a, reward_a, x_a), (obs_b, reward_b, x_b) in zip(a, b):
        np.testing.assert_array_equal(obs_a, obs_b)
        assert reward_a == reward_b
        np.testing.assert_array_equal(x_a, x_b)
    assert not np.array_equal(a[0][0], c[0][0])  # the noise differs from the first measurement on
    assert not np.array_equal(a[-1][0], c[-1][0])


def test_truncates_at_the_end_of_the_task():
    env = UnderwaterArmEnv(duration=0.05)
    env.reset(seed=0)
    flags = [env.step(np.zeros(6))[3] for _ in range(5)]
    assert flags == [False, False, False, False, True]


@pytest.mark.parametrize(
    ("arm", "name"),
    [
        pytest.param("paper", "SMC", id="paper-SMC"),
        pytest.param("paper", "gp-mpc", id="paper-gp-mpc"),
        pytest.param("ur5", "SMC", id="ur5-SMC"),
        pytest.param("ur5", "MPC", id="ur5-MPC"),
        pytest.param("alpha5", "SMC", id="alpha5-SMC"),
        pytest.param("alpha5", "GP_MPC", id="alpha5-GP_MPC"),
        pytest.param(URDF_ARM, "SMC", id="myarm.urdf-SMC"),
        pytest.param(URDF_ARM, "GP-MPC", id="myarm.urdf-GP-MPC"),
    ],
)
def test_controller_rollout_gives_the_runner_e_p(arm, name):
    """The env's rollout of a built-in controller is run_experiment's on the same seed, bit for bit."""
    config = with_overrides(ExperimentConfig(), {"arm": arm, "duration": 0.5, "plant.noise_variance": 0.001})
    env = gymnasium.make(ENV_ID, config=config)  # wrapped: the policy reaches the env through it
    policy = ControllerPolicy.from_name(name, env)
    obs, _ = env.reset(seed=3)
    states, actions, errors = [], [], []
    truncated = terminated = False
    while not (truncated or terminated):
        action = policy(obs)
        obs, _, terminated, truncated, info = env.step(action)
        policy.observe(obs)
        states.append(info["x"])
        actions.append(action)
        errors.append(info["error"])
    assert not terminated
    traj = run_experiment(config, name, seed=3)
    np.testing.assert_array_equal(np.array(states), traj.x)
    np.testing.assert_array_equal(np.array(actions), traj.u)
    ep_env = np.mean(np.square(errors), axis=0)
    np.testing.assert_array_equal(ep_env, tracking_metrics(traj)["Ep"])


def test_policy_reset_replays_the_episode():
    env = UnderwaterArmEnv(arm="alpha5", noise_variance=0.001, duration=0.2)
    policy = ControllerPolicy.from_name("GP-MPC", env)
    episodes = []
    for _ in range(2):
        policy.reset()
        obs, _ = env.reset(seed=5)
        actions = []
        for _ in range(env.steps):
            actions.append(policy(obs))
            obs, *_ = env.step(actions[-1])
            policy.observe(obs)
        episodes.append(np.array(actions))
    np.testing.assert_array_equal(episodes[0], episodes[1])


@pytest.mark.parametrize("arm", ["paper", "alpha5"])
def test_reset_at_a_given_state(arm):
    env = UnderwaterArmEnv(arm=arm, duration=0.1)
    x0 = np.linspace(-0.2, 0.2, 2 * env.n)
    obs, info = env.reset(seed=0, options={"x0": x0})
    np.testing.assert_array_equal(info["x"], x0)
    np.testing.assert_array_equal(obs[: 2 * env.n], x0)
    with pytest.raises(ValueError, match=f"options\\['x0'\\] must be {2 * env.n} finite numbers"):
        env.reset(options={"x0": np.zeros(2 * env.n + 1)})


@pytest.mark.parametrize(
    ("arm", "action"),
    [
        ("paper", np.full(6, np.nan)),
        ("paper", np.array([0, 0, 0, np.inf, 0, 0])),
        ("paper", np.zeros(5)),
        ("alpha5", np.zeros(6)),
        ("alpha5", np.array([0.0, np.nan, 0.0, 0.0])),
    ],
)
def test_bad_action_is_a_clear_error(arm, action):
    env = UnderwaterArmEnv(arm=arm, duration=0.2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=f"action must be {env.n} finite joint torques"):
        env.step(action)


def test_torques_beyond_the_limits_are_clipped():
    a, b = UnderwaterArmEnv(arm="alpha5", duration=0.1), UnderwaterArmEnv(arm="alpha5", duration=0.1)
    a.reset(seed=0)
    b.reset(seed=0)
    limit = a.action_space.high
    np.testing.assert_array_equal(a.step(10 * limit)[0], b.step(limit)[0])


def test_register_is_idempotent():
    hydroarm.envs.register()
    hydroarm.envs.register()
    assert gymnasium.spec(ENV_ID).entry_point == "hydroarm.envs.underwater_arm:UnderwaterArmEnv"
    assert hydroarm.envs.UnderwaterArmEnv is UnderwaterArmEnv


def run_python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)


@pytest.mark.subprocess
def test_import_hydroarm_does_not_import_gymnasium_nor_the_env():
    result = run_python(
        "import sys, hydroarm\n"
        "assert 'gymnasium' not in sys.modules\n"
        "loaded = [m for m in sys.modules if m.startswith(('hydroarm.envs', 'hydroarm.control'))]\n"
        "assert not loaded, loaded\n"
    )
    assert result.returncode == 0, result.stderr


@pytest.mark.subprocess
def test_gymnasium_make_imports_hydroarm_itself():
    """Without importing hydroarm first: the module-qualified id makes Gymnasium import hydroarm.envs."""
    result = run_python(
        "import gymnasium\n"
        "env = gymnasium.make('hydroarm.envs:hydroarm/UnderwaterArm-v0', arm='alpha5', duration=0.05)\n"
        "obs, _ = env.reset(seed=0)\n"
        "assert obs.shape == (16,), obs.shape\n"
        "obs, *_ = env.step(env.action_space.sample())\n"
        "assert obs.shape == (16,), obs.shape\n"
    )
    assert result.returncode == 0, result.stderr
