"""The stress study (examples/stress.toml, docs/robustness.md) in miniature: random initial
states, the robustness table of the sweep summary, fault counts, resuming."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from hydroarm.config import ConfigError, read_mapping
from hydroarm.model.arm.loading import load_arm
from hydroarm.model.arm.plant import UnderwaterPlant
from hydroarm.model.task.references import task_for_arm
from hydroarm.sim.experiment import (
    ExperimentConfig,
    InitialState,
    build_controller,
    run_experiment,
    start_for_arm,
    with_overrides,
)
from hydroarm.sim.runner import run_closed_loop
from hydroarm.studies.executor import SerialExecutor
from hydroarm.studies.sweep import (
    Robustness,
    error_envelope,
    load_sweep,
    plan_sweep,
    run_sweep,
    steady_max_error,
    validate_sweep,
)

ROOT = Path(__file__).resolve().parents[1]
STRESS = ROOT / "examples" / "stress.toml"


def rows_of(path: Path) -> list[dict]:
    with path.open() as handle:
        return list(csv.DictReader(handle))


def tiny_stress(**changes) -> dict:
    """examples/stress.toml with 3 samples of 0.5 s and the bound checked from 0.2 s on."""
    data = read_mapping(STRESS)
    data.update(samples=3, robustness={"max_error": 0.5, "after": 0.2})
    data["base"] = {**data["base"], "duration": 0.5}
    data.update(changes)
    return data


# --- random initial states ---------------------------------------------------------------


@pytest.mark.parametrize("name", ["paper", "alpha5"])
def test_default_initial_state_is_the_task_start_exactly(name):
    arm = load_arm(name)
    config = ExperimentConfig(arm=name)
    reference, x0 = task_for_arm(arm)
    start_reference, start = start_for_arm(arm, config)
    for field in ("offset", "cos_amp", "sin_amp", "omega"):
        assert np.array_equal(getattr(start_reference, field), getattr(reference, field))
    assert start.dtype == x0.dtype and np.array_equal(start, x0)


def test_default_run_is_unchanged_bit_for_bit():
    config = with_overrides(ExperimentConfig(), {"duration": 0.2, "plant.noise_variance": 0.001})
    arm = load_arm("paper")
    reference, x0 = task_for_arm(arm)
    plant = UnderwaterPlant(arm, config.water, config.plant)
    expected = run_closed_loop(plant, build_controller("MPC", arm, config), reference, 0.2, 3, x0=x0)
    got = run_experiment(config, "MPC", 3)
    assert np.array_equal(got.x, expected.x) and np.array_equal(got.u, expected.u)


def test_a_spread_gives_a_deterministic_different_start():
    arm = load_arm("paper")
    spread = {"initial_state.position_spread": 0.5, "initial_state.velocity_spread": 1.0}
    config = with_overrides(ExperimentConfig(), {**spread, "initial_state.seed": 7})
    _, x0 = task_for_arm(arm)
    _, start = start_for_arm(arm, config)
    _, again = start_for_arm(arm, with_overrides(ExperimentConfig(), {**spread, "initial_state.seed": 7}))
    _, other = start_for_arm(arm, with_overrides(ExperimentConfig(), {**spread, "initial_state.seed": 8}))
    assert np.array_equal(start, again) and not np.array_equal(start, other)
    assert not np.array_equal(start, x0)
    assert np.all(np.abs(start[:6] - x0[:6]) <= 0.5) and np.all(np.abs(start[6:] - x0[6:]) <= 1.0)
    # Only the velocities move when only they spread; the draw is the documented one.
    velocity_only = InitialState(velocity_spread=1.0, seed=7).apply(x0)
    rng = np.random.default_rng(7)
    rng.uniform(-0.0, 0.0, 6)
    assert np.array_equal(velocity_only[:6], x0[:6]) and np.array_equal(velocity_only[6:], rng.uniform(-1.0, 1.0, 6))
    # The run starts there.
    traj = run_experiment(with_overrides(config, {"duration": 0.05}), "SMC", 0)
    assert np.array_equal(traj.x[0], start)


def test_initial_state_is_validated():
    with pytest.raises(ConfigError, match="initial_state.position_spread"):
        with_overrides(ExperimentConfig(), {"initial_state.position_spread": -0.1})
    with pytest.raises(ConfigError, match="initial_state.seed"):
        with_overrides(ExperimentConfig(), {"initial_state.seed": -1})


def test_the_environment_starts_from_the_initial_state():
    pytest.importorskip("gymnasium")
    from hydroarm.envs.underwater_arm import UnderwaterArmEnv

    assert np.array_equal(UnderwaterArmEnv().reset(seed=0)[1]["x"], np.zeros(12))
    config = with_overrides(ExperimentConfig(), {"initial_state.position_spread": 0.3, "initial_state.seed": 4})
    _, info = UnderwaterArmEnv(config=config).reset(seed=0)
    assert np.array_equal(info["x"], config.initial_state.apply(np.zeros(12)))


# --- the bound ---------------------------------------------------------------------------------


def test_the_error_envelope_gives_the_largest_error_from_any_window_start():
    traj = run_experiment(with_overrides(ExperimentConfig(), {"duration": 0.5}), "MPC", 0)
    envelope = error_envelope(traj)
    assert envelope["window_s"] == pytest.approx(0.1) and len(envelope["max_abs_error"]) == 5
    error = np.max(np.abs(traj.q_ref - traj.q), axis=1)
    for after in (0.0, 0.2, 0.4):
        assert steady_max_error(envelope, after) == pytest.approx(error[traj.t >= after - 1e-12].max())
    assert math.isnan(steady_max_error(envelope, 0.5))


def test_robustness_settings_are_validated():
    with pytest.raises(ConfigError, match="robustness.max_error"):
        validate_sweep(tiny_stress(robustness={"max_error": 0.0}))
    with pytest.raises(ConfigError, match="robustness.after"):
        validate_sweep(tiny_stress(robustness={"after": -1.0}))
    assert Robustness().max_error == 0.5


# --- the study in miniature -------------------------------------------------------------------


def check_robustness_adds_up(summary: dict, controllers: list[str], rows_each: int) -> None:
    table = summary["robustness"]["controllers"]
    assert list(table) == controllers
    for entry in table.values():
        assert entry["rows"] == rows_each
        assert entry["within"] + entry["outside"] + entry["stopped"] + entry["unfinished"] == entry["rows"]
        assert entry["stopped"] == sum(entry["stopped_by"].values())
        assert entry["unfinished"] == 0 and entry["finished"] == rows_each


def test_the_stress_file_is_the_documented_study():
    config = load_sweep(STRESS)
    plan = plan_sweep(config, STRESS.parent, str(STRESS))
    assert len(plan.rows) == 800 and len(plan.tasks) == 800 and config.base.duration == 10.0
    starts = {row.config.initial_state for row in plan.rows}
    assert len(starts) == 200 and all(s.position_spread == 0.5 and s.velocity_spread == 1.0 for s in starts)
    for key, (low, high) in {
        "water.current.scale": (0.0, 3.0),
        "plant.noise_variance": (0.0, 0.01),
        "mismatch.mass_scale": (0.7, 1.3),
        "water.cd": (0.5, 1.5),
        "water.cm": (1.0, 3.0),
    }.items():
        values = [row.params[key] for row in plan.rows]
        assert low <= min(values) and max(values) <= high, key


@pytest.mark.slow
def test_stress_sweep_in_miniature_then_resume(tmp_path):
    config = validate_sweep(tiny_stress(), "stress-tiny")
    summary = run_sweep(config, tmp_path, executor=SerialExecutor())
    assert summary["failed"] == [] and summary["ran"] == 12
    check_robustness_adds_up(summary, ["SMC", "MPC", "GP-MPC", "GP-IDMPC"], 3)
    assert summary["robustness"]["bound"] == {"max_error": 0.5, "after": 0.2}
    text = (tmp_path / "summary.md").read_text()
    assert "## Robustness: runs within the tracking bound" in text and "| GP-MPC | 3 |" in text
    assert (tmp_path / "robustness.png").is_file() and summary["plots"]["robustness"] == "robustness.png"
    assert json.loads((tmp_path / "summary.json").read_text())["robustness"]["bound"]["after"] == 0.2
    table = rows_of(tmp_path / "results.csv")
    assert len(table) == 12 and {"within_bound", "steady_max_error", "stopped", "faults_total"} <= set(table[0])
    assert len({r["initial_state.seed"] for r in table}) == 3
    record = json.loads(next((tmp_path / "runs").glob("*.json")).read_text())
    assert isinstance(record["faults"], dict) and record["envelope"]["max_abs_error"]

    # Resuming recomputes nothing; a new bound recomputes nothing either, only the verdicts.
    before = (tmp_path / "results.csv").read_text()
    again = run_sweep(config, tmp_path, executor=SerialExecutor())
    assert again["ran"] == 0 and again["reused"] == 12 and (tmp_path / "results.csv").read_text() == before
    looser = validate_sweep(tiny_stress(robustness={"max_error": 100.0, "after": 0.2}), "stress-tiny")
    third = run_sweep(looser, tmp_path, executor=SerialExecutor())
    assert third["ran"] == 0
    for entry in third["robustness"]["controllers"].values():
        assert entry["within"] == entry["finished"] - entry["stopped"]


def test_stress_corners_run_without_an_exception_escaping(tmp_path):
    """The file's extremes: current 3x, noise variance 10x, C_d and C_m +50 %, masses -30 % and +30 %."""
    corner = {
        "initial_state.seed": [1],
        "water.current.scale": [3.0],
        "plant.noise_variance": [0.01],
        "water.cd": [1.5],
        "water.cm": [3.0],
        "mismatch.mass_scale": [0.7, 1.3],
    }
    data = tiny_stress(mode="grid", parameters=corner)
    data.pop("samples")
    summary = run_sweep(validate_sweep(data, "stress-corner"), tmp_path, executor=SerialExecutor())
    assert summary["failed"] == [] and summary["ran"] == 8
    check_robustness_adds_up(summary, ["SMC", "MPC", "GP-MPC", "GP-IDMPC"], 2)
    table = rows_of(tmp_path / "results.csv")
    for row in table:  # a run that stopped says why, and the count of its faults agrees
        if row["stopped"]:
            assert row["within_bound"] == "False" and int(row[f"faults.{row['stopped']}"]) == 1
        faults = sum(int(row[c]) for c in row if c.startswith("faults."))
        assert faults == int(row["faults_total"])
