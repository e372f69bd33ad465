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
