"""Which value wins between the settings, the arm file and its hydrodynamics file
(hydroarm.studies.settings_resolved): the resolved values are the ones the code uses (the strip
water's coefficients, the experiment's torque limit), and docs/settings.md's table is PRECEDENCE."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from hydroarm.cli import app
from hydroarm.model.arm.loading import load_arm
from hydroarm.model.water.strips import StripGeometry
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides
from hydroarm.studies.settings_resolved import PRECEDENCE, resolve_settings

ROOT = Path(__file__).resolve().parents[1]
MYARM = str(ROOT / "examples" / "urdf" / "myarm.hydro.toml")  # its upper_arm link sets cd = 1.2


def _by(rows, setting):
    return {row.where: row for row in rows if row.setting == setting}


def test_the_resolved_coefficients_are_the_strip_waters():
    """The hydrodynamics file's link cd (1.2) wins over water.cd = 0.8; every other cylinder takes
    water.cd; each resolved C_d and C_m is the one StripGeometry integrates."""
    config = with_overrides(ExperimentConfig(), {"arm": MYARM, "water.cd": 0.8, "water.cm": 1.5})
    arm = load_arm(MYARM)
    rows = resolve_settings(config, arm)
    cd, cm = _by(rows, "water.cd"), _by(rows, "water.cm")
    assert float(cd["upper_arm"].value) == 1.2 and "hydrodynamics file" in cd["upper_arm"].source
    assert all(
        float(row.value) == 0.8 and row.source == "settings water.cd" for k, row in cd.items() if k != "upper_arm"
    )
    water = config.water
    geometry = StripGeometry(arm, water)
    for k, cylinder in enumerate(arm.cylinders):
        used_cd = geometry.drag_per_length[k] / (0.5 * water.rho * cylinder.diameter)
        used_cm = geometry.mass_per_length[k] / (water.rho * cylinder.area)
        assert np.isclose(used_cd, float(cd[cylinder.name].value), rtol=1e-12)
        assert np.isclose(used_cm, float(cm[cylinder.name].value), rtol=1e-12)


def test_the_resolved_torque_limit_is_the_experiments():
    for overrides, source in (({}, "the arm file's torque_limit"), ({"torque_limit": 7.5}, "settings torque_limit")):
        config = with_overrides(ExperimentConfig(duration=0.05), overrides)
        row = _by(resolve_settings(config, load_arm(config.arm)), "torque_limit")
        (row,) = row.values()
        used = build_experiment(config, "SMC").arm.torque_limit
        assert [float(x) for x in row.value.split(", ")] == used.tolist() and row.source == source


def test_docs_settings_md_carries_the_precedence_table():
    text = (ROOT / "docs" / "settings.md").read_text()
    for what, sources in PRECEDENCE:
        assert f"| {what} | " + " | ".join(sources) in text


def test_settings_resolved_command():
    result = CliRunner().invoke(app, ["settings", "--resolved", "--arm", MYARM, "--set", "water.cd=0.8", "--json"])
    assert result.exit_code == 0, result.output
    rows = json.loads(result.stdout)
    upper = [r for r in rows if r["setting"] == "water.cd" and r["where"] == "upper_arm"]
    assert upper[0]["value"] == "1.2"
    bad = CliRunner().invoke(app, ["settings", "--arm", "paper"])
    assert bad.exit_code == 2 and "--resolved" in bad.output


def test_cylinder_over_link_over_water(tmp_path):
    """The three tiers of the one coefficient rule (hydroarm.model.arm.description.coefficient): a cylinder's own
    cd (1.7) beats its link's (1.2), which beats water.cd (0.8); a cylinder with neither takes the
    water's; the resolved table and the strip water agree on each."""
    import shutil

    from hydroarm.model.arm.description import coefficient

    shutil.copy(ROOT / "examples" / "urdf" / "myarm.urdf", tmp_path / "myarm.urdf")
    text = (ROOT / "examples" / "urdf" / "myarm.hydro.toml").read_text()
    text = text.replace('link = "forearm"\n', 'link = "forearm"\ncd = 1.2\ncm = 1.4\n')
    text = text.replace("diameter = 0.06\n", "diameter = 0.06\ncd = 1.7\n")
    (tmp_path / "myarm.hydro.toml").write_text(text)
    hydro = str(tmp_path / "myarm.hydro.toml")
    arm = load_arm(hydro)
    config = with_overrides(ExperimentConfig(), {"arm": hydro, "water.cd": 0.8, "water.cm": 1.5})
    forearm = next(c for c in arm.cylinders if c.name.startswith("forearm"))
    column = next(c for c in arm.cylinders if c.name.startswith("column"))
    assert forearm.coefficients(config.water) == (1.7, 1.4)  # cylinder cd, link cm
    assert column.coefficients(config.water) == (0.8, 1.5)  # the water's
    assert coefficient(None, None, 0.8) == 0.8 and coefficient(1.7, 1.2, 0.8) == 1.7 and coefficient(None) is None
    rows = resolve_settings(config, arm)
    assert _by(rows, "water.cd")[forearm.name].value == "1.7" and _by(rows, "water.cm")[forearm.name].value == "1.4"
    geometry = StripGeometry(arm, config.water)
    k = arm.cylinders.index(forearm)
    assert np.isclose(geometry.drag_per_length[k], 0.5 * config.water.rho * 1.7 * forearm.diameter, rtol=1e-12)


def test_the_resolved_system_rows_are_what_each_plant_reads():
    """The inner step, the current and the Gauss points, as `--resolved` gives them per system,
    are the floating plant's and the fixed-base plant's own (compiled or not)."""
    vehicle = with_overrides(
        ExperimentConfig(duration=0.1),
        {"vehicle.name": "bluerov2-heavy", "arm": "mount", "vehicle.current": 0.3, "vehicle.plant.drag_points": 4},
    )
    built = build_experiment(vehicle, None)
    rows = {row.setting: row for row in resolve_settings(vehicle, built.arm)}
    assert float(rows["vehicle.plant.inner_step"].value) == built.plant.config.inner_step
    assert float(rows["vehicle.current"].value) == built.plant.water.current.mean[0]
    assert int(rows["vehicle.plant.drag_points"].value) == built.plant.fast.geometry.nodes.shape[0] == 4
    for overrides, key, points in (
        ({"water.quadrature_points": 6}, "water.quadrature_points", 6),
        ({"plant.compiled": True, "plant.drag_points": 3}, "plant.drag_points", 3),
    ):
        fixed = with_overrides(ExperimentConfig(duration=0.1), overrides)
        plant = build_experiment(fixed, None).plant
        rows = {row.setting: row for row in resolve_settings(fixed, load_arm(fixed.arm))}
        water = plant.fast.water if plant.fast is not None else plant.water
        assert int(rows[key].value) == water.quadrature_points == points
        assert rows["water.current"].value == plant.water.current.model
