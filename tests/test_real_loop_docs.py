"""docs/robustness.md, section 6: its tables are the results files' (issue 32), written by the
scripts that made them (scripts/real_loop_defaults.py, scripts/real_loop_campaign.py)."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

from hydroarm.control.estimator import EstimatorConfig
from hydroarm.studies.sweep.schema import load_sweep

ROOT = Path(__file__).resolve().parents[1]


def _script(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_default_real_loop_table_is_its_results_file():
    script = _script("real_loop_defaults")
    data = json.loads((ROOT / "docs" / "data" / "real_loop_defaults.json").read_text())
    rows = script.rows(data["runs"])
    for row, stored in zip(rows, data["rows"], strict=True):  # the rows follow from the runs
        for key, value in row.items():
            same = (math.isnan(value) and math.isnan(stored[key])) if isinstance(value, float) else False
            assert same or value == stored[key], (row["arm"], row["controller"], key)
    table = script.table(rows)
    assert (ROOT / "docs" / "data" / "real_loop_defaults.md").read_text() == table
    assert table in (ROOT / "docs" / "robustness.md").read_text()
    # the command is the issue's, with nothing else set
    assert data["command"].endswith(
        "--set sensor.velocity=differenced --set sensor.resolution=9.5874e-05 --set sensor.delay=1 "
        "--set friction.scale=1.0"
    )


def test_the_campaign_tables_are_its_results_file():
    script = _script("real_loop_campaign")
    data = json.loads((ROOT / "docs" / "data" / "real_loop.json").read_text())
    assert script.table(data["runs"]) in (ROOT / "docs" / "robustness.md").read_text()
    assert script.grid_table(data["runs"]) in (ROOT / "docs" / "robustness.md").read_text()
    # run on defaults: the sweep file sets no estimator setting
    assert load_sweep(ROOT / "examples" / "real_loop.toml").base.estimator == EstimatorConfig()
