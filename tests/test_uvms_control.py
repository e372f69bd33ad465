"""Station keeping of the UVMS: allocation, the controllers, the GP feed-forward, the study,
the env and the CLI's vehicle commands."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings

import numpy as np
import pytest

from hydroarm.control.vehicle_control import ThrusterAllocation, pose_error
from hydroarm.model.vehicle.description import load_vehicle
from hydroarm.sim.experiment import ExperimentConfig, build_experiment
from hydroarm.sim.vehicle import VehicleRun


def vehicle_run(duration: float, controller: str = "smc", **vehicle) -> dict:
    """The station-keeping metrics of a run of the BlueROV2 Heavy with its Alpha 5."""
    config = ExperimentConfig(arm="mount", duration=duration, vehicle=VehicleRun(name="bluerov2_heavy", **vehicle))
    return build_experiment(config, controller).run()


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("bluerov2_heavy")


def test_allocation_is_exact_within_limits_and_saturates_otherwise(vehicle):
    allocation = ThrusterAllocation(vehicle)
    wrench = np.array([10.0, -5.0, 8.0, 0.5, -0.3, 0.2])
    thrust, saturated = allocation.allocate(wrench)
    assert not saturated and np.allclose(vehicle.allocation @ thrust, wrench, atol=1e-9)
    big = np.array([400.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    thrust, saturated = allocation.allocate(big)
    assert saturated
    assert np.all(thrust <= vehicle.thrust_max + 1e-9) and np.all(thrust >= vehicle.thrust_min - 1e-9)
    assert (vehicle.allocation @ thrust)[0] > 0.9 * allocation.wrench_limit[0]  # as far as the thrusters reach


def test_pose_error_is_body_frame():
    q = np.array([1.0, 2.0, 3.0, 0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)])  # yaw 90 deg
    target = np.array([2.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0])
    error = pose_error(q, target)
    assert np.allclose(error[:3], [0.0, -1.0, 0.0]) and np.allclose(error[3:], [0.0, 0.0, -np.pi / 2])


def test_vehicle_mpc_predicts_what_the_plant_does_under_the_restoring_feed_forward(vehicle):
    """From 0.1 rad of roll at rest, the MPC's wrench with no correction is the restoring
    feed-forward alone; the vehicle's own equations (weight at the centre of gravity, buoyancy
    at the centre of buoyancy, Fossen's water terms at rest) then give no acceleration, so the
    prediction one step ahead must stay at rest. Counting the restoring stiffness in the model
    as well predicted -0.0146 rad/s of roll rate after 50 ms."""
    from hydroarm.control.vehicle_control import VehicleMPC, restoring_wrench
    from hydroarm.model.vehicle.description import vehicle_generalised_force

    mpc = VehicleMPC(vehicle)
    roll = 0.1
    rot = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(roll), -np.sin(roll)], [0.0, np.sin(roll), np.cos(roll)]])
    wrench = -restoring_wrench(vehicle, rot)  # what compute() commands with no deviation
    g = 9.81
    weight = rot.T @ np.array([0.0, 0.0, -vehicle.mass * g])
    gravity = np.concatenate([weight, np.cross(vehicle.cg, weight)])
    water = vehicle_generalised_force(
        np.zeros(6), rot, np.zeros(3), vehicle.added_mass, vehicle.linear_damping, vehicle.quadratic_damping,
        1000.0 * g * vehicle.displaced_volume, vehicle.cb, True, True, True,
    )  # fmt: skip
    plant_acceleration = np.linalg.solve(mpc.inertia, wrench + gravity + water)
    assert np.max(np.abs(plant_acceleration)) < 1e-12
    state = np.concatenate([[0.0, 0.0, 0.0, roll, 0.0, 0.0], np.zeros(6)])  # pose deviation = -error
    predicted = mpc.ad @ state  # no deviation wrench
    assert np.max(np.abs(predicted[6:])) < 1e-12, predicted[6:]


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["pid", "mpc"])
def test_gp_feed_forward_beats_the_blind_controller(kind):
    blind = vehicle_run(6.0, control={"kind": kind}).meta["metrics"]
    aware = vehicle_run(6.0, control={"kind": kind}, aware=True).meta["metrics"]
    assert blind["drift_max_m"] < 0.1 and aware["drift_rms_m"] < 0.5 * blind["drift_rms_m"]


def test_short_run_holds_station():
    traj = vehicle_run(1.5)
    metrics = traj.meta["metrics"]
    assert np.all(np.isfinite(traj.x)) and np.all(np.isfinite(traj.meta["final_state"]))
    assert metrics["drift_max_m"] < 0.05 and traj.meta["stopped"] is None
    assert set(metrics) >= {"drift_rms_m", "attitude_rms_deg", "saturation_time_s", "ee_error_rms_m"}
    assert traj.extra["thrust_command"].shape == (150, 8) and traj.extra["saturated"].dtype == bool


def test_learning_arm_controllers_run_on_the_vehicle_and_report_the_gp_events():
    """Any registry controller drives the arm on the vehicle (GP-IDMPC here, behind its Kalman
    filter on the true state), through the one runner: its faults are counted, none stop it."""
    traj = vehicle_run(0.5, "gp-idmpc", aware=True)
    assert traj.meta["stopped"] is None, traj.meta["error"]
    assert traj.meta["controller"] == "GP-IDMPC+KF+PID+GP"
    assert np.all(np.isfinite(traj.disturbance_estimate[5:]))  # the arm's GP estimate is recorded
    assert set(traj.meta["faults"]) >= {"gp_jittered", "diverged"}


@pytest.mark.slow
def test_quick_study_writes_its_outputs(tmp_path, monkeypatch):
    from hydroarm.studies import vehicle_study

    monkeypatch.setattr(vehicle_study, "study_tasks", lambda duration: vehicle_study.__dict__["_tasks"](2.0))
    metrics = vehicle_study.run_vehicle_study(tmp_path, quick=True, workers=0)
    assert (tmp_path / "report.md").is_file() and (tmp_path / "fig_x.png").is_file()
    on_disk = json.loads((tmp_path / "metrics.json").read_text())
    assert set(on_disk["effects"]) == set(vehicle_study.EFFECTS) and on_disk["effect_ranking_by_drift"]
    assert metrics["gp_gain_percent"]["pid"]["drift_rms_m"] == on_disk["gp_gain_percent"]["pid"]["drift_rms_m"]


def test_env_passes_check_env_and_is_seeded():
    gymnasium = pytest.importorskip("gymnasium")
    from gymnasium.utils.env_checker import check_env

    import hydroarm.envs  # noqa: F401  (registers the ids)

    env = gymnasium.make("hydroarm/UVMS-v0", duration=0.2).unwrapped
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning: finite observation bounds (issue 24)
        check_env(env, skip_render_check=True)
    assert np.all(np.isfinite(env.observation_space.high))

    def episode(seed):
        obs, _ = env.reset(seed=seed)
        out = [obs]
        for k in range(10):
            obs, *_ = env.step(np.full(8, 0.1 * np.sin(k)))
            out.append(obs)
        return np.array(out)

    assert np.array_equal(episode(5), episode(5)) and not np.array_equal(episode(5), episode(6))


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "hydroarm.cli", *args], capture_output=True, text=True, timeout=120)


@pytest.mark.subprocess
def test_cli_lists_vehicles_and_rejects_bad_vehicle_files(tmp_path):
    listed = _cli("vehicles", "--json")
    assert listed.returncode == 0 and json.loads(listed.stdout)[0]["name"] == "bluerov2-heavy"
    from hydroarm.model.vehicle.description import builtin_vehicle_path

    text = builtin_vehicle_path("bluerov2_heavy").read_text()
    cases = {
        "mass": text.replace("mass = 13.5 ", "mass = -1.0 "),
        "allocation": text.replace("[hull]", "allocation = [[1, 2, 3], [1, 2, 3]]\n\n[hull]"),
        "ballast.0.mass": text + "\n[[ballast]]\nmass = 0.0\nvolume = 1e-4\nposition = [0.0, 0.0, 0.0]\n",
        "thrusters.4.axis": text.replace("axis = [0.0, 0.0, 1.0]", "axis = [0.0, 0.0, 0.0]", 1),
    }
    for field, content in cases.items():
        path = tmp_path / f"bad_{field}.toml"
        path.write_text(content)
        result = _cli("run", "--vehicle", str(path), "--set", "duration=0.1", "--out", str(tmp_path / "out"))
        assert result.returncode == 2, (field, result.stderr)
        assert field in result.stderr and "Traceback" not in result.stderr
    ok = _cli("run", "--vehicle", "bluerov2-heavy", "--arm", "alpha5", "--set", "duration=0.2", "--json",
              "--out", str(tmp_path / "ok"))  # fmt: skip
    assert ok.returncode == 0 and "drift_rms_m" in ok.stdout
