"""Adding a controller is its module and one registration: a toy controller registered from
outside the package runs through the experiment builder and the runner, a sweep, ``hydroarm
tune``'s grid and the Gymnasium env, with nothing else changed."""

from __future__ import annotations

import numpy as np
import pytest

from hydroarm.control.interface import ControlOutput
from hydroarm.control.registry import REGISTRY, ControllerSpec, canonical_name, register
from hydroarm.model.nominal import NominalModel
from hydroarm.sim.experiment import ExperimentConfig, gp_inputs, run_experiment


class ToyComputedTorque:
    """Computed torque on the dry model with fixed PD gains, clipped to the arm's limits."""

    def __init__(self, arm, control_period, kp=400.0, kd=40.0):
        self.name = "TOY-CT"
        self.control_period = control_period
        self.model = NominalModel(arm, inner_step=None)
        self.limit = np.asarray(arm.torque_limit, dtype=float)
        self.kp, self.kd, self.n = kp, kd, arm.n_joints
        self.steps = 0

    def reset(self) -> None:
        self.steps = 0

    def compute(self, t, y, reference) -> ControlOutput:
        q, v = y[: self.n], y[self.n :]
        q_r, v_r, a_r = reference.sample(t)
        a = a_r + self.kp * (q_r - q) + self.kd * (v_r - v)
        tau = np.clip(self.model.inverse_dynamics(q, v, a), -self.limit, self.limit)
        return ControlOutput(tau=tau, record={"toy_step": np.asarray(self.steps)})

    def observe(self, t, y, u, y_next) -> None:
        self.steps += 1


@pytest.fixture
def toy():
    spec = ControllerSpec(
        "TOY-CT",
        ("smc",),  # reads an existing section (its sweeps' run ids then depend on it), none of its own
        "a toy computed-torque controller registered from a test",
        lambda arm, sections, period: ToyComputedTorque(arm, period),
        tuning_grid={"smc.surface_slope": [10.0, 20.0]},
    )
    register(spec)
    yield spec
    del REGISTRY[spec.name]


def test_a_registered_controller_runs_through_the_builder_and_the_runner(toy):
    assert canonical_name("toy_ct") == "TOY-CT" and gp_inputs("toy-ct", ExperimentConfig(), 6) is None
    traj = run_experiment(ExperimentConfig(duration=1.0), "toy-ct", seed=0)
    assert traj.meta["controller"] == "TOY-CT" and traj.meta["stopped"] is None
    assert np.array_equal(traj.extra["toy_step"], np.arange(100))  # its record, kept per step
    error = traj.q_ref - traj.q
    assert np.max(np.abs(error[-20:])) < np.max(np.abs(error[:5]))  # it tracks


def test_a_registered_controller_runs_in_a_sweep_and_has_a_tuning_grid(toy, tmp_path):
    from hydroarm.studies.sweep import run_sweep
    from hydroarm.studies.sweep.schema import SweepConfig
    from hydroarm.studies.tune import plan_tuning

    config = SweepConfig(controllers=["toy-ct", "smc"], seeds=1, base={"duration": 0.3})
    summary = run_sweep(config, tmp_path / "sweep", workers=0)
    assert summary["ran"] == 2 and not summary["failed"]
    assert "TOY-CT" in (tmp_path / "sweep" / "results.csv").read_text()
    assert len(plan_tuning(ExperimentConfig(), "toy-ct")) == 2 * 2  # its grid, clean and noisy


def test_a_registered_controller_drives_the_env_as_in_the_runner(toy):
    gymnasium = pytest.importorskip("gymnasium")
    from hydroarm.envs.underwater_arm import ControllerPolicy

    env = gymnasium.make(
        "hydroarm.envs:hydroarm/UnderwaterArm-v0", duration=0.3, noise_variance=1e-3, action_mode="torque"
    )
    policy = ControllerPolicy.from_name("toy-ct", env)
    obs, _ = env.reset(seed=4)
    torques = []
    done = False
    while not done:
        action = policy(obs)
        torques.append(action)
        obs, _, terminated, truncated, _ = env.step(action)
        policy.observe(obs)
        done = terminated or truncated
    config = env.unwrapped.config  # the env's defaults (its water: the Kirchhoff added mass)
    assert config.water.added_mass_model == "kirchhoff" and config.plant.noise_variance == 1e-3
    runner = run_experiment(config, "toy-ct", seed=4)
    assert np.array_equal(np.array(torques), runner.u)  # the env reproduces the runner bit for bit


def test_a_name_is_registered_once(toy):
    from hydroarm.config import ConfigError

    with pytest.raises(ConfigError, match="registered already"):
        register(ControllerSpec("toy_ct", (), "again", toy.build))
