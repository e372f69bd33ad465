"""The vector environment (hydroarm.envs.vector.WorkerVectorEnv): what ``gymnasium.make_vec`` gives,
the same numbers as independent single environments, Gymnasium's autoreset semantics (its
SyncVectorEnv as the reference), errors, interrupts and closing, and the compile cost paid at make."""

from __future__ import annotations

import functools
import os
import signal
import subprocess
import sys
import textwrap
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

from gymnasium.utils.env_checker import data_equivalence  # noqa: E402
from gymnasium.vector import AutoresetMode, SyncVectorEnv  # noqa: E402

from hydroarm.envs import ENV_ID, UVMS_ENV_ID  # noqa: E402  (registers the environments)
from hydroarm.envs.underwater_arm import UnderwaterArmEnv  # noqa: E402
from hydroarm.envs.vector import WorkerVectorEnv, default_workers  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
FORK = pytest.mark.skipif(os.name != "posix", reason="the test's env functions reach the workers by fork")
# short episodes with noise and a start spread: every seeded draw shows in the numbers
ENV_KWARGS = {"arm": "alpha5", "duration": 0.05, "noise_variance": 1e-3, "start_spread": (0.1, 0.2)}


def actions_for(envs, steps: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1.0, 1.0, (steps, *envs.action_space.shape))


@pytest.mark.parametrize("mode", [None, "vector_entry_point"])
def test_make_vec_gives_the_worker_vector_env_with_its_autoreset_mode(mode):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # make_vec warns when the autoreset mode is not stated
        envs = gymnasium.make_vec(ENV_ID, num_envs=8, vectorization_mode=mode, arm="alpha5", duration=0.05)
    try:
        assert isinstance(envs.unwrapped, WorkerVectorEnv)
        assert envs.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
        assert envs.unwrapped.workers == min(default_workers(), 8)
        assert len(envs.unwrapped.worker_pids) == envs.unwrapped.workers - 1
        assert envs.observation_space.shape == (8, 16) and envs.action_space.shape == (8, 4)
        assert envs.single_observation_space == UnderwaterArmEnv(arm="alpha5", duration=0.05).observation_space
        obs, _ = envs.reset(seed=0)
        assert envs.observation_space.contains(obs)
        obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())
        assert envs.observation_space.contains(obs) and reward.shape == (8,) and reward.dtype == np.float64
        assert terminated.dtype == np.bool_ and truncated.dtype == np.bool_
        assert info["x"].shape == (8, 8) and info["_x"].all()
    finally:
        envs.close()


def test_the_vehicle_env_has_its_vector_env_too():
    envs = gymnasium.make_vec(UVMS_ENV_ID, num_envs=2, duration=0.2)
    try:
        assert isinstance(envs.unwrapped, WorkerVectorEnv)
        single = gymnasium.make(UVMS_ENV_ID, duration=0.2).unwrapped
        obs, _ = envs.reset(seed=3)
        expected, _ = single.reset(seed=4)  # copy 1: seed + 1
        np.testing.assert_array_equal(obs[1], expected)
        action = np.full((2, single.n_thr), 0.1)
        obs, reward, *_ = envs.step(action)
        expected, reward_1, *_ = single.step(action[1])
        np.testing.assert_array_equal(obs[1], expected)
        assert reward[1] == reward_1
    finally:
        envs.close()


@pytest.mark.parametrize("workers", [1, 2, 3])
def test_copies_give_the_numbers_of_independent_single_envs(workers):
    """8 copies, seeds 10..17, through two episode ends and their autoresets, equal 8 single envs
    reset with those seeds and stepped with the same actions (and reset, unseeded, after each
    end, as NEXT_STEP does), bit for bit."""
    envs = WorkerVectorEnv(functools.partial(UnderwaterArmEnv, **ENV_KWARGS), 8, workers=workers)
    singles = [UnderwaterArmEnv(**ENV_KWARGS) for _ in range(8)]
    try:
        assert envs.workers == workers and sum(count for _, count in envs.blocks) == 8
        obs, info = envs.reset(seed=10)
        for i, env in enumerate(singles):
            expected, expected_info = env.reset(seed=10 + i)
            np.testing.assert_array_equal(obs[i], expected)
            np.testing.assert_array_equal(info["x"][i], expected_info["x"])
        done = np.zeros(8, dtype=bool)
        ends = 0
        for batch in actions_for(envs, 2 * singles[0].steps + 2):
            obs, reward, terminated, truncated, info = envs.step(batch)
            for i, env in enumerate(singles):
                if done[i]:  # the autoreset step
                    expected, expected_info = env.reset()
                    assert reward[i] == 0.0 and not terminated[i] and not truncated[i]
                else:
                    expected, r, te, tr, expected_info = env.step(batch[i])
                    assert (reward[i], terminated[i], truncated[i]) == (r, te, tr)
                    np.testing.assert_array_equal(info["error"][i], expected_info["error"])
                np.testing.assert_array_equal(obs[i], expected)
                np.testing.assert_array_equal(info["x"][i], expected_info["x"])
            done = terminated | truncated
            ends += int(done.all())
        assert ends == 2
        assert not np.array_equal(obs[0], obs[1])  # the copies' seeds differ
    finally:
        envs.close()


@pytest.mark.parametrize("mode", list(AutoresetMode), ids=lambda m: m.value)
def test_autoreset_as_gymnasiums_sync_vector_env(mode):
    """Observations, rewards, flags and infos (final_obs / final_info of SAME_STEP included) equal
    those of Gymnasium's SyncVectorEnv of the same copies in the same autoreset mode; DISABLED
    resets through options["reset_mask"]."""
    make = functools.partial(UnderwaterArmEnv, **ENV_KWARGS)
    ours = WorkerVectorEnv(make, 5, workers=2, autoreset_mode=mode)
    reference = SyncVectorEnv([make] * 5, autoreset_mode=mode)
    try:
        assert ours.metadata["autoreset_mode"] == reference.metadata["autoreset_mode"] == mode
        assert data_equivalence(ours.reset(seed=[3, 1, 4, 1, 5]), reference.reset(seed=[3, 1, 4, 1, 5]), exact=True)
        ended = 0
        for k, batch in enumerate(actions_for(ours, 14, seed=2)):
            a, b = ours.step(batch), reference.step(batch)
            assert data_equivalence(a, b, exact=True), f"step {k}"
            done = a[2] | a[3]
            ended += int(done.any())
            if mode == AutoresetMode.DISABLED and (done.any() or k == 1):
                mask = done.copy() if done.any() else np.eye(5, dtype=bool)[0]  # copy 0 out of step: partial masks
                a, b = ours.reset(options={"reset_mask": mask}), reference.reset(options={"reset_mask": mask})
                assert data_equivalence(a, b, exact=True), f"reset after step {k}"
        assert ended >= 2
    finally:
        ours.close()
        reference.close()


def test_gymnasiums_vector_wrappers_accept_it_without_a_warning():
    envs = gymnasium.make_vec(ENV_ID, num_envs=4, arm="alpha5", duration=0.03)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        wrapped = gymnasium.wrappers.vector.RecordEpisodeStatistics(
            gymnasium.wrappers.vector.NormalizeObservation(envs)
        )
        wrapped.reset(seed=0)
        for _ in range(3):
            _, _, _, truncated, info = wrapped.step(wrapped.action_space.sample())
    assert truncated.all() and info["episode"]["l"].tolist() == [3, 3, 3, 3]
    wrapped.close()
    assert envs.unwrapped.closed


def test_call_get_attr_set_attr_reach_every_copy():
    envs = WorkerVectorEnv(functools.partial(UnderwaterArmEnv, **ENV_KWARGS), 4, workers=2)
    try:
        assert envs.get_attr("n") == (4, 4, 4, 4)
        envs.reset(seed=0)
        states = envs.call("measured_state")
        assert len(states) == 4 and all(s.shape == (8,) for s in states)
        envs.set_attr("start_spread", [(0.0, 0.0)] * 4)
        _, info = envs.reset(seed=0)
        np.testing.assert_array_equal(info["x"], np.tile(envs.get_attr("x0")[0], (4, 1)))
        actions = envs.call("action", np.ones(4))
        assert len(actions) == 4
    finally:
        envs.close()


def test_bad_actions_are_refused_before_any_copy_steps():
    envs = WorkerVectorEnv(functools.partial(UnderwaterArmEnv, **ENV_KWARGS), 4, workers=2)
    try:
        obs, _ = envs.reset(seed=0)
        with pytest.raises(ValueError, match=r"actions must have the shape \(4, 4\)"):
            envs.step(np.zeros((4, 3)))
        bad = np.zeros((4, 4))
        bad[2, 1] = np.nan
        with pytest.raises(ValueError, match=r"copies \[2\] have non-finite"):
            envs.step(bad)
        assert not envs.closed
        np.testing.assert_array_equal(envs.call("t"), np.zeros(4))  # nothing stepped
        envs.step(np.zeros((4, 4)))
        np.testing.assert_allclose(envs.call("t"), np.full(4, 0.01))
    finally:
        envs.close()


class Fails(gymnasium.Wrapper):
    """A copy that raises in ``step`` when its first action entry is :data:`TRIGGER`."""

    TRIGGER = 0.5

    def step(self, action):
        if action[0] == self.TRIGGER:
            raise FloatingPointError("the copy's test failure")
        return self.env.step(action)


def failing_copy() -> gymnasium.Env:
    return Fails(UnderwaterArmEnv(**ENV_KWARGS))


@FORK
@pytest.mark.parametrize("copy", [1, 5], ids=["this-process", "worker"])
def test_an_exception_in_a_copy_is_one_clear_error_and_closes_everything(copy, tmp_path):
    envs = WorkerVectorEnv(failing_copy, 6, workers=2, context="fork")
    processes = list(envs._processes)
    memory = Path("/dev/shm") / envs._memory.name
    assert memory.exists()
    envs.reset(seed=0)
    actions = np.zeros((6, 4))
    actions[copy, 0] = Fails.TRIGGER
    with pytest.raises(FloatingPointError, match="the copy's test failure") as raised:
        envs.step(actions)
    notes = "\n".join(getattr(raised.value, "__notes__", []))
    assert f"raised in copy {copy} of the 6-copy vector env, during step; the vector env is closed" in notes
    if copy >= 3:  # from the worker: its traceback is the cause
        assert "Fails" in str(raised.value.__cause__) or "step" in str(raised.value.__cause__)
    assert envs.closed and not memory.exists()
    assert all(not process.is_alive() and process.exitcode == 0 for process in processes)
    with pytest.raises(gymnasium.error.ClosedEnvironmentError):
        envs.step(np.zeros((6, 4)))


def test_a_worker_that_dies_is_a_clear_error_not_a_hang():
    envs = WorkerVectorEnv(functools.partial(UnderwaterArmEnv, **ENV_KWARGS), 4, workers=2)
    envs.reset(seed=0)
    (pid,) = envs.worker_pids
    os.kill(pid, signal.SIGKILL)
    with pytest.raises(
        RuntimeError, match=r"worker 1 of the vector env \(copies 2-3\) exited with code -9 during step"
    ):
        envs.step(np.zeros((4, 4)))
    assert envs.closed and envs.worker_pids == ()


def test_a_bad_setting_fails_at_make_with_the_envs_own_error_and_no_process_left():
    from hydroarm.config import ConfigError

    children_before = set(multiprocessing_children())
    with pytest.raises(ConfigError, match="arm 'nope'"):
        gymnasium.make_vec(ENV_ID, num_envs=4, arm="nope")
    with pytest.raises(ValueError, match=r"workers must be an integer in \[1, num_envs = 4\]"):
        gymnasium.make_vec(ENV_ID, num_envs=4, workers=5, arm="alpha5")
    with pytest.raises(ValueError, match="autoreset_mode must be an AutoresetMode or one of"):
        gymnasium.make_vec(ENV_ID, num_envs=4, autoreset_mode="later", arm="alpha5")
    assert set(multiprocessing_children()) <= children_before


def multiprocessing_children() -> list[int]:
    import multiprocessing

    return [process.pid for process in multiprocessing.active_children()]


def test_close_stops_the_workers_and_frees_the_shared_memory():
    envs = WorkerVectorEnv(functools.partial(UnderwaterArmEnv, **ENV_KWARGS), 4, workers=2)
    processes = list(envs._processes)
    memory = Path("/dev/shm") / envs._memory.name
    envs.reset(seed=0)
    envs.step(np.zeros((4, 4)))
    envs.close()
    envs.close()  # idempotent
    assert all(not process.is_alive() and process.exitcode == 0 for process in processes)
    if os.name == "posix" and Path("/dev/shm").is_dir():
        assert not memory.exists()
    with pytest.raises(gymnasium.error.ClosedEnvironmentError):
        envs.reset()


def run_python(code: str, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=300, cwd=ROOT, **kwargs
    )


@pytest.mark.subprocess
@pytest.mark.skipif(os.name != "posix", reason="a terminal's Ctrl-C: SIGINT to the process group")
@pytest.mark.parametrize("where", ["_local.step", "_infos"])
def test_ctrl_c_stops_the_workers_and_closes_the_env(where):
    """Ctrl-C in a terminal sends SIGINT to the whole process group: the workers ignore it, the
    calling process gets KeyboardInterrupt with the env closed and no worker left. The SIGINT is
    sent to the group from inside a step, so that it lands during a vector env call every time:
    while the workers step (this process stepping its own copies, ``_local.step``) or after they
    have replied (``_infos``, gathering their infos). A signal sent from outside at a random time
    can land between two calls, in the caller's own code, where no env can act on it."""
    code = f"""
        import os, signal, numpy as np, gymnasium
        envs = gymnasium.make_vec("hydroarm.envs:hydroarm/UnderwaterArm-v0", num_envs=4, workers=2, arm="alpha5")
        env = envs.unwrapped
        processes = list(env._processes)
        owner, name = (env._local, "step") if "{where}" == "_local.step" else (env, "_infos")
        original, calls = getattr(owner, name), []

        def interrupting(*args, **kwargs):
            calls.append(1)
            if len(calls) == 20:  # Ctrl-C: the whole process group
                os.killpg(os.getpgid(0), signal.SIGINT)
            return original(*args, **kwargs)

        envs.reset(seed=0)
        setattr(owner, name, interrupting)
        try:
            while True:
                envs.step(np.zeros((4, 4)))
        except KeyboardInterrupt:
            alive = [p.is_alive() for p in processes]
            print("interrupted", len(calls), env.closed, alive, flush=True)
    """
    process = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(code)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
        start_new_session=True,
        # a terminal's SIGINT: a background job of a non-interactive shell, or a pytest-xdist
        # worker, passes it on ignored, and Python then never raises KeyboardInterrupt
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        out, err = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
    assert process.returncode == 0, err
    assert out.strip() == "interrupted 20 True [False]", (out, err)


COMPILED = """
    import sys
    import numpy as np
    from numba.core.dispatcher import Dispatcher

    def signatures():
        '''The compiled (or cache-loaded) signatures of every numba function of hydroarm's modules.'''
        found = {}
        for name, module in list(sys.modules.items()):
            if name.startswith("hydroarm"):
                for attribute, value in vars(module).items():
                    if isinstance(value, Dispatcher):
                        found[f"{name}.{attribute}"] = tuple(value.signatures)
        return found

    def new_since(before):
        return sorted(name for name, value in signatures().items() if value != before.get(name))
"""


@pytest.mark.subprocess
@pytest.mark.parametrize(
    "make",
    [
        "gymnasium.make('hydroarm.envs:hydroarm/UnderwaterArm-v0', arm='alpha5')",
        "gymnasium.make('hydroarm.envs:hydroarm/UnderwaterArm-v0', arm='paper')",
        "gymnasium.make('hydroarm.envs:hydroarm/UVMS-v0')",
    ],
    ids=["arm-alpha5", "arm-paper", "vehicle"],
)
def test_the_first_step_compiles_nothing(make):
    """In a fresh interpreter: after make, neither reset nor the first steps compile or load a
    numba function (their signatures are all there after make)."""
    result = run_python(
        COMPILED
        + f"""
    import gymnasium
    env = {make}
    after_make = signatures()
    env.reset(seed=0)
    for _ in range(3):
        env.step(env.action_space.sample())
    print(new_since(after_make))
    assert any(after_make.values()), after_make
    """
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]", result.stdout


@pytest.mark.subprocess
@FORK
def test_the_vector_envs_lanes_compile_nothing_at_their_first_step():
    """In a fresh interpreter, so that the forked workers inherit nothing compiled: each copy
    records the numba signatures present when it was made, and the first steps (and resets)
    of every copy, in this process and in the workers, add none."""
    result = run_python(
        COMPILED
        + """
    import os
    import gymnasium
    from hydroarm.envs.underwater_arm import UnderwaterArmEnv
    from hydroarm.envs.vector import WorkerVectorEnv

    class Probe(gymnasium.Wrapper):
        def __init__(self, env):
            super().__init__(env)
            self.made = signatures()
            assert any(self.made.values())

        def step(self, action):
            observation, reward, terminated, truncated, info = self.env.step(action)
            return observation, reward, terminated, truncated, {**info, "new": len(new_since(self.made))}

        def reset(self, **kwargs):
            observation, info = self.env.reset(**kwargs)
            return observation, {**info, "new": len(new_since(self.made)), "pid": os.getpid()}

    envs = WorkerVectorEnv(lambda: Probe(UnderwaterArmEnv(arm="alpha5", duration=0.02)), 4, workers=2, context="fork")
    _, info = envs.reset(seed=0)
    assert len(set(info["pid"].tolist())) == 2, info["pid"]  # two processes
    new = [info["new"].tolist()]
    for _ in range(4):  # through an episode end and its autoreset
        _, _, _, _, info = envs.step(envs.action_space.sample())
        new.append(info["new"].tolist())
    envs.close()
    print(new)
    """
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == str([[0, 0, 0, 0]] * 5), result.stdout


@pytest.mark.parametrize(
    "infos",
    [
        [{"x": np.arange(3.0) + i, "t": 0.1 * i, "k": i, "ok": i % 2 == 0, "f": np.float32(i)} for i in range(5)],
        [{"x": np.arange(2) + i} if i != 3 else {"t": 1.0} for i in range(5)],  # a reset copy among stepping ones
        [{"x": np.zeros(2)}, {}, {"x": np.ones(2)}, {}, {}],  # a reset mask
        [{"x": np.zeros(2), "y": np.zeros(2)}] * 2 + [{"x": np.arange(2), "y": np.zeros(2)}] * 3,  # dtypes differ
        [{"final_obs": np.zeros(2), "final_info": {"t": 0.5, "x": np.ones(2)}, "t": 0.0}] * 5,  # SAME_STEP's
        [{"n": 1}, {"n": 2.0}, {"n": 3}, {"n": np.int32(4)}, {"n": True}],  # types differ
    ],
    ids=["stackable", "mixed-keys", "masked", "dtypes", "final", "types"],
)
@pytest.mark.parametrize("blocks", [[(0, 5)], [(0, 3), (3, 2)], [(0, 1), (1, 2), (3, 2)]], ids=["1", "2", "3"])
def test_packed_infos_merge_as_gymnasiums_add_info(infos, blocks):
    """The lanes send their copies' infos stacked when they can (hydroarm.envs.vector._pack): the
    merged vector info equals VectorEnv._add_info's of the dicts one by one, keys, dtypes and masks."""
    from gymnasium.vector import VectorEnv

    from hydroarm.envs.vector_lanes import pack_infos as _pack

    envs = object.__new__(WorkerVectorEnv)  # only _infos's attributes: no lanes to start
    envs.num_envs, envs.blocks, envs.closed = 5, blocks, True
    merged = envs._infos([_pack(infos[start : start + count]) for start, count in blocks])
    expected: dict = {}
    for i, info in enumerate(infos):
        if info:
            expected = VectorEnv._add_info(envs, expected, info, i)
    assert merged.keys() == expected.keys()
    for key in expected:
        if isinstance(expected[key], np.ndarray):
            assert merged[key].dtype == expected[key].dtype, key
    assert data_equivalence(merged, expected, exact=True)


def gone(pid: int) -> bool:
    """The process has exited (no such process, or a zombie waiting to be reaped)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rsplit(")", 1)[1].split()[0] == "Z"
    except FileNotFoundError:
        return True


@pytest.mark.subprocess
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
def test_workers_exit_when_the_calling_process_is_killed():
    """SIGKILL gives the calling process no chance to close: its workers see their pipe close and exit."""
    code = """
        import os, signal, numpy as np, gymnasium
        envs = gymnasium.make_vec("hydroarm.envs:hydroarm/UnderwaterArm-v0", num_envs=3, workers=3, arm="alpha5")
        envs.reset(seed=0)
        envs.step(np.zeros((3, 4)))
        print(*envs.unwrapped.worker_pids, flush=True)
        os.kill(os.getpid(), signal.SIGKILL)
    """
    process = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(code)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        cwd=ROOT,
    )
    pids = [int(pid) for pid in process.stdout.readline().split()]  # not to EOF: a live worker would hold it
    assert process.wait(timeout=300) == -signal.SIGKILL
    process.stdout.close()
    assert len(pids) == 2
    deadline = time.monotonic() + 60.0  # a liveness deadline (the workers look every second), not a speed bound
    while not all(gone(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert all(gone(pid) for pid in pids), [pid for pid in pids if not gone(pid)]


def test_the_speed_docs_envs_md_states_is_the_measured_one():
    """docs/envs.md's figures are docs/data/env_vector_speed.json's (python -m hydroarm_bench.envs)."""
    import json

    measured = json.loads((ROOT / "docs" / "data" / "env_vector_speed.json").read_text())
    assert measured["date"] and measured["machine"] and measured["load_average_start"]
    text = " ".join((ROOT / "docs" / "envs.md").read_text().split())
    single, vector = measured["single_cpu_ms_per_step"], measured["vector_cpu_ms_per_env_step"]
    for phrase in (
        f"Measured {measured['date']} on a quiet {measured['cpus']}-core",
        f"load average {measured['load_average_start'][0]:.1f} at the start;",
        f"one environment {measured['single_steps_per_s']:.0f} steps/s",
        f"({measured['workers']} lanes) {measured['vector_env_steps_per_s']:.0f} environment steps/s: "
        f"**{measured['speedup']:.2f}x**",
        f"async vector env gave {measured['async_env_steps_per_s']:.0f} ({measured['async_speedup']:.2f}x)",
        f"kept {measured['single_cores_used']:.2f} and {measured['vector_cores_used']:.2f} cores busy",
        f"2 x {single:.3f} / {vector:.3f} = {2 * single / vector:.2f}x",
    ):
        assert phrase in text, phrase


@pytest.mark.subprocess
@pytest.mark.parametrize("context", ["spawn", "forkserver"])
def test_other_start_methods_give_the_same_numbers(context):
    """The workers started by spawn or forkserver (Python 3.14's default on Linux) import hydroarm
    afresh and unpickle the env's constructor: the same numbers as a single env."""
    import multiprocessing

    if context not in multiprocessing.get_all_start_methods():
        pytest.skip(f"no {context} here")
    make = functools.partial(UnderwaterArmEnv, **ENV_KWARGS)
    envs = WorkerVectorEnv(make, 2, workers=2, context=context)
    single = make()
    try:
        obs, _ = envs.reset(seed=5)
        np.testing.assert_array_equal(obs[1], single.reset(seed=6)[0])
        for batch in actions_for(envs, 3):
            obs, reward, *_ = envs.step(batch)
            expected, expected_reward, *_ = single.step(batch[1])
            np.testing.assert_array_equal(obs[1], expected)
            assert reward[1] == expected_reward
    finally:
        envs.close()
