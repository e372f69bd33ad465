"""A newcomer's second hour (issue 24): no traceback on the inputs that gave one, messages that
say what is wrong."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from hydroarm.cli import app
from hydroarm.config import ConfigError
from hydroarm.studies.experiment import ExperimentConfig, build_experiment, with_overrides
from hydroarm.studies.runner import run_closed_loop, tracking_metrics
from hydroarm.studies.uvms_run import UVMSRunConfig

RUNNER = CliRunner()


def _one_error_line(result) -> str:
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), result.output
    return lines[0]


class ScalarReference:
    """A reference whose ``sample`` takes one time only (math, not NumPy), as a user writes one."""

    def __init__(self, inner):
        self.inner = inner

    def sample(self, t: float):
        assert isinstance(t, float), type(t)
        return self.inner.sample(t)


@pytest.mark.parametrize("controller", ["SMC", "MPC", "GP-MPC", "IDMPC", "GP-IDMPC"])
def test_a_scalar_reference_runs_every_controller_as_the_vectorised_one(controller):
    """The same run from the task's vectorised reference and from one that takes a scalar time:
    the controllers must ask the scalar one one time at a time and get the same torques."""
    config = ExperimentConfig(duration=0.05)
    experiment = build_experiment(config, controller)
    expected = run_closed_loop(experiment.plant, experiment.controller, experiment.reference, 0.05, 0, x0=experiment.x0)
    experiment = build_experiment(config, controller)
    scalar = ScalarReference(experiment.reference)
    got = run_closed_loop(experiment.plant, experiment.controller, scalar, 0.05, 0, x0=experiment.x0)
    np.testing.assert_array_equal(got.u, expected.u)


@pytest.mark.parametrize(
    ("settings", "field"),
    [({"control_period": 0.5, "duration": 0.1}, "control_period"), ({"control_period": 0.01, "duration": 0.004}, "")],
)
def test_a_run_without_a_control_step_is_refused_at_validation(settings, field):
    with pytest.raises(ConfigError, match="control_period .*must be <= duration|at least one control step"):
        with_overrides(ExperimentConfig(), settings)


def test_the_shortest_valid_run_has_metrics():
    """What passes validation must not fail later (docs/reliability.md): one control step."""
    config = with_overrides(ExperimentConfig(), {"control_period": 0.1, "duration": 0.1})
    metrics = tracking_metrics(build_experiment(config, "SMC").run())
    assert len(metrics["Ep"]) == 6 and all(np.isfinite(metrics["Ep"]))


def test_run_with_a_control_period_beyond_the_duration_exits_2_and_writes_nothing(tmp_path):
    out = tmp_path / "cp"
    result = RUNNER.invoke(app, ["run", "--set", "control_period=0.5", "--set", "duration=0.1", "--out", str(out)])
    line = _one_error_line(result)
    assert "control_period" in line and "duration" in line
    assert not out.exists()


@pytest.mark.parametrize(
    "command", [["run"], ["reproduce", "--quick"], ["run-uvms"], ["run", "--vehicle", "bluerov2-heavy"]]
)
def test_an_out_folder_that_cannot_be_made_exits_2_in_one_line(command):
    result = RUNNER.invoke(app, [*command, "--out", "/proc/hydroarm-cannot-be-here"])
    line = _one_error_line(result)
    assert "--out '/proc/hydroarm-cannot-be-here'" in line and "cannot write" in line


def test_an_out_folder_under_a_file_exits_2(tmp_path):
    (tmp_path / "file").write_text("x")
    line = _one_error_line(RUNNER.invoke(app, ["run", "--out", str(tmp_path / "file" / "run")]))
    assert "is not a folder" in line


def test_an_unknown_arm_controller_on_a_vehicle_exits_2_naming_the_allowed():
    line = _one_error_line(RUNNER.invoke(app, ["run", "--vehicle", "bluerov2-heavy", "--set", "arm_controller=foo"]))
    assert "arm_controller = 'foo'" in line and "gp-idmpc" in line


def test_the_vehicle_run_settings_refuse_a_run_without_a_step():
    with pytest.raises(ConfigError, match="control_period"):
        from hydroarm.config import validate

        validate(UVMSRunConfig, {"duration": 0.005, "control_period": 0.01}, "settings")


@pytest.mark.parametrize("arm_controller", ["idmpc", "gp-idmpc"])
def test_the_inverse_dynamics_mpcs_run_on_the_vehicle(arm_controller, tmp_path):
    """They sample the reach-and-return reference (scalar times only) over their horizon."""
    result = RUNNER.invoke(
        app,
        ["run", "--vehicle", "bluerov2-heavy", "--set", f"arm_controller={arm_controller}",
         "--set", "duration=1.2", "--out", str(tmp_path / "v")],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert (tmp_path / "v" / "metrics.json").is_file()
