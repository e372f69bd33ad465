"""Strict validation of the config models (``hydroarm.config.FrozenModel``: pydantic's strict mode).

No coercion across kinds: a boolean or a string for a number, a number or a string for a
boolean, a float for an int are refused with one :class:`ConfigError` line naming the field,
the value and what is allowed; what real inputs need is still accepted: an int for a float, a
list (TOML, YAML, ``--set``) for a tuple, a mapping for a nested model (such as the ``gp``
section).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import numpy as np
import pydantic
import pytest

from hydroarm.cli import _experiment_config
from hydroarm.config import ConfigError, FrozenModel, load_model, validate
from hydroarm.control.gp import GPConfig
from hydroarm.model.arm.loading import builtin_arm_path, load_arm
from hydroarm.model.water.morison import Water
from hydroarm.sim.experiment import ExperimentConfig, with_overrides
from hydroarm.studies.sweep import validate_sweep


def refused(data: dict, model=ExperimentConfig, source: str = "settings") -> str:
    """The message of the one ConfigError that validating ``data`` raises."""
    with pytest.raises(ConfigError) as error:
        validate(model, data, source)
    return str(error.value)


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        # a boolean for a number
        ({"mpc": {"horizon": True}}, "settings: mpc.horizon = True: Input should be a valid integer"),
        ({"water": {"rho": True}}, "settings: water.rho = True: Input should be a valid number"),
        ({"duration": False}, "settings: duration = False: Input should be a valid number"),
        # a number for a boolean
        ({"water": {"drag": 1}}, "settings: water.drag = 1: Input should be a valid boolean"),
        ({"gpmpc": {"variance_aware": 0.0}}, "settings: gpmpc.variance_aware = 0.0: Input should be a valid boolean"),
        # a string for a number
        (
            {"mpc": {"r": "0.1"}},
            "settings: mpc.r = '0.1': Input should be a valid number; or Input should be a valid list",
        ),
        ({"mpc": {"horizon": "10"}}, "settings: mpc.horizon = '10': Input should be a valid integer"),
        ({"plant": {"friction": "0"}}, "settings: plant.friction = '0': Input should be a valid number"),
        # a string for a boolean
        ({"water": {"buoyancy": "true"}}, "settings: water.buoyancy = 'true': Input should be a valid boolean"),
        # a float for an int (lax mode took an integral float)
        ({"mpc": {"horizon": 10.0}}, "settings: mpc.horizon = 10.0: Input should be a valid integer"),
        ({"initial_state": {"seed": 1.5}}, "settings: initial_state.seed = 1.5: Input should be a valid integer"),
        # a boolean inside a list: named by the item's path, once
        ({"mpc": {"r": [True, 1.0]}}, "settings: mpc.r.0 = True: Input should be a valid number"),
        ({"torque_limit": [1.0, "2"]}, "settings: torque_limit.1 = '2': Input should be a valid number"),
        (
            {"water": {"current": {"mean": [0.0, True, 0.0]}}},
            "settings: water.current.mean.1 = True: Input should be a valid number",
        ),
        # the gp section: strict fields, strict tuple items
        ({"gp": {"window": True}}, "settings: gp.window = True: Input should be a valid integer"),
        ({"gp": {"window": 10.0}}, "settings: gp.window = 10.0: Input should be a valid integer"),
        ({"gp": {"learning_rate": "0.1"}}, "settings: gp.learning_rate = '0.1': Input should be a valid number"),
        ({"gp": {"normalize_y": 1}}, "settings: gp.normalize_y = 1: Input should be a valid boolean"),
        (
            {"gp": {"log_sf2_bounds": [True, 1.0]}},
            "settings: gp.log_sf2_bounds.0 = True: Input should be a valid number",
        ),
        ({"gp": {"theta0": [1.0, 1.0, "1"]}}, "settings: gp.theta0.2 = '1': Input should be a valid number"),
        ({"gp": {"input_scale": "abc"}}, "settings: gp.input_scale = 'abc': Input should be a valid tuple"),
    ],
)
def test_no_coercion_across_kinds(data, expected):
    message = refused(data)
    assert message == expected, message


@pytest.mark.parametrize("value", [True, "1", 1.5])
@pytest.mark.parametrize("name", list(GPConfig.model_fields))
def test_every_gp_field_is_strict(name, value):
    """Every GPConfig field is strict as a settings section (a new field needs a Strict type)."""
    default = GPConfig.model_fields[name].default
    if type(default) is type(value) or (isinstance(default, float) and isinstance(value, float)):
        return  # a boolean for a boolean field, a float for a float field are fine
    if default is None and isinstance(value, float):
        return  # None-able tuples: a float is simply not a tuple (checked with "1" and True)
    message = refused({"gp": {name: value}})
    assert message.startswith(f"settings: gp.{name} = {value!r}: "), message
    assert "should be" in message or "must" in message, message
    assert len(message.splitlines()) == 1, message


def test_an_int_is_a_valid_float():
    config = validate(ExperimentConfig, {"water": {"rho": 1000, "current": {"mean": [0, 1, 0]}}, "duration": 2}, "s")
    assert config.water.rho == 1000.0 and isinstance(config.water.rho, float)
    assert config.water.current.mean == [0.0, 1.0, 0.0] and all(isinstance(x, float) for x in config.water.current.mean)
    assert isinstance(config.duration, float)


def test_numpy_floats_are_valid_floats():
    config = with_overrides(ExperimentConfig(), {"plant.noise_variance": np.float64(1e-3), "duration": np.float32(2.0)})
    assert config.plant.noise_variance == 1e-3 and config.duration == 2.0


def test_a_list_is_accepted_for_a_tuple_field():
    config = validate(ExperimentConfig, {"gp": {"log_sf2_bounds": [-1, 2], "theta0": [1, 2.0, 3]}}, "settings")
    assert config.gp.log_sf2_bounds == (-1.0, 2.0) and isinstance(config.gp.log_sf2_bounds, tuple)
    assert config.gp.theta0 == (1.0, 2.0, 3.0) and isinstance(config.gp.theta0, tuple)
    assert isinstance(config.gp, GPConfig)


def test_nested_models_given_as_mappings_and_instances_validate():
    config = validate(ExperimentConfig, {"water": {"cd": 0.5, "current": {"model": "none"}}, "gp": {"window": 5}}, "s")
    assert config.water.cd == 0.5 and config.water.current.model == "none" and config.gp.window == 5
    again = ExperimentConfig(water=Water(cd=0.7), gp=GPConfig(window=6))
    assert again.water.cd == 0.7 and again.gp.window == 6


def test_a_dump_validates_again():
    """``with_overrides`` validates ``model_dump`` (tuples, python mode) and files give JSON-like dumps (lists)."""
    config = validate(ExperimentConfig, {"gp": {"theta0": [1.0] * 14}, "mpc": {"r": [0.1] * 6}}, "settings")
    assert validate(ExperimentConfig, config.model_dump(mode="python"), "settings") == config
    assert validate(ExperimentConfig, config.model_dump(mode="json"), "settings") == config
    assert with_overrides(config, {"mpc.horizon": 12}).mpc.horizon == 12


def test_a_toml_file_with_a_boolean_for_a_number_is_refused(tmp_path):
    path = tmp_path / "settings.toml"
    path.write_text("[mpc]\nhorizon = true\n[gp]\nlog_sf2_bounds = [-1.0, 2]\n")
    with pytest.raises(ConfigError) as error:
        load_model(ExperimentConfig, path)
    assert str(error.value) == f"{path}: mpc.horizon = True: Input should be a valid integer"
    path.write_text("[mpc]\nhorizon = 12\n[gp]\nlog_sf2_bounds = [-1.0, 2]\n")
    config = load_model(ExperimentConfig, path)
    assert config.mpc.horizon == 12 and config.gp.log_sf2_bounds == (-1.0, 2.0)


def test_an_arm_file_with_a_string_for_a_number_is_refused(tmp_path):
    text = builtin_arm_path("paper").read_text()
    path = tmp_path / "arm.toml"
    path.write_text(text.replace("gravity = 9.81", 'gravity = "9.81"', 1))
    assert 'gravity = "9.81"' in path.read_text()
    with pytest.raises(ConfigError) as error:
        load_arm(path)
    assert str(error.value) == f"{path}: gravity = '9.81': Input should be a valid number", str(error.value)


@pytest.mark.parametrize(
    ("item", "expected"),
    [
        ("water.drag=1", "water.drag = 1: Input should be a valid boolean"),
        ("water.drag=yes", "water.drag = 'yes': Input should be a valid boolean"),
        ("mpc.horizon=true", "mpc.horizon = True: Input should be a valid integer"),
        ("mpc.r=0.1x", "mpc.r = '0.1x': Input should be a valid number"),
        ("gp.log_sf2_bounds=[true, 1.0]", "gp.log_sf2_bounds.0 = True: Input should be a valid number"),
    ],
)
def test_cli_set_values_are_strict(item, expected):
    with pytest.raises(ConfigError) as error:
        _experiment_config(None, [item])
    assert str(error.value).startswith("settings: " + expected), str(error.value)


def test_cli_set_gives_lists_for_tuples_and_ints_for_floats():
    config = _experiment_config(None, ["gp.log_sf2_bounds=[-1, 2]", "water.rho=1000", "water.drag=false", "arm=ur5"])
    assert config.gp.log_sf2_bounds == (-1.0, 2.0) and config.water.rho == 1000.0
    assert config.water.drag is False and config.arm == "ur5"


def test_sweep_range_is_strict():
    data = {"controllers": ["SMC"], "parameters": {"mpc.r": {"low": True, "high": 1.0, "num": 2}}}
    with pytest.raises(ConfigError, match=r"parameters\.mpc\.r: low = True: Input should be a valid number"):
        validate_sweep(data, "s.toml")
    data["parameters"]["mpc.r"] = {"low": 1, "high": 2, "num": 2, "log": "yes"}
    with pytest.raises(ConfigError, match=r"parameters\.mpc\.r: log = 'yes': Input should be a valid boolean"):
        validate_sweep(data, "s.toml")
    data["parameters"]["mpc.r"] = {"low": 1, "high": 2, "num": 2}
    assert validate_sweep(data, "s.toml").parameters["mpc.r"].low == 1.0


class _Relaxed(FrozenModel):
    """The recipe of FrozenModel's docstring: one field relaxed, its items strict."""

    path: Annotated[Path, pydantic.Strict(False)] = Path(".")
    pair: Annotated[tuple[pydantic.StrictFloat, pydantic.StrictFloat], pydantic.Strict(False)] = (0.0, 1.0)
    strict_pair: tuple[float, float] = (0.0, 1.0)


def test_relaxed_fields_take_strings_for_paths_and_lists_for_tuples():
    model = validate(_Relaxed, {"path": "runs/a.toml", "pair": [1, 2.5]}, "x")
    assert model.path == Path("runs/a.toml") and model.pair == (1.0, 2.5)
    assert refused({"pair": [True, 1.0]}, _Relaxed, "x") == "x: pair.0 = True: Input should be a valid number"
    assert refused({"pair": ["1", 1.0]}, _Relaxed, "x") == "x: pair.0 = '1': Input should be a valid number"
    assert refused({"path": 3}, _Relaxed, "x").startswith("x: path = 3: ")
    # without the relaxation, strict mode refuses a list for a tuple
    assert (
        refused({"strict_pair": [1.0, 2.0]}, _Relaxed, "x")
        == "x: strict_pair = [1.0, 2.0]: Input should be a valid tuple"
    )


def test_non_finite_numbers_are_still_refused():
    assert refused({"water": {"rho": math.inf}}) == "settings: water.rho = inf: Input should be a finite number"
    assert refused({"gp": {"jitter": math.nan}}) == "settings: gp.jitter = nan: Input should be a finite number"
