"""The batched vector env (hydroarm.envs.batched): each copy is the single env on the compiled
plant, bit for bit (observations, states, flags; rewards to round-off), with Gymnasium's
next-step autoreset, seeds and batched spaces; the loop settings it cannot step are refused."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode

import hydroarm.envs
from hydroarm.envs.batched import BatchedArmVectorEnv, make_compiled_arm_env
from hydroarm.envs.underwater_arm import UnderwaterArmEnv

gymnasium.register_envs(hydroarm.envs)
KWARGS = {"arm": "alpha5", "duration": 0.05, "noise_variance": 1e-4, "start_spread": (0.05, 0.1)}
COPIES = 3


def _actions(steps: int, n: int, seed: int = 7) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1.2, 1.2, (steps, COPIES, n))  # some outside the box: clipped


def test_copies_equal_single_envs_bit_for_bit_across_autoreset():
    """Copy i reset with seed 10 + i and stepped with row i of the actions gives the single
    compiled env's observations, true states, termination and truncation bit for bit, and its
    rewards to 1e-12 relative, through two episodes (next-step autoreset: the single env is reset
    unseeded at the step after its episode ended, and that step's action is ignored)."""
    envs = BatchedArmVectorEnv(COPIES, **KWARGS)
    singles = [make_compiled_arm_env(**KWARGS) for _ in range(COPIES)]
    steps = envs.env.steps
    actions = _actions(2 * steps + 3, envs.n)
    obs, _ = envs.reset(seed=10)
    expected = [single.reset(seed=10 + c)[0] for c, single in enumerate(singles)]
    np.testing.assert_array_equal(obs, np.array(expected))
    ended = np.zeros(COPIES, dtype=bool)
    autoresets = 0
    for batch in actions:
        obs, rewards, terminated, truncated, _ = envs.step(batch)
        for c, single in enumerate(singles):
            if ended[c]:
                first, _ = single.reset()
                np.testing.assert_array_equal(obs[c], first)
                assert rewards[c] == 0.0 and not terminated[c] and not truncated[c]
                autoresets += 1
                continue
            o, r, term, trunc, _ = single.step(batch[c])
            np.testing.assert_array_equal(obs[c], o)
            np.testing.assert_array_equal(envs.states[c], single.state)
            assert (terminated[c], truncated[c]) == (term, trunc)
            np.testing.assert_allclose(rewards[c], r, rtol=1e-12, atol=0)
        ended = terminated | truncated
    assert autoresets == 2 * COPIES  # every copy went through two episode ends


def test_copies_match_the_reference_plant_env():
    """Against the default single env (the reference plant, not compiled), over one episode:
    observations within 1e-12 (the two plants agree to round-off, docs/model.md)."""
    envs = BatchedArmVectorEnv(COPIES, **KWARGS)
    singles = [UnderwaterArmEnv(**KWARGS) for _ in range(COPIES)]
    obs, _ = envs.reset(seed=[3, 4, 5])
    expected = np.array([single.reset(seed=s)[0] for s, single in zip((3, 4, 5), singles, strict=True)])
    np.testing.assert_array_equal(obs, expected)  # the start: no plant step yet
    for batch in _actions(envs.env.steps, envs.n, seed=1):
        obs, *_ = envs.step(batch)
        expected = np.array([single.step(batch[c])[0] for c, single in enumerate(singles)])
        np.testing.assert_allclose(obs, expected, rtol=0, atol=1e-12)


def test_make_vec_gives_it_with_batched_spaces():
    envs = gymnasium.make_vec(
        "hydroarm/UnderwaterArmBatched-v0", num_envs=4, vectorization_mode="vector_entry_point", arm="paper"
    )
    assert isinstance(envs, BatchedArmVectorEnv)
    single = make_compiled_arm_env(arm="paper")
    assert envs.single_observation_space == single.observation_space
    assert envs.single_action_space == single.action_space
    assert envs.observation_space.shape == (4, 4 * single.n) and envs.action_space.shape == (4, single.n)
    assert envs.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    obs, info = envs.reset(seed=0)
    assert envs.observation_space.contains(obs)
    obs, rewards, terminated, truncated, info = envs.step(envs.action_space.sample())
    assert envs.observation_space.contains(obs) and rewards.shape == (4,) and terminated.dtype == bool
    assert info["x"].shape == (4, 2 * single.n) and info["_x"].all()
    check_env(gymnasium.make("hydroarm/UnderwaterArmBatched-v0", arm="alpha5", duration=0.1).unwrapped)


def test_disabled_autoreset_resets_the_mask_only():
    envs = BatchedArmVectorEnv(COPIES, autoreset_mode="Disabled", **KWARGS)
    first, _ = envs.reset(seed=0)
    envs.step(np.zeros((COPIES, envs.n)))
    mask = np.array([True, False, True])
    obs, _ = envs.reset(options={"reset_mask": mask})
    assert list(envs.steps_taken) == [0, 1, 0]
    assert not np.array_equal(obs[1], first[1])


@pytest.mark.parametrize(
    "settings, field", [({"sensor.delay": 1}, "sensor.delay"), ({"actuator.delay": 1}, "actuator.delay")]
)
def test_real_loop_settings_are_refused(settings, field):
    """The sensor's and drives' blocks are not stepped by the batched env: refused, the field named."""
    with pytest.raises(ValueError, match=field):
        BatchedArmVectorEnv(2, arm="alpha5", settings=settings)


def test_bad_actions_are_refused():
    envs = BatchedArmVectorEnv(2, **KWARGS)
    envs.reset(seed=0)
    with pytest.raises(ValueError, match="actions must be"):
        envs.step(np.zeros((3, envs.n)))
    with pytest.raises(ValueError, match="actions must be"):
        envs.step(np.full((2, envs.n), np.nan))


def test_the_batched_plant_script_runs_small(tmp_path):
    """scripts/batched_plant.py (the GPU design's CPU baseline, docs/model.md) runs in CI, small."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "scripts" / "batched_plant.py"
    done = subprocess.run(
        [sys.executable, str(script), "--arm", "alpha5", "--copies", "1", "3", "--steps", "2"],
        capture_output=True, text=True, check=True, cwd=tmp_path,
    )  # fmt: skip
    result = json.loads(done.stdout)
    assert [row["copies"] for row in result["rows"]] == [1, 3]
    assert all(row["finite"] and row["copy_steps_per_s"] > 0 for row in result["rows"])
