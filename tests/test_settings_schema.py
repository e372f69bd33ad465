"""Settings carry a schema version with migrations (issue 33): run ids made before it are
unchanged, an old run folder and an old settings file load through the migrations, a newer
schema gets one message."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from hydroarm.cli import app
from hydroarm.config import ConfigError, dotted_keys
from hydroarm.sim.experiment import (
    ExperimentConfig,
    load_experiment_config,
    run_experiment,
    run_settings,
    settings_from_record,
    with_overrides,
)
from hydroarm.sim.runner import Trajectory
from hydroarm.sim.settings_schema import MIGRATIONS, SCHEMA, migrate, moved_settings
from hydroarm.studies.sweep.plan import run_id
from hydroarm.studies.sweep.schema import Mismatch

RUNNER = CliRunner()

REAL_LOOP = {"sensor.delay": 2, "sensor.resolution": 0.01, "actuator.delay": 1, "estimator.delay": "plant"}
PLANNER = {"pi_idmpc.planner_hold": 2, "idmpc.delay_margin": 1}

# (settings, controller, seed) -> (digest, sweep run id with arm key "abc"), computed with the
# drop-lists (LATER_KEYS, OPTIONAL_SECTIONS) before the migrations replaced them
PINNED = [
    ({}, "GP-MPC", 0, "9e4e1dee7bcac3f3", "gp-mpc__seed0__ab276dcfdbc69f07"),
    (REAL_LOOP, "GP-MPC", 0, "b253dfa2318af010", "gp-mpc__seed0__89d2b45947f2b953"),
    ({"water.added_mass_model": "kirchhoff", "water.cd": 1.2}, "GP-MPC", 0, "c72ba78a37eec635",
     "gp-mpc__seed0__75280b74999c89f5"),
    (PLANNER, "GP-MPC", 0, "d53a39b56cecdcf8", "gp-mpc__seed0__ab276dcfdbc69f07"),
    ({"plant.compiled": True}, "GP-MPC", 0, "2183b66eaa94ccdd", "gp-mpc__seed0__3b14babf5c7e3a9f"),
    ({"vehicle.name": "bluerov2-heavy"}, "GP-MPC", 0, "4870c8f292d0c606", "gp-mpc__seed0__6043e809903e3019"),
    (PLANNER, "PI-IDMPC", 3, "d53a39b56cecdcf8", "pi-idmpc__seed3__a49ff0ad7301bbae"),
    ({"observer.kind": "ndob"}, "IDMPC", 3, "9c86394ce7f95923", "idmpc__seed3__14ace0c4d1eb445f"),
    (REAL_LOOP, "IDMPC", 3, "b253dfa2318af010", "idmpc__seed3__168551fa0c0d5945"),
]  # fmt: skip


@pytest.mark.parametrize(("overrides", "controller", "seed", "digest", "identifier"), PINNED)
def test_run_ids_and_digests_made_before_the_schema_are_unchanged(overrides, controller, seed, digest, identifier):
    config = with_overrides(ExperimentConfig(), overrides)
    assert config.digest() == digest
    assert run_id(config, controller, seed, Mismatch(), "abc") == identifier


def test_every_migration_names_real_keys_and_fills_todays_default():
    """A key a migration fills (where a record has none) holds today's default: else a run made
    before the key existed would read back as a different run (a default that changes needs a
    migration of its own)."""
    known = set(dotted_keys(ExperimentConfig))
    default = ExperimentConfig()
    assert [m.schema for m in MIGRATIONS] == list(range(2, SCHEMA + 1))
    for migration in MIGRATIONS:
        assert set(migration.sections) <= set(ExperimentConfig.model_fields), migration.what
        for key, value in migration.keys.items():
            section, name = key.split(".")
            assert getattr(getattr(default, section), name) == value, key
        assert set(migration.moved.values()) <= known and not set(migration.moved) & known
    assert moved_settings()["water_model.planner_hold"] == "pi_idmpc.planner_hold"


def test_the_compact_form_reads_back_to_the_same_settings():
    for overrides in ({}, REAL_LOOP, PLANNER, {"plant.compiled": True, "plant.drag_points": 3}):
        config = with_overrides(ExperimentConfig(), overrides)
        for schema in (1, SCHEMA):  # every migration's fill is a no-op on today's compact form
            loaded = settings_from_record({**config.canonical(), "schema": schema}, "run")
            # the same compact form (estimator.acceleration_variance = null is written resolved)
            assert loaded.canonical() == config.canonical() and loaded.digest() == config.digest()


def test_a_saved_run_records_its_schema_and_loads_back(tmp_path):
    config = with_overrides(ExperimentConfig(duration=0.05), {"water.cd": 1.2, "observer.kind": "tde"})
    traj = run_experiment(config, "smc")
    path = traj.save(tmp_path / "run.npz")
    meta = Trajectory.load(path).meta
    assert meta["schema"] == SCHEMA and run_settings(meta, str(path)).canonical() == config.canonical()


def test_an_old_run_folder_loads_through_the_migrations():
    """A PI-IDMPC run saved before the planner's settings moved to ``pi_idmpc`` and before schema
    numbers: its settings name ``water_model.planner_hold``; read as schema 1 they move."""
    config = with_overrides(ExperimentConfig(), PLANNER)
    old = config.canonical()
    old_form = config.canonical()
    planner = old.pop("pi_idmpc")
    old["water_model"] = {**ExperimentConfig().water_model.model_dump(mode="json"), **planner}
    meta = {"settings": old, "digest": config.digest()}  # no "schema": made before it
    loaded = run_settings(meta, "runs/pi-idmpc__seed0.npz")
    assert loaded.canonical() == old_form and loaded.pi_idmpc.planner_hold == 2 and loaded.digest() == meta["digest"]
    with pytest.raises(ConfigError, match="it moved to 'pi_idmpc.planner_hold'"):
        run_settings({**meta, "schema": SCHEMA}, "run")  # today's schema has no such key


def test_an_old_settings_file_loads_through_the_migrations(tmp_path):
    old = tmp_path / "old.toml"
    old.write_text("schema = 7\nduration = 2.0\n[water_model]\nplanner_hold = 2\n")
    config = load_experiment_config(old)
    assert config.pi_idmpc.planner_hold == 2 and config.duration == 2.0
    unversioned = tmp_path / "unversioned.toml"  # read as today's: the moved key gets one message
    unversioned.write_text("[water_model]\nplanner_hold = 2\n")
    with pytest.raises(ConfigError, match="unknown setting 'water_model.planner_hold': it moved to 'pi_idmpc"):
        load_experiment_config(unversioned)
    both = tmp_path / "both.toml"
    both.write_text("schema = 7\n[water_model]\nplanner_hold = 2\n[pi_idmpc]\nplanner_hold = 3\n")
    with pytest.raises(ConfigError, match="water_model.planner_hold .schema 7. moved to pi_idmpc.planner_hold"):
        load_experiment_config(both)


def test_a_newer_schema_gets_one_message(tmp_path):
    newer = tmp_path / "newer.toml"
    newer.write_text(f"schema = {SCHEMA + 1}\nduration = 1.0\n")
    with pytest.raises(ConfigError) as error:
        load_experiment_config(newer)
    assert f"schema = {SCHEMA + 1}: written by a newer hydroarm" in str(error.value)
    assert str(error.value).count("\n") == 0
    result = RUNNER.invoke(app, ["run", "--config", str(newer), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2 and "written by a newer hydroarm" in result.output
    assert "Traceback" not in result.output and not (tmp_path / "out").exists()
    with pytest.raises(ConfigError, match="written by a newer hydroarm"):
        run_settings({"settings": {}, "schema": SCHEMA + 1}, "run")
    for bad in (0, "3", 2.0, True):
        with pytest.raises(ConfigError, match="must be a whole number"):
            settings_from_record({"schema": bad}, "s")


def test_migrations_apply_in_order_and_only_after_the_records_schema():
    data = {"water_model": {"planner_hold": 2}}
    later = {"plan_latency": 0, "plan_worker": "inline", "planner_budget": 0, "plan_prediction_steps": 10}
    assert migrate(data, 7)["pi_idmpc"] == {"planner_hold": 2, **later}  # 13 and 15 filled
    at_8 = migrate(data, 8)  # written at schema 8: water_model.planner_hold is a mistake, not moved
    assert at_8["water_model"] == {"planner_hold": 2}
    assert at_8["pi_idmpc"] == later  # only 13's and 15's keys
    assert migrate(data, 14)["pi_idmpc"] == {"planner_budget": 0, "plan_prediction_steps": 10}
    assert at_8["idmpc"] == {
        "delay_margin": 0,
        "loop_delay": "plant",
        "inertia_margin": 1.5,
        "friction_feedforward": "arm",
        "gp_residual": "rk4",
        "gp_feedforward_delayed": "none",
    }  # 9 to 11, 14, 16 and 17 filled
    assert migrate({}, 1)["estimator"] == {"measures": "plant", "delay": "plant", "repeated": "skip"}


def test_tune_writes_the_schema_and_migrates_an_old_file(tmp_path):
    from hydroarm.studies.tune import write_settings

    path = tmp_path / "tuned.toml"
    path.write_text("schema = 7\n[water_model]\nplanner_hold = 2\n")
    write_settings(path, {"smc.surface_slope": 20.0}, "tuned")
    text = path.read_text()
    assert f"schema = {SCHEMA}" in text and "[pi_idmpc]" in text
    config = load_experiment_config(path)
    assert config.pi_idmpc.planner_hold == 2 and config.smc.surface_slope == 20.0


def test_a_sweep_base_file_of_an_old_schema_is_migrated(tmp_path):
    from hydroarm.studies.sweep import validate_sweep

    base = tmp_path / "base.toml"
    base.write_text("schema = 7\n[water_model]\nplanner_hold = 2\n")
    sweep = validate_sweep({"controllers": ["PI-IDMPC"], "base": "base.toml"}, "s.toml", tmp_path)
    assert sweep.base.pi_idmpc.planner_hold == 2
