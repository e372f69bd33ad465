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
from hydroarm.model.arm.plant import PlantConfig
from hydroarm.model.dynamics.integrator import INNER_STEP_RANGE
from hydroarm.model.vehicle.fast import FastUVMSConfig
from hydroarm.model.vehicle.plant import UVMSPlantConfig
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
    from hydroarm.model.water.morison import Water

    for model, name in ((Water, "rho"), (ReplayConfig, "water_density")):
        field = model.model_fields[name]
        low = next(item.gt for item in field.metadata if getattr(item, "gt", None) is not None)
        high = next(item.le for item in field.metadata if getattr(item, "le", None) is not None)
        assert (low, high) == (0.0, 2000.0) and field.description.endswith("(kg/m^3)")


# --- the plant mismatch: a section of the settings ------------------------------------------------


def test_the_mismatch_is_a_validated_section_with_its_ranges():
    from hydroarm.sim.mismatch import Mismatch

    assert with_overrides(ExperimentConfig(), {"mismatch.mass_scale": 0.8}).mismatch == Mismatch(mass_scale=0.8)
    for key, value, words in (("mismatch.mass_scale", 0.0, "greater than 0"), ("mismatch.payload_kg", -1.0, ">= 0")):
        with pytest.raises(ConfigError) as error:
            with_overrides(ExperimentConfig(), {key: value})
        assert f"settings: {key} = {value!r}" in str(error.value) and "\n" not in str(error.value)
        assert words in str(error.value) or "greater than or equal to 0" in str(error.value)
    with pytest.raises(ConfigError, match="mismatch.mass_scale = 0.8: not used on a vehicle run"):
        with_overrides(ExperimentConfig(), {"vehicle.name": VEHICLE, "mismatch.mass_scale": 0.8})


def test_a_settings_file_mismatch_and_set_give_the_same_run(tmp_path):
    """--set mismatch.mass_scale=0.8 (split off by the CLI before), the same in a --config file's
    [mismatch], and the plant built on perturbed_arm by hand: the same torques, bit for bit; a
    mismatch away from its defaults names the run (its digest), none leaves the digest as it was."""
    import numpy as np

    from hydroarm.model.arm.loading import load_arm
    from hydroarm.sim.mismatch import Mismatch, perturbed_arm
    from hydroarm.sim.runner import Trajectory

    file = tmp_path / "light.toml"
    file.write_text("duration = 0.1\n[mismatch]\nmass_scale = 0.8\n")
    runs = {}
    for label, args in (
        ("set", ["--set", "duration=0.1", "--set", "mismatch.mass_scale=0.8"]),
        ("file", ["--config", str(file)]),
    ):
        result = CliRunner().invoke(app, ["run", "--controller", "smc", *args, "--out", str(tmp_path / label)])
        assert result.exit_code == 0, result.output
        runs[label] = Trajectory.load(tmp_path / label / "trajectory.npz")
    config = with_overrides(ExperimentConfig(duration=0.1), {"mismatch.mass_scale": 0.8})
    arm = load_arm("paper")
    plant_arm = perturbed_arm(arm, Mismatch(mass_scale=0.8))
    by_hand = build_experiment(config.model_copy(update={"mismatch": Mismatch()}), "SMC", arm=arm, plant_arm=plant_arm)
    reference = by_hand.run(0)
    for traj in runs.values():
        np.testing.assert_array_equal(traj.u, reference.u)
        assert traj.meta["mismatch"]["mass_scale"] == 0.8
    assert config.digest() != ExperimentConfig(duration=0.1).digest()
    assert "mismatch" not in ExperimentConfig().canonical()
    bad = CliRunner().invoke(app, ["run", "--set", "mismatch.mass_scale=0", "--out", str(tmp_path / "bad")])
    assert bad.exit_code == 2 and "mismatch.mass_scale = 0" in bad.output and "Traceback" not in bad.output


def test_a_mismatch_sweep_keeps_its_run_ids():
    """The sweep's [mismatch] and swept mismatch.* now set the settings' section; the run ids are
    the ones made before (pinned: computed with the code before the move)."""
    from hydroarm.studies.sweep import plan_sweep, validate_sweep

    config = validate_sweep(
        {"controllers": ["MPC"], "base": {"duration": 0.3}, "mismatch": {"payload_kg": 0.5},
         "parameters": {"mismatch.mass_scale": [1.0, 2.0]}}
    )  # fmt: skip
    plan = plan_sweep(config)
    assert [row.id for row in plan.rows] == ["mpc__seed0__0abce41b7399831c", "mpc__seed0__6a8fc91115670926"]
    assert [row.config.mismatch.mass_scale for row in plan.rows] == [1.0, 2.0]
    assert all(row.config.mismatch.payload_kg == 0.5 for row in plan.rows)
    with pytest.raises(ConfigError, match="give it once"):
        plan_sweep(validate_sweep({"controllers": ["MPC"], "base": {"mismatch": {"payload_kg": 0.1}},
                                   "mismatch": {"payload_kg": 0.5}}))  # fmt: skip


def test_gp_and_vehicle_gp_each_reach_their_own_learner():
    """Two GPs on a vehicle run: the arm controller's (GP-MPC) reads `gp`, the station keeper's
    feed-forward (vehicle.aware) reads `vehicle.gp`; neither setting reaches the other learner."""
    config = with_overrides(
        ExperimentConfig(duration=0.1),
        {"vehicle.name": VEHICLE, "arm": "mount", "vehicle.aware": True, "gp.window": 17, "vehicle.gp.window": 23},
    )
    controller = build_experiment(config, "GP-MPC").controller
    assert controller.gp.config.window == 23
    arm_gps = [c.gp for c in _chain(controller.arm_controller) if hasattr(c, "gp")]
    assert arm_gps and all(gp.config.window == 17 for gp in arm_gps)


def _chain(controller):
    """A controller and those it wraps (an estimator or observer wrapper's ``inner``)."""
    out = [controller]
    while hasattr(out[-1], "inner"):
        out.append(out[-1].inner)
    return out


# --- one system per run: every key the other system alone reads is refused ---------------------


def _leaves(prefix: str) -> list[str]:
    from hydroarm.config import dotted_keys, leaf_keys

    keys = leaf_keys(dotted_keys(ExperimentConfig))
    return [k for k in keys if k == prefix or k.startswith(prefix + ".")]


def _a_valid_change(key: str, base: dict):
    """A value of ``key`` away from its default that the system of ``base`` accepts, or None."""
    default = with_overrides(ExperimentConfig(), base)
    for part in key.split("."):
        default = getattr(default, part)
    candidates = (
        [not default] if isinstance(default, bool)
        else [default + 1, 2 * default, default / 2, default + 0.1] if isinstance(default, (int, float))
        else [[v * 1.1 + 0.1 for v in default]] if isinstance(default, list)
        else ["uniform", "reynolds", "kirchhoff", "mpc", "pid", "encoder", "hold"] if isinstance(default, str)
        else [1, 0.5, 2]
    )  # fmt: skip
    for value in candidates:
        try:
            if isinstance(default, int) and not isinstance(default, bool):
                value = int(value)
            with_overrides(ExperimentConfig(), {**base, key: value})
        except (ConfigError, TypeError, ValueError):
            continue
        if value != default:
            return value
    return None


@pytest.mark.parametrize(("system", "other"), [("fixed arm", {"vehicle.name": VEHICLE}), ("arm on a vehicle", {})])
def test_every_key_one_system_alone_reads_is_refused_on_the_other(system, other):
    """Exhaustive over sim.settings_rules.SYSTEM_ONLY: each key that the system alone reads, set
    to a value its system accepts, fails validation on the other with one line naming the key."""
    from hydroarm.sim.settings_rules import SYSTEM_ONLY

    own = {} if system == "fixed arm" else {"vehicle.name": VEHICLE}
    tried = 0
    for entry in SYSTEM_ONLY[system]:
        for key in _leaves(entry):
            if key == "vehicle.name":
                continue
            value = _a_valid_change(key, own)
            if value is None:
                continue
            tried += 1
            with pytest.raises(ConfigError) as error:
                with_overrides(ExperimentConfig(), {**other, key: value})
            message = str(error.value)
            named = key if not key.startswith("water.current.") else "water.current"
            assert f"settings: {named}" in message and "\n" not in message, (key, message)
    assert tried >= (29 if system == "fixed arm" else 33)  # of 31 and 39 keys (the rest: no simple valid value)


def test_every_torque_limit_is_the_one_setting():
    """The settings', a DH arm file's and a hydrodynamics file's torque_limit: one definition
    (model.arm.TorqueLimit, (0, 1e12] N m); a limit outside it is refused in each."""
    from hydroarm.model.arm.description import TORQUE_LIMIT_MAX, ArmSpec
    from hydroarm.model.arm.hydro_spec import HydroSpec

    for model in (ExperimentConfig, ArmSpec, HydroSpec):
        field = pydantic.TypeAdapter(model.model_fields["torque_limit"].annotation)
        assert field.validate_python(TORQUE_LIMIT_MAX) == TORQUE_LIMIT_MAX  # an arm file's floor was 1e7
        for bad in (2 * TORQUE_LIMIT_MAX, 0.0, [1.0, -1.0]):
            with pytest.raises(pydantic.ValidationError):
                field.validate_python(bad)
    with pytest.raises(ConfigError, match="torque_limit = 0"):
        with_overrides(ExperimentConfig(), {"torque_limit": 0.0})


def test_a_run_folder_made_before_the_move_is_the_same_run():
    """What `hydroarm run` records of its settings in the output folder (to tell a folder of other
    settings): unchanged by the mismatch's move into the settings, with and without one (pinned:
    computed with the code before the move), so re-running into an old folder is not refused."""
    import hashlib
    import json

    from hydroarm.studies.single_run import RunRequest, prepare_run

    def digest(config):
        what = prepare_run(RunRequest(config, "smc")).what
        # the settings added beside and after the move (schema 13 to 17) are not what is pinned
        for key in ("friction_feedforward", "gp_residual", "gp_feedforward_delayed"):
            what["experiment"]["idmpc"].pop(key)
        for key in ("plan_latency", "plan_worker", "planner_budget", "plan_prediction_steps"):
            what["experiment"]["pi_idmpc"].pop(key)
        return hashlib.sha256(json.dumps(what, sort_keys=True).encode()).hexdigest()[:16]

    base = ExperimentConfig(duration=0.1)
    assert digest(base) == "bb11a7888c10b1b1"
    assert digest(with_overrides(base, {"mismatch.mass_scale": 0.8})) == "5b017e799af2b391"


@pytest.mark.parametrize(
    ("overrides", "arm_on", "hull_on"),
    [({}, True, True), ({"vehicle.plant.arm_drag": False}, False, True), ({"water.drag": False}, False, False)],
)
def test_the_arm_drag_on_a_vehicle_is_on_only_where_both_switches_are(overrides, arm_on, hull_on):
    """The precedence table's row: water.drag switches the hull's drag and the arm's,
    vehicle.plant.arm_drag the arm's alone (the floating plant's one place that combines them)."""
    config = with_overrides(ExperimentConfig(duration=0.1), {"vehicle.name": VEHICLE, "arm": "mount", **overrides})
    fast = build_experiment(config, None).plant.fast
    assert fast.geometry.drag is arm_on and fast.water.drag is hull_on  # the hull: vehicle_water(vehicle, water)
