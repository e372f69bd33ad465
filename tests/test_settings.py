"""Every setting findable (issue 16): a description on every field, `hydroarm settings` and
docs/settings.md generated from the config models, and an unknown key answered with the
nearest known ones."""

from __future__ import annotations

import json
from pathlib import Path

import pydantic
import pytest
from typer.testing import CliRunner

from hydroarm.cli import app
from hydroarm.config import ConfigError, _members, dotted_keys
from hydroarm.sim.experiment import ExperimentConfig, with_overrides
from hydroarm.studies.settings_table import experiment_settings, settings_markdown, settings_table
from hydroarm.studies.sweep import plan_sweep, validate_sweep
from hydroarm.studies.sweep.schema import Mismatch

ROOT = Path(__file__).resolve().parents[1]
RUNNER = CliRunner()


def _models(model: type[pydantic.BaseModel]) -> list[type[pydantic.BaseModel]]:
    """``model`` and every config model reachable from its fields."""
    found = [model]
    for field in model.model_fields.values():
        for member in _members(field.annotation):
            if isinstance(member, type) and issubclass(member, pydantic.BaseModel) and member not in found:
                found += [m for m in _models(member) if m not in found]
    return found


def test_every_field_of_every_config_model_has_a_description():
    missing = [
        f"{model.__module__}.{model.__name__}.{name}"
        for model in (*_models(ExperimentConfig), Mismatch)
        for name, field in model.model_fields.items()
        if not (field.description or "").strip()
    ]
    assert missing == []


def test_docs_settings_md_is_up_to_date():
    """docs/settings.md is what `hydroarm settings --markdown` prints (regenerate it with that)."""
    assert (ROOT / "docs" / "settings.md").read_text() == settings_markdown(), (
        "docs/settings.md is stale: run `hydroarm settings --markdown > docs/settings.md`"
    )


def test_the_table_has_every_key_its_default_and_its_range():
    rows = {row.key: row for row in settings_table()}
    leaves = [
        k
        for k in dotted_keys(ExperimentConfig)
        if not any(o.startswith(k + ".") for o in dotted_keys(ExperimentConfig))
    ]
    assert list(rows) == leaves
    assert rows["mpc.horizon"].default == 10 and rows["mpc.horizon"].allowed == "1 <= x <= 200"
    assert rows["duration"].allowed == "0 < x <= 3600" and "(s)" in rows["duration"].description
    assert rows["water.current.model"].allowed == "one of paper, uniform, none"
    assert rows["water.current.mean"].allowed == "3 values, each -20 <= x <= 20"
    assert rows["smc.surface_slope"].kind == "float or one per joint"
    assert rows["torque_limit"].default is None and rows["torque_limit"].allowed.endswith("or null")
    assert rows["gp.log_sf2_bounds"].allowed.startswith("2 values")
    assert rows["water.drag"].allowed == "true or false"


def test_every_default_shown_is_the_one_a_run_gets():
    """Each row's default is the value at its key in ``ExperimentConfig()``, including sections whose
    parent gives them other defaults than their model's own (shown wrong before 2026-12-05:
    ``water_model.remainder.kind`` "none" for PI-IDMPC's TDE, ``vehicle.gp.window`` 10 for 60)."""
    config = ExperimentConfig().model_dump(mode="json")
    for row in settings_table():
        value = config
        for part in row.key.split("."):
            value = value[part]
        assert row.default == value, row.key
    rows = {row.key: row.default for row in settings_table()}
    assert rows["water_model.remainder.kind"] == "tde" and rows["vehicle.gp.window"] == 60


def test_cli_settings_of_one_controller_shows_only_the_sections_it_reads():
    result = RUNNER.invoke(app, ["settings", "--controller", "gp-mpc", "--json"])
    assert result.exit_code == 0, result.output
    sections = {row["section"].split(".")[0] for row in json.loads(result.output)}
    assert sections == {
        "", "water", "plant", "sensor", "actuator", "friction", "initial_state", "vehicle", "mpc", "gp", "gpmpc",
        "estimator",
    }  # fmt: skip
    every = RUNNER.invoke(app, ["settings", "--json"])
    assert [row["key"] for row in json.loads(every.output)] == [row.key for row in experiment_settings()]
    text = RUNNER.invoke(app, ["settings", "--controller", "smc"]).output
    assert "smc.switching_gain = 50.0" in text and "mpc.r" not in text and "0 < x <= 1e+06" in text
    wrong = RUNNER.invoke(app, ["settings", "--controller", "pid"])
    assert wrong.exit_code == 2 and "pid" in wrong.output


HINT = "hydroarm settings"


def test_an_unknown_setting_names_the_nearest_ones_and_where_to_find_all(tmp_path):
    with pytest.raises(ConfigError) as error:
        with_overrides(ExperimentConfig(), {"mpc.rr": 0.001})
    assert str(error.value).startswith("unknown setting 'mpc.rr'; did you mean 'mpc.r'?") and HINT in str(error.value)
    result = RUNNER.invoke(app, ["run", "--set", "mpc.rr=0.001", "--out", str(tmp_path / "out")])
    assert result.exit_code == 2 and "unknown setting 'mpc.rr'; did you mean 'mpc.r'?" in result.output
    assert HINT in result.output and not (tmp_path / "out").exists()


def test_a_value_is_pointed_at_settings_and_a_section_given_a_value_names_its_settings(tmp_path):
    """``--set vehicle_controller=pid`` is answered with settings (``vehicle.control.kind``), not
    with the section ``vehicle.control`` (setting that to a string only moved the error); a table
    is still answered with sections; a section given a value names its settings, in one line."""
    with pytest.raises(ConfigError) as error:
        with_overrides(ExperimentConfig(), {"vehicle_controller": "pid"})
    assert "did you mean 'vehicle.control.kind'" in str(error.value)
    assert "'vehicle.control'" not in str(error.value)
    config = tmp_path / "c.toml"
    config.write_text("[vehicle_control]\nkind = 'pid'\n")
    result = RUNNER.invoke(app, ["run", "--config", str(config), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2 and "did you mean 'vehicle.control'?" in result.output
    result = RUNNER.invoke(app, ["run", "--set", "vehicle.control=pid", "--out", str(tmp_path / "out")])
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert "vehicle.control = 'pid': a section, not a setting: set its settings (kind," in result.output


def test_an_unknown_setting_in_a_config_file_or_a_sweep_file(tmp_path):
    config = tmp_path / "c.toml"
    config.write_text("[mpc]\nrr = 0.001\n")
    result = RUNNER.invoke(app, ["run", "--config", str(config), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2 and "unknown setting 'mpc.rr'; did you mean 'mpc.r'?" in result.output
    assert HINT in result.output
    with pytest.raises(ConfigError, match=r"unknown setting 'base\.mpc\.rr'; did you mean 'base\.mpc\.r'\?"):
        validate_sweep({"controllers": ["MPC"], "base": {"mpc": {"rr": 1}}}, "s.toml")
    with pytest.raises(ConfigError) as error:
        plan_sweep(validate_sweep({"controllers": ["MPC"], "parameters": {"mpc.rr": [0.1]}}, "s.toml"), source="s.toml")
    assert "parameters.mpc.rr: unknown setting 'mpc.rr'; did you mean 'mpc.r'?" in str(error.value)
    assert HINT in str(error.value)


def test_plain_settings_lists_every_section_markdown_does():
    """`hydroarm settings` with no option lists the replay's and the mismatch's sections too, as
    --markdown and docs/settings.md do (it listed the run's alone, while the docs pointed to it)."""
    text = CliRunner().invoke(app, ["settings"]).output
    for key in ("joint_time_offset = 0.0", "imu_mounting_rpy_deg", "cleaning.smoothing", "mismatch.mass_scale"):
        assert key in text, key
