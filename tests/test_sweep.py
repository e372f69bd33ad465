"""Sweeps (hydroarm.studies.sweep): planning and validation, local and Ray execution, resuming,
model mismatch, the results table and the summary."""

from __future__ import annotations

import csv
import importlib.util
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from hydroarm.config import ConfigError
from hydroarm.model.arm.loading import load_arm
from hydroarm.model.arm.plant import UnderwaterPlant
from hydroarm.model.task.references import task_for_arm
from hydroarm.sim.experiment import ExperimentConfig, build_controller, run_experiment, with_overrides
from hydroarm.sim.runner import Trajectory, run_closed_loop, tracking_metrics
from hydroarm.studies.executor import SerialExecutor
from hydroarm.studies.sweep import (
    Mismatch,
    SweepConfig,
    arm_digest,
    load_sweep,
    perturbed_arm,
    plan_sweep,
    run_sweep,
    sample_points,
    summarise,
    validate_sweep,
)

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
SHORT = {"duration": 0.3, "plant": {"noise_variance": 0.001}}


def rows_of(path: Path) -> list[dict]:
    with path.open() as handle:
        return list(csv.DictReader(handle))


def small(**extra) -> SweepConfig:
    data = {"controllers": ["MPC", "GP-MPC"], "seeds": 2, "base": SHORT, "parameters": {"mpc.r": [1e-3, 1e-2]}}
    data.update(extra)
    return validate_sweep(data)


# --- a whole sweep on the local process pool ---------------------------------------------


@pytest.mark.slow
def test_local_sweep_end_to_end_then_rerun_skips_and_recomputes_corrupt(tmp_path):
    calls = []
    out = tmp_path / "out"
    summary = run_sweep(small(), out, workers=2, on_progress=lambda d, t, label: calls.append((d, t)))
    assert summary["rows"] == 8 and summary["runs"] == 8 and summary["ran"] == 8 and summary["failed"] == []
    assert calls[0] == (0, 8) and calls[-1] == (8, 8)
    for name in (
        "sweep.json",
        "results.csv",
        "summary.md",
        "summary.json",
        "ep_boxplot.png",
        "ep_by_mpc_r.png",
        "ep_distribution.png",
    ):
        assert (out / name).is_file(), name
    assert len(list((out / "runs").glob("*.json"))) == 8
    table = rows_of(out / "results.csv")
    assert len(table) == 8
    metrics = {"Ep_mean", "Ep_1", "Ep_6", "torque_rms_mean", "diverged", "step_ms_median"}
    settings = {"arm", "water.cd", "plant.noise_variance", "gp.window", "mismatch.mass_scale"}
    assert {"id", "controller", "seed", "mpc.r"} | metrics | settings <= set(table[0])
    assert {(r["controller"], r["seed"], r["mpc.r"]) for r in table} == {
        (c, s, r) for c in ("MPC", "GP-MPC") for s in ("0", "1") for r in ("0.001", "0.01")
    }
    # The same numbers as `hydroarm run` with those settings, bit for bit.
    config = with_overrides(ExperimentConfig(), {"duration": 0.3, "plant.noise_variance": 0.001, "mpc.r": 0.01})
    expected = tracking_metrics(run_experiment(config, "GP-MPC", 1))["Ep"]
    row = next(r for r in table if r["controller"] == "GP-MPC" and r["seed"] == "1" and r["mpc.r"] == "0.01")
    assert [float(row[f"Ep_{j + 1}"]) for j in range(6)] == expected
    assert summary["controllers"]["GP-MPC"]["finished"] == 4
    assert summary["by_parameter"]["mpc.r"]["groups"]["0.01"]["MPC"]["finished"] == 2
    assert "| MPC | 4 | 4 |" in (out / "summary.md").read_text()

    # Re-running skips every finished run and rewrites the same table.
    before = (out / "results.csv").read_text()
    again = run_sweep(small(), out, executor=SerialExecutor())
    assert again["ran"] == 0 and again["reused"] == 8
    assert (out / "results.csv").read_text() == before

    # A corrupt and a missing run file are recomputed, nothing else.
    files = sorted((out / "runs").glob("*.json"))
    files[0].write_text(files[0].read_text()[:40])
    files[1].unlink()
    third = run_sweep(small(), out, executor=SerialExecutor())
    assert third["ran"] == 2 and third["reused"] == 6
    numbers = lambda path: [(r["id"], r["Ep_mean"], r["Ep_6"], r["rms_mean"]) for r in rows_of(path)]  # noqa: E731
    assert numbers(out / "results.csv") == [(r["id"], r["Ep_mean"], r["Ep_6"], r["rms_mean"]) for r in table]
    assert json.loads(files[0].read_text())["id"] == files[0].stem


def test_runs_that_differ_only_in_another_controllers_settings_are_shared(tmp_path):
    data = {
        "controllers": ["smc", "mpc"],
        "seeds": [3],
        "base": {"duration": 0.1},
        "parameters": {"mpc.r": [1e-3, 1e-2]},
    }
    config = validate_sweep(data)
    plan = plan_sweep(config)
    assert len(plan.rows) == 4 and len(plan.tasks) == 3  # SMC does not read mpc.*
    summary = run_sweep(config, tmp_path, executor=SerialExecutor())
    assert summary["ran"] == 3
    smc = [r for r in rows_of(tmp_path / "results.csv") if r["controller"] == "SMC"]
    assert len(smc) == 2 and smc[0]["id"] == smc[1]["id"] and smc[0]["Ep_mean"] == smc[1]["Ep_mean"]
    assert {r["mpc.r"] for r in smc} == {"0.001", "0.01"}


def test_interrupted_sweep_leaves_a_readable_table_and_resumes(tmp_path):
    class StopAfterTwo(SerialExecutor):
        def map(self, run, tasks, arms, on_step=None):
            for count, item in enumerate(super().map(run, tasks, arms, on_step)):
                if count == 2:
                    raise KeyboardInterrupt
                yield item

    config = small(base={"duration": 0.1})
    with pytest.raises(KeyboardInterrupt):
        run_sweep(config, tmp_path, executor=StopAfterTwo())
    assert len(rows_of(tmp_path / "results.csv")) == 2
    assert not list(tmp_path.rglob("*.tmp"))
    summary = run_sweep(config, tmp_path, executor=SerialExecutor())
    assert summary["reused"] == 2 and summary["ran"] == 6 and len(rows_of(tmp_path / "results.csv")) == 8


def test_a_failed_run_is_reported_and_retried(tmp_path):
    class FailFirst(SerialExecutor):
        def map(self, run, tasks, arms, on_step=None):
            for count, (task, outcome) in enumerate(super().map(run, tasks, arms, on_step)):
                yield task, (RuntimeError("solver exploded") if count == 0 else outcome)

    config = small(base={"duration": 0.1}, seeds=1)
    summary = run_sweep(config, tmp_path, executor=FailFirst())
    assert len(summary["failed"]) == 1 and "solver exploded" in summary["failed"][0]["error"]
    assert (tmp_path / "failed.json").is_file() and "Failed runs" in (tmp_path / "summary.md").read_text()
    assert len(rows_of(tmp_path / "results.csv")) == 3
    again = run_sweep(config, tmp_path, executor=SerialExecutor())
    assert again["ran"] == 1 and again["failed"] == [] and not (tmp_path / "failed.json").exists()


def test_trajectories_are_kept_on_request(tmp_path):
    config = validate_sweep({"controllers": ["MPC"], "base": {"duration": 0.1}, "save_trajectories": True})
    run_sweep(config, tmp_path, executor=SerialExecutor())
    (npz,) = list((tmp_path / "runs").glob("*.npz"))
    traj = Trajectory.load(npz)
    assert traj.meta["id"] == npz.stem and len(traj.t) == 10


# --- random mode ------------------------------------------------------------------------------


def test_random_mode_is_deterministic_for_a_sampling_seed(tmp_path):
    data = {
        "controllers": ["MPC"], "mode": "random", "samples": 14, "sampling_seed": 3, "base": {"duration": 0.05},
        "parameters": {
            "mpc.r": {"low": 1e-4, "high": 1e-1, "log": True},
            "gp.window": {"low": 5, "high": 40, "integer": True},
            "water.current.model": ["paper", "none"],
        },
    }  # fmt: skip
    points = sample_points(validate_sweep(data))
    assert points == sample_points(validate_sweep(data)) and len(points) == 14
    assert points != sample_points(validate_sweep({**data, "sampling_seed": 4}))
    assert all(1e-4 <= p["mpc.r"] <= 1e-1 for p in points)
    assert all(isinstance(p["gp.window"], int) and 5 <= p["gp.window"] <= 40 for p in points)
    assert {p["water.current.model"] for p in points} == {"paper", "none"}
    ids = [r.id for r in plan_sweep(validate_sweep(data)).rows]
    assert ids == [r.id for r in plan_sweep(validate_sweep(data)).rows]
    # More distinct values than boxes: a scatter plot per parameter.
    summary = run_sweep(validate_sweep(data), tmp_path, executor=SerialExecutor())
    assert summary["by_parameter"]["mpc.r"]["grouped"] is False
    assert (tmp_path / "ep_by_mpc_r.png").is_file() and (tmp_path / "ep_by_water_current_model.png").is_file()
    again = summarise(tmp_path, metric="torque_rms_mean")
    assert again["metric"] == "torque_rms_mean" and again["controllers"]["MPC"]["finished"] == 14


def test_grid_ranges_expand():
    parameters = {
        "mpc.r": {"low": 1e-3, "high": 1e-1, "num": 3, "log": True},
        "gp.window": {"low": 5, "high": 6, "num": 4, "integer": True},
    }
    config = validate_sweep({"controllers": ["MPC"], "parameters": parameters})
    points = sample_points(config)
    assert len(points) == 3 * 2
    assert sorted({p["mpc.r"] for p in points}) == pytest.approx([1e-3, 1e-2, 1e-1])
    assert {p["gp.window"] for p in points} == {5, 6}


# --- validation ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"parameters": {"mpc.foo": [1]}}, "parameters.mpc.foo: unknown setting"),
        ({"parameters": {"mismatch.foo": [1]}}, "parameters.mismatch.foo: unknown setting"),
        ({"parameters": {"mpc.r": []}}, "parameters.mpc.r: empty list"),
        ({"parameters": {"mpc.r": 0.1}}, "parameters.mpc.r = 0.1: give a list"),
        ({"parameters": {"mpc.r": {"low": 2.0, "high": 1.0, "num": 2}}}, "high (1.0) < low (2.0)"),
        ({"parameters": {"mpc.r": {"low": 1.0, "high": 2.0}}}, "parameters.mpc.r: a range in grid mode needs num"),
        ({"parameters": {"mpc.r": [0.1, -1.0]}}, "parameters (mpc.r = -1): mpc.r"),
        ({"parameters": {"mismatch.mass_scale": [0.0]}}, "mass_scale = 0.0"),
        ({"parameters": {"arm": ["paper", "no/such/arm.toml"]}}, "arm 'no/such/arm.toml'"),
        ({"controllers": ["MPC", "PID"]}, "controllers.1 = 'PID'"),
        ({"controllers": []}, "controllers = []"),
        ({"controllers": ["MPC", "mpc"]}, "controllers: a controller is listed twice"),
        ({"bogus": 1}, "unknown key 'bogus'"),
        ({"base": {"mpc": {"horizon": 0}}}, "base.mpc.horizon = 0"),
        ({"seeds": 0}, "seeds"),
        ({"mode": "random"}, "samples: missing"),
        ({"samples": 3}, "samples: only for mode = 'random'"),
    ],
)
def test_validation_names_the_field(change, message):
    data = {"controllers": ["MPC"], "parameters": {"mpc.r": [0.01]}}
    data.update(change)
    with pytest.raises(ConfigError) as error:
        plan_sweep(validate_sweep(data, "s.toml"), source="s.toml")
    assert message in str(error.value)
    assert str(error.value).startswith("s.toml")


def test_sweep_file_dotted_keys_relative_arm_and_base_file(tmp_path):
    shutil.copy(EXAMPLES / "myarm.toml", tmp_path / "arm.toml")
    (tmp_path / "experiment.toml").write_text("duration = 0.2\n[mpc]\nhorizon = 5\n")
    (tmp_path / "s.toml").write_text(
        'controllers = ["gp-mpc"]\nbase = "experiment.toml"\n'
        '[parameters]\nmpc.r = [0.01]\narm = ["arm.toml", "paper"]\n'
    )
    config = load_sweep(tmp_path / "s.toml")
    assert config.base.duration == 0.2 and config.base.mpc.horizon == 5 and config.controllers == ["GP-MPC"]
    assert list(config.parameters) == ["mpc.r", "arm"]
    plan = plan_sweep(config, tmp_path)
    assert len(plan.arms) == 2 and {r.config.arm for r in plan.rows} == {"arm.toml", "paper"}
    # The arm's content, not its path, is in the run id: a copy elsewhere gives the same ids,
    # an edited arm new ones.
    other = tmp_path / "elsewhere"
    other.mkdir()
    shutil.copy(tmp_path / "s.toml", other / "s.toml")
    shutil.copy(tmp_path / "arm.toml", other / "arm.toml")
    (other / "experiment.toml").write_text((tmp_path / "experiment.toml").read_text())
    assert [r.id for r in plan_sweep(load_sweep(other / "s.toml"), other).rows] == [r.id for r in plan.rows]
    (other / "arm.toml").write_text((other / "arm.toml").read_text().replace("mass = 3.0", "mass = 3.1"))
    changed = [r.id for r in plan_sweep(load_sweep(other / "s.toml"), other).rows]
    assert changed[0] != plan.rows[0].id and changed[1] == plan.rows[1].id


def test_examples_are_valid():
    for name in ("sweep.toml", "sweep_random.toml", "stress.toml"):
        path = EXAMPLES / name
        plan = plan_sweep(load_sweep(path), path.parent, str(path))
        assert plan.rows
    assert load_arm(str(EXAMPLES / "myarm.toml")).n_joints == 3
    urdf = load_arm(str(EXAMPLES / "urdf" / "myarm.urdf"))
    assert urdf.n_joints == 3 and urdf.position_limit is not None
    assert arm_digest(urdf) == arm_digest(load_arm(str(EXAMPLES / "urdf" / "myarm.hydro.toml")))


# --- model mismatch -----------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["paper", "alpha5"])
def test_perturbed_arm_scales_the_plant_masses_only(name):
    arm = load_arm(name)
    q = np.linspace(0.1, 0.6, arm.n_joints)
    assert perturbed_arm(arm, Mismatch()) is arm
    heavy = perturbed_arm(arm, Mismatch(mass_scale=1.5))
    np.testing.assert_allclose(heavy.mass_matrix(q), 1.5 * arm.mass_matrix(q), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(heavy.gravity(q), 1.5 * arm.gravity(q), rtol=1e-12, atol=1e-12)
    assert heavy.cylinders == arm.cylinders
    loaded = perturbed_arm(arm, Mismatch(payload_kg=2.0))
    masses = lambda a: sum(i.mass for i in a.model.inertias)  # noqa: E731
    assert masses(loaded) == pytest.approx(masses(arm) + 2.0)
    assert not np.allclose(loaded.gravity(q), arm.gravity(q))
    assert masses(load_arm(name)) == masses(arm)  # the nominal arm is untouched


def test_mismatch_sweep_runs_the_perturbed_plant_with_the_nominal_controller(tmp_path):
    config = validate_sweep({"controllers": ["MPC"], "base": SHORT, "parameters": {"mismatch.mass_scale": [1.0, 2.0]}})
    run_sweep(config, tmp_path, executor=SerialExecutor())
    rows = {r["mismatch.mass_scale"]: r for r in rows_of(tmp_path / "results.csv")}
    assert rows["1.0"]["Ep_mean"] != rows["2.0"]["Ep_mean"]
    experiment = with_overrides(ExperimentConfig(), {"duration": 0.3, "plant.noise_variance": 0.001})
    nominal = load_arm("paper")
    # No mismatch: exactly `hydroarm run`.
    assert float(rows["1.0"]["Ep_1"]) == tracking_metrics(run_experiment(experiment, "MPC", 0))["Ep"][0]
    # Mass x2: the plant's arm is heavy, the controller's the arm file.
    plant = UnderwaterPlant(perturbed_arm(nominal, Mismatch(mass_scale=2.0)), experiment.water, experiment.plant)
    reference, x0 = task_for_arm(nominal)
    traj = run_closed_loop(plant, build_controller("MPC", nominal, experiment), reference, 0.3, 0, x0=x0)
    assert float(rows["2.0"]["Ep_1"]) == tracking_metrics(traj)["Ep"][0]


# --- Ray --------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.ray
@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="ray is not installed (pip install hydroarm[ray])")
def test_ray_sweep_end_to_end_matches_the_local_one(tmp_path, monkeypatch):
    import ray

    monkeypatch.setenv("RAY_USAGE_STATS_ENABLED", "0")
    config = small(seeds=1)
    local = run_sweep(config, tmp_path / "local", executor=SerialExecutor())
    remote = run_sweep(config, tmp_path / "ray", workers=2, ray_address="local")
    assert not ray.is_initialized()  # the instance it started is shut down
    assert remote["ran"] == 4 and remote["failed"] == []
    key = lambda r: (r["id"], r["Ep_mean"], r["Ep_1"], r["torque_rms_mean"])  # noqa: E731
    assert sorted(map(key, rows_of(tmp_path / "ray" / "results.csv"))) == sorted(
        map(key, rows_of(tmp_path / "local" / "results.csv"))
    )
    assert local["controllers"] == remote["controllers"]
    # A re-run through Ray finds everything finished and starts no Ray instance.
    assert run_sweep(config, tmp_path / "ray", ray_address="local")["ran"] == 0
