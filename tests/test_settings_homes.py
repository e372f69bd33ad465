"""One home per setting (issue 33): each setting that several modules or files can give is
defined once and, per system, read from one place; a key another system reads is refused naming
its home, never validated and then replaced."""

from __future__ import annotations

import re
from pathlib import Path

import pydantic
import pytest
from typer.testing import CliRunner

from hydroarm.cli import app
from hydroarm.config import ConfigError
from hydroarm.model.integrator import INNER_STEP_RANGE
from hydroarm.model.plant import PlantConfig
from hydroarm.model.uvms_fast import FastUVMSConfig
from hydroarm.model.uvms_plant import UVMSPlantConfig
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides
from hydroarm.sim.vehicle import VEHICLE_HOMES
from hydroarm.studies.replay import ReplayConfig

ROOT = Path(__file__).resolve().parents[1]
VEHICLE = "bluerov2-heavy"


def _bounds(model: type[pydantic.BaseModel], name: str) -> tuple[float, float]:
    low = high = None
    for item in model.model_fields[name].metadata:
        low = getattr(item, "ge", None) if getattr(item, "ge", None) is not None else low
        high = getattr(item, "le", None) if getattr(item, "le", None) is not None else high
    return low, high


@pytest.mark.parametrize("model", [PlantConfig, UVMSPlantConfig, FastUVMSConfig, ReplayConfig])
def test_every_inner_step_is_the_one_setting(model):
    """Every plant's inner_step has the one range (model.integrator.inner_step_setting); the
    replay's took 1e-4 as its floor before."""
    assert _bounds(model, "inner_step") == INNER_STEP_RANGE
    with pytest.raises(pydantic.ValidationError):
        model(inner_step=INNER_STEP_RANGE[1] * 1.01)


def test_no_plant_declares_its_own_inner_step():
    """grep: no ``inner_step = pydantic.Field`` (or ``inner_step: float = pydantic.Field``) in src:
    each goes through inner_step_setting."""
    found = [
        f"{path.relative_to(ROOT)}"
        for path in (ROOT / "src").rglob("*.py")
        if re.search(r"inner_step:\s*float\s*=\s*pydantic\.Field", path.read_text())
    ]
    assert found == []


def test_each_system_reads_its_own_inner_step():
    """A fixed arm integrates with plant.inner_step, a vehicle run with vehicle.plant.inner_step;
    on a vehicle run, plant.inner_step is refused naming the field (it would be ignored)."""
    fixed = build_experiment(with_overrides(ExperimentConfig(duration=0.1), {"plant.inner_step": 2e-3}), None)
    assert fixed.plant.inner_step == 2e-3
    floating = build_experiment(
        with_overrides(ExperimentConfig(duration=0.1), {"vehicle.name": VEHICLE, "arm": "mount",
                                                         "vehicle.plant.inner_step": 2e-3}), None,
    )  # fmt: skip
    assert floating.plant.config.inner_step == 2e-3
    with pytest.raises(ConfigError, match=r"plant.inner_step = 0.002: not used on a vehicle run"):
        with_overrides(ExperimentConfig(), {"vehicle.name": VEHICLE, "plant.inner_step": 2e-3})


@pytest.mark.parametrize(
    ("key", "value"),
    [("water.current.model", "uniform"), ("water.current.mean", [0.3, 0.0, 0.0]), ("water.quadrature_points", 5)],
)
def test_a_vehicle_run_refuses_a_water_setting_it_takes_from_its_own_section(key, value):
    """water.current and water.quadrature_points were replaced, silently, by vehicle.current and
    vehicle.plant.drag_points on a vehicle run: now refused naming their home; a fixed arm takes them."""
    home = VEHICLE_HOMES[".".join(key.split(".")[:2])]
    with pytest.raises(ConfigError) as error:
        with_overrides(ExperimentConfig(), {"vehicle.name": VEHICLE, key: value})
    message = str(error.value)
    assert "not used on a vehicle run" in message and f"a vehicle run's is {home}" in message
    assert "\n" not in message
    with_overrides(ExperimentConfig(), {key: value})  # the fixed arm reads it


def test_the_vehicle_homes_are_the_ones_the_floating_plant_reads():
    """vehicle.current and vehicle.plant.drag_points reach the floating plant (the homes named)."""
    config = with_overrides(
        ExperimentConfig(duration=0.1),
        {"vehicle.name": VEHICLE, "arm": "mount", "vehicle.current": 0.35, "vehicle.plant.drag_points": 5},
    )
    plant = build_experiment(config, None).plant
    assert list(plant.water.current.mean) == [0.35, 0.0, 0.0] and plant.water.current.model == "uniform"
    assert plant.fast.geometry.nodes.shape == (5,)


def test_the_cli_refuses_water_current_on_a_vehicle_with_exit_2(tmp_path):
    out = tmp_path / "out"
    result = CliRunner().invoke(
        app, ["run", "--vehicle", VEHICLE, "--set", "water.current.model=uniform", "--out", str(out)]
    )
    assert result.exit_code == 2 and "water.current = " in result.output and "vehicle.current" in result.output
    assert "Traceback" not in result.output and not out.exists()


def test_every_water_density_is_the_one_setting():
    """Water.rho and the replay's water_density: one definition (model.water.density_setting)."""
    from hydroarm.model.water import Water

    for model, name in ((Water, "rho"), (ReplayConfig, "water_density")):
        field = model.model_fields[name]
        low = next(item.gt for item in field.metadata if getattr(item, "gt", None) is not None)
        high = next(item.le for item in field.metadata if getattr(item, "le", None) is not None)
        assert (low, high) == (0.0, 2000.0) and field.description.endswith("(kg/m^3)")
