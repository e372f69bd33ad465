"""The system a run simulates is a fixed arm or an arm on a vehicle (issue 33): a setting the
other system reads fails validation with one message naming the field (exit 2 on the CLI),
before anything is built."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from hydroarm.cli import app
from hydroarm.cli._common import _experiment_config
from hydroarm.config import ConfigError
from hydroarm.sim.experiment import ExperimentConfig, load_experiment_config, with_overrides
from hydroarm.sim.vehicle import FIXED_BASE_ONLY_SECTIONS
from hydroarm.studies.sweep import load_sweep, plan_sweep

ROOT = Path(__file__).resolve().parents[1]
RUNNER = CliRunner()
VEHICLE = "bluerov2-heavy"


@pytest.mark.parametrize(
    ("key", "value"),
    [("vehicle.aware", True), ("vehicle.current", 0.5), ("vehicle.control.kind", "mpc"), ("vehicle.gp.window", 30)],
)
def test_a_fixed_arm_refuses_a_vehicle_setting(key, value):
    with pytest.raises(ConfigError) as error:
        with_overrides(ExperimentConfig(), {key: value})
    message = str(error.value)
    assert message.startswith(f"settings: {key} = {value!r}: read only by a run on a vehicle") and "\n" not in message
    assert with_overrides(ExperimentConfig(), {"vehicle.name": VEHICLE, key: value}).vehicle.name == VEHICLE


@pytest.mark.parametrize(
    ("key", "value"), [("sensor.delay", 2), ("plant.noise_variance", 1e-4), ("friction.scale", 1.0)]
)
def test_a_vehicle_run_refuses_a_fixed_base_setting(key, value):
    assert key.split(".")[0] in FIXED_BASE_ONLY_SECTIONS
    with pytest.raises(ConfigError, match="^settings: " + re.escape(key) + " = .*: not used on a vehicle run"):
        with_overrides(ExperimentConfig(), {"vehicle.name": VEHICLE, key: value})
    assert with_overrides(ExperimentConfig(), {key: value}).vehicle.name is None  # a fixed arm takes it


def test_the_cli_refuses_either_with_exit_2_before_any_work(tmp_path):
    out = tmp_path / "out"
    for args, words in (
        (["--set", "vehicle.aware=true"], "vehicle.aware = True: read only by a run on a vehicle"),
        (["--vehicle", VEHICLE, "--set", "sensor.delay=2"], "sensor.delay = 2: not used on a vehicle run"),
    ):
        result = RUNNER.invoke(app, ["run", *args, "--out", str(out)])
        assert result.exit_code == 2 and words in result.output, result.output
        assert "Traceback" not in result.output and not out.exists()
    file = tmp_path / "s.toml"
    file.write_text("[vehicle]\naware = true\n")
    with pytest.raises(ConfigError, match="vehicle.aware = True: read only by a run on a vehicle"):
        load_experiment_config(file)


def test_vehicle_and_its_settings_are_validated_together_on_the_cli():
    """``hydroarm run --vehicle X --set vehicle.control.kind=mpc`` (docs/vehicle.md): the vehicle
    is among the overrides, not applied after them."""
    config = _experiment_config(None, ["vehicle.control.kind=mpc"], vehicle=VEHICLE)
    assert config.vehicle.name == VEHICLE and config.vehicle.control.kind == "mpc"


def test_every_example_sweep_still_validates(monkeypatch):
    monkeypatch.chdir(ROOT / "examples")  # their arm files are named from there
    for path in sorted((ROOT / "examples").glob("*.toml")):
        if path.name == "myarm.toml":  # an arm file
            continue
        plan_sweep(load_sweep(path), source=str(path))
