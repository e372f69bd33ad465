"""docs/robustness.md, section 6: its tables are the results files' (issue 32), written by the
scripts that made them (scripts/real_loop_defaults.py, scripts/real_loop_campaign.py)."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import pytest

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


ARM_CONTROLLERS = ["GP-IDMPC", "IDMPC"]


def _by_arm(script) -> dict[str, list[dict]]:
    paper = json.loads((ROOT / "docs" / "data" / "real_loop.json").read_text())["runs"]
    arms = json.loads((ROOT / "docs" / "data" / "real_loop_arms.json").read_text())["arms"]
    return {"paper": paper, **{arm: arms[arm]["runs"] for arm in script.ARMS if arm in arms}}


def test_the_campaign_on_every_arm_is_its_results_file():
    script = _script("real_loop_campaign")
    by_arm = _by_arm(script)
    assert list(by_arm) == ["paper", "ur5", "alpha5", "iiwa14"]
    page = (ROOT / "docs" / "robustness.md").read_text()
    assert script.arms_table(by_arm, ARM_CONTROLLERS) in page
    assert script.arms_world_table(by_arm, "GP-IDMPC") in page
    assert script.arms_rate_table(by_arm, ARM_CONTROLLERS) in page
    assert script.arms_table(by_arm, ["SMC", "MPC", "GP-MPC"]) in page  # where they ran: paper, alpha5, iiwa14


def test_every_arm_runs_the_sweep_files_grid_and_its_own_ideal_loop():
    """Each arm's runs are keyed by it and cover the sweep file's 18 worlds for each controller,
    with that controller's ideal loop on the same arm (the reference of E_p / ideal)."""
    script = _script("real_loop_campaign")
    data = json.loads((ROOT / "docs" / "data" / "real_loop_arms.json").read_text())
    worlds = {t[1]: t[4] for t in script.tasks("paper") if t[0] == "grid"}
    assert len(worlds) == 18
    for arm, entry in data["arms"].items():
        assert entry["arm"] == script.ARMS[arm]
        for controller in ARM_CONTROLLERS:
            runs = [r for r in entry["runs"] if r["controller"] == controller]
            assert all(r["arm"] == arm for r in runs)
            grid = {r["world"]: r["overrides"] for r in runs if r["group"] == "grid"}
            assert grid == worlds, (arm, controller)
            assert [r["world"] for r in runs if r["group"] == "alone" and r["world"] == "ideal"] == ["ideal"]


def test_the_reference_torque_is_the_plants_inverse_dynamics():
    """The stored torque the ur5's reference needs is recomputed, and on the paper arm (500 N m
    per joint) the reference never asks more than the limit."""
    script = _script("real_loop_campaign")
    stored = json.loads((ROOT / "docs" / "data" / "real_loop_arms.json").read_text())["reference_torque"]
    again = script.reference_torque("ur5")
    for key, values in again.items():
        assert values == pytest.approx(stored["ur5"][key], rel=1e-9, abs=1e-9), key
    assert max(stored["paper"]["share_over_limit"]) == 0.0
    assert max(stored["paper"]["peak_Nm"]) < min(stored["paper"]["limit_Nm"])


def test_the_observer_variants_in_the_paper_grid_are_its_results_file():
    script = _script("real_loop_campaign")
    runs = json.loads((ROOT / "docs" / "data" / "real_loop.json").read_text())["runs"]
    variants = [name for name in script.VARIANTS if any(r["controller"] == name for r in runs)]
    assert {"IDMPC+TDE", "IDMPC+TDE-gated", "IDMPC+NDOB", "IDMPC+NDOB-gated"} <= set(variants)
    page = (ROOT / "docs" / "robustness.md").read_text()
    assert script.table(runs, variants) in page
    assert script.grid_table(runs, variants) in page


class _Serial:
    """A stand-in for the campaign's process pool: the runs one after another, in this process."""

    def __init__(self, workers):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def map(self, function, tasks):
        return (function(task) for task in tasks)


@pytest.mark.parametrize("arm", ["paper", "alpha5"])
def test_an_interrupted_campaign_keeps_the_runs_it_finished(tmp_path, monkeypatch, arm):
    """The results file is written after every run: interrupted at its third run, the campaign's
    file holds the first two (and, merged into another arm's file, that file's other runs)."""
    script = _script("real_loop_campaign")
    out = tmp_path / "campaign.json"
    if arm != "paper":
        out.write_text(json.dumps({"arms": {"ur5": {"arm": "ur5", "runs": [{"kept": True}], "wall_time_s": {}}}}))

    def fake_run(task):
        if fake_run.calls == 2:
            raise KeyboardInterrupt
        fake_run.calls += 1
        group, world, controller = task[:3]
        return {"group": group, "world": world, "controller": controller, "Ep": 0.01, "within_band": True,
                "wall_s": 1.0}  # fmt: skip

    fake_run.calls = 0
    monkeypatch.setattr(script, "run", fake_run)
    monkeypatch.setattr(script, "ProcessPoolExecutor", _Serial)
    argv = ["real_loop_campaign.py", "--arm", arm, "--out", str(out), "--controllers", "IDMPC", "--groups", "grid"]
    monkeypatch.setattr("sys.argv", argv)
    with pytest.raises(KeyboardInterrupt):
        script.main()
    data = json.loads(out.read_text())
    runs = data["runs"] if arm == "paper" else data["arms"][arm]["runs"]
    assert [r["controller"] for r in runs] == ["IDMPC", "IDMPC"] and len({r["world"] for r in runs}) == 2
    if arm != "paper":
        assert data["arms"]["ur5"]["runs"] == [{"kept": True}]
    assert not out.with_suffix(".json.partial").exists()


def test_the_observer_variants_and_pi_idmpc_on_every_arm_are_the_results_file():
    """The variants' and PI-IDMPC's tables on every arm are the campaign's results (the paper arm's
    from docs/data/real_loop.json), and every arm ran each of them in the 18 grid worlds."""
    script = _script("real_loop_campaign")
    by_arm = _by_arm(script)
    variants = ["IDMPC+TDE", "IDMPC+TDE-gated", "IDMPC+NDOB", "IDMPC+NDOB-gated"]
    page = (ROOT / "docs" / "robustness.md").read_text()
    assert script.arms_table(by_arm, variants) in page
    assert script.arms_table(by_arm, ["PI-IDMPC"]) in page
    assert script.arms_rate_table(by_arm, ["PI-IDMPC"]) in page
    assert script.arms_world_table(by_arm, "PI-IDMPC") in page
    for arm, runs in by_arm.items():
        for controller in [*variants, "PI-IDMPC"]:
            grid = {r["world"] for r in runs if r["controller"] == controller and r["group"] == "grid"}
            assert len(grid) == 18, (arm, controller)
