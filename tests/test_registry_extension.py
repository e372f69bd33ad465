"""Adding a controller is its module and one registration: a toy controller registered from
outside the package runs through the experiment builder and the runner, a sweep, ``hydroarm
tune``'s grid and the Gymnasium env, with nothing else changed; it declares its own settings
section (``toy``), which the settings validate, list and hand to it."""

from __future__ import annotations

import json

import numpy as np
import pydantic
import pytest
from typer.testing import CliRunner

from hydroarm.cli import app
from hydroarm.config import ConfigError, FrozenModel
from hydroarm.control.interface import ControlOutput
from hydroarm.control.registry import REGISTRY, ControllerSpec, canonical_name, register
from hydroarm.model.dynamics.nominal import NominalModel
from hydroarm.sim.experiment import ExperimentConfig, gp_inputs, run_experiment, settings_from_record, with_overrides
from hydroarm.studies.sweep.plan import run_id
from hydroarm.studies.sweep.schema import Mismatch


class ToyConfig(FrozenModel):
    """The toy controller's own settings section."""

    kp: float = pydantic.Field(400.0, gt=0.0, le=1e5, description="position gain (1/s^2)")
    kd: float = pydantic.Field(40.0, gt=0.0, le=1e4, description="velocity gain (1/s)")


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
        (),
        "a toy computed-torque controller registered from a test",
        lambda arm, sections, period: ToyComputedTorque(arm, period, sections["toy"].kp, sections["toy"].kd),
        tuning_grid={"toy.kp": [100.0, 400.0]},
        settings={"toy": ToyConfig},  # its own section: `toy.kp`, `toy.kd`
    )
    spec = register(spec)
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
    tasks = plan_tuning(ExperimentConfig(), "toy-ct")
    assert len(tasks) == 2 * 2 and {task.settings["toy"]["kp"] for task in tasks if "toy" in task.settings} == {100.0}


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


def test_a_registered_controller_declares_its_own_settings_section(toy, tmp_path):
    """``toy.kp`` is a setting like any other: validated with its range (exit 2 on the CLI),
    listed by ``hydroarm settings``, handed to the controller, in the run's digest when set and
    left out at its defaults (the digests and run ids of every other run unchanged)."""
    assert toy.sections == ("toy",) and "toy" not in ExperimentConfig().canonical()
    assert ExperimentConfig().digest() == "9e4e1dee7bcac3f3"  # as without the extension (test_settings_schema)
    soft = with_overrides(ExperimentConfig(duration=0.3), {"toy.kp": 25.0, "toy.kd": 10.0})
    assert soft.section("toy") == ToyConfig(kp=25.0, kd=10.0) and soft.canonical()["toy"]["kp"] == 25.0
    stiff = ExperimentConfig(duration=0.3)
    assert soft.digest() != stiff.digest()
    assert run_id(soft, "SMC", 0, Mismatch(), "a") == run_id(stiff, "SMC", 0, Mismatch(), "a")  # SMC reads no toy
    soft_run, stiff_run = run_experiment(soft, "toy-ct"), run_experiment(stiff, "toy-ct")
    soft_error, stiff_error = np.abs(soft_run.q_ref - soft_run.q), np.abs(stiff_run.q_ref - stiff_run.q)
    assert soft_error[-1].max() > stiff_error[-1].max()  # the gains reach the controller
    with pytest.raises(ConfigError, match=r"toy\.kp = -1\.0: Input should be greater than 0"):
        with_overrides(ExperimentConfig(), {"toy.kp": -1.0})
    with pytest.raises(ConfigError, match=r"toy\.kpp = 1\.0: unknown setting of the section 'toy' \(allowed: kp, kd\)"):
        with_overrides(ExperimentConfig(), {"toy": {"kpp": 1.0}})
    result = CliRunner().invoke(
        app, ["run", "--controller", "toy-ct", "--set", "toy.kp=-1", "--out", str(tmp_path / "out")]
    )
    assert result.exit_code == 2 and "toy.kp = -1" in result.output and "greater than 0" in result.output
    assert "Traceback" not in result.output and not (tmp_path / "out").exists()
    listed = CliRunner().invoke(app, ["settings", "--controller", "toy-ct", "--json"])
    rows = {row["key"]: row for row in json.loads(listed.output)}
    assert rows["toy.kp"]["default"] == 400.0 and rows["toy.kp"]["allowed"] == "0 < x <= 100000"
    text = CliRunner().invoke(app, ["settings"]).output
    assert "[toy]  declared by the registered controller TOY-CT" in text and "toy.kd = 40.0" in text
    config = tmp_path / "toy.toml"
    config.write_text("[toy]\nkp = 50.0\n")
    from hydroarm.sim.experiment import load_experiment_config

    assert load_experiment_config(config).section("toy").kp == 50.0


def test_a_declared_section_may_not_shadow_a_built_in_one(toy):
    clash = register(ControllerSpec("TOY-SMC", (), "clash", toy.build, settings={"smc": ToyConfig}))
    try:
        with pytest.raises(ConfigError, match="declares the settings section 'smc', a built-in one"):
            settings_from_record({"duration": 1.0}, "settings")
    finally:
        del REGISTRY[clash.name]
    with pytest.raises(ConfigError, match="settings section 'toy' is declared already"):
        register(ControllerSpec("TOY-2", (), "again", toy.build, settings={"toy": pydantic.BaseModel}))
