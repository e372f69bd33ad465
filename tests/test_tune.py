"""hydroarm tune: the same procedure for every controller, on the dry arm, resumable; settings files."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest

from hydroarm.sim.experiment import ExperimentConfig, load_experiment_config, with_overrides
from hydroarm.studies.tune import DRY, plan_tuning, tune, tuning_grid, write_settings


def test_every_registered_controller_has_a_grid():
    from hydroarm.control.registry import CONTROLLERS

    base = ExperimentConfig()
    for name in CONTROLLERS:
        grid = tuning_grid(base, name)
        assert grid, name
        for key in grid:
            with_overrides(base, {key: grid[key][0]})  # every tuned key is a real setting


def test_plan_is_the_grid_clean_and_noisy_on_the_dry_arm():
    tasks = plan_tuning(ExperimentConfig(), "smc")
    grid = tuning_grid(ExperimentConfig(), "SMC")
    assert len(tasks) == 2 * math.prod(len(v) for v in grid.values())
    assert len({t.id for t in tasks}) == len(tasks)
    for task in tasks:
        water = task.settings["water"]
        assert not (water["drag"] or water["added_mass"] or water["buoyancy"])
        assert water["current"]["model"] == DRY["water.current.model"]
        assert task.settings["plant"]["noise_variance"] == (1e-3 if task.noisy else 0.0)


def test_tune_ranks_by_the_mean_of_clean_and_noisy_and_resumes(tmp_path):
    base = with_overrides(ExperimentConfig(), {"duration": 0.3})
    grid = {"smc.surface_slope": [5.0, 40.0]}
    first = tune(base, "SMC", tmp_path / "runs", workers=0, grid=grid)
    assert [row["point"]["smc.surface_slope"] for row in first.rows] == [
        r["point"]["smc.surface_slope"] for r in first.rows
    ]
    for row in first.rows:
        assert row["score"] == pytest.approx(0.5 * (row["clean"] + row["noisy"]))
    assert first.rows[0]["score"] <= first.rows[1]["score"]
    assert first.best == first.rows[0]["point"]
    files = sorted(p.name for p in (tmp_path / "runs").iterdir())
    assert len(files) == 4
    seen = []
    again = tune(base, "smc", tmp_path / "runs", workers=0, grid=grid, on_progress=lambda d, t, label: seen.append(d))
    assert again.rows == first.rows and seen == [4]  # everything reused, nothing run again


def test_settings_file_merges_and_is_read_back(tmp_path):
    path = tmp_path / "tuned.toml"
    write_settings(path, {"arm": "alpha5", "smc.surface_slope": 20.0, "smc.linear_gain": 10.0}, "first")
    write_settings(path, {"mpc.r": 1e-3, "mpc.q_velocity": 0.01, "smc.surface_slope": 30.0}, "second")
    config = load_experiment_config(path)  # the file carries its schema (schema = N)
    assert config.arm == "alpha5"
    assert (config.smc.surface_slope, config.smc.linear_gain) == (30.0, 10.0)
    assert (config.mpc.r, config.mpc.q_velocity) == (1e-3, 0.01)
    assert path.read_text().startswith("# second") and "schema = " in path.read_text()


@pytest.mark.subprocess
def test_cli_tune_refuses_an_unknown_controller(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "hydroarm.cli", "tune", "--controller", "pid", "--out", str(tmp_path / "t.toml")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert result.returncode == 2 and "controller = 'pid'" in result.stderr
    assert not (tmp_path / "t.toml").exists()


@pytest.mark.slow
@pytest.mark.subprocess
def test_cli_tune_writes_a_settings_file_run_reads(tmp_path):
    out = tmp_path / "tuned.toml"
    cmd = [sys.executable, "-m", "hydroarm.cli"]
    args = [
        "tune",
        "--controller",
        "mpc",
        "--arm",
        "alpha5",
        "--set",
        "duration=0.3",
        "--out",
        str(out),
        "--workers",
        "0",
    ]
    result = subprocess.run([*cmd, *args], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    rows = json.loads((tmp_path / "tuned.toml.json").read_text())["rows"]
    assert len(rows) == 10
    config = load_experiment_config(out)
    assert config.arm == "alpha5" and config.mpc.r == rows[0]["point"]["mpc.r"]
    run = [
        *cmd,
        "run",
        "--controller",
        "mpc",
        "--config",
        str(out),
        "--set",
        "duration=0.2",
        "--out",
        str(tmp_path / "r"),
    ]
    assert subprocess.run(run, capture_output=True, text=True, timeout=300).returncode == 0


@pytest.mark.parametrize("arm", ["paper", "ur5", "alpha5"])
def test_builtin_arms_ship_tuned_settings_that_the_cli_applies(arm):
    from hydroarm.cli import _experiment_config
    from hydroarm.model.arm.loading import tuned_settings_path

    shipped = load_experiment_config(tuned_settings_path(arm))
    assert shipped.arm == arm
    config = _experiment_config(None, [], tuned=True, arm=arm)
    assert (config.smc, config.mpc) == (shipped.smc, shipped.mpc)
    assert config.smc != ExperimentConfig().smc or config.mpc != ExperimentConfig().mpc  # really tuned
    overridden = _experiment_config(None, ["smc.surface_slope=7.0"], tuned=True, arm=arm)
    assert overridden.smc.surface_slope == 7.0  # --set wins over the tuned file


def test_tuned_settings_for_an_arm_without_them_is_a_clear_error():
    from hydroarm.config import ConfigError
    from hydroarm.model.arm.loading import tuned_settings_path

    with pytest.raises(ConfigError, match="no tuned settings ship for arm 'examples/urdf/iiwa14.urdf'"):
        tuned_settings_path("examples/urdf/iiwa14.urdf")
