"""Adaptive GP-MPC on the true plant, paper task: beats MPC, explains the disturbance, deterministic."""

from __future__ import annotations

import numpy as np
import pytest

import hydroarm
from hydroarm.studies.experiment import ExperimentConfig, run_experiment, with_overrides
from hydroarm.control.gp import GPConfig
from hydroarm.control.gpmpc import GPMPC, GPMPCConfig
from hydroarm.control.mpc import LinearMPC
from hydroarm.studies.runner import run_closed_loop, tracking_metrics


@pytest.fixture(scope="module")
def clean_runs():
    config = ExperimentConfig()
    return {name: run_experiment(config, name, seed=0) for name in ("MPC", "GP-MPC")}


def test_gp_mpc_beats_mpc_on_the_paper_task(clean_runs):
    """10 s, no noise: lower mean E_p, and lower steady-state E_p (t > 2 s) on every joint.

    Joint 6 has next to no disturbance: its cylinder lies on its own axis and the
    paper's current d_6 = 0, so only ~1e-4 N m reaches it through the added-mass
    coupling (joint 1 sees ~100 N m); its steady error still drops with the others'.
    """
    mpc = tracking_metrics(clean_runs["MPC"])
    gp = tracking_metrics(clean_runs["GP-MPC"])
    assert np.mean(gp["Ep"]) < 0.7 * np.mean(mpc["Ep"])  # measured: 0.095 vs 0.199 (-52 %)
    for joint in range(6):
        assert gp["Ep_steady"][joint] < mpc["Ep_steady"][joint], joint
    assert np.max(np.abs(clean_runs["MPC"].disturbance[:, 5])) < 1e-3


def test_gp_estimate_explains_the_disturbance(clean_runs):
    """After 1 s the RMS estimate error is at most 20 % of the disturbance's RMS on joints 1-3."""
    traj = clean_runs["GP-MPC"]
    after = traj.t > 1.0
    error = traj.disturbance_estimate[after] - traj.disturbance[after]
    rms_error = np.sqrt(np.mean(error**2, axis=0))
    rms_disturbance = np.sqrt(np.mean(traj.disturbance[after] ** 2, axis=0))
    for joint in range(3):
        assert rms_error[joint] <= 0.2 * rms_disturbance[joint], (rms_error, rms_disturbance)


def test_torque_limits_and_status(clean_runs):
    arm = hydroarm.load_arm("paper")
    for traj in clean_runs.values():
        assert np.all(np.abs(traj.u) <= arm.torque_limit)
        assert set(np.unique(traj.status)) <= {"ok"}


def test_same_seed_same_trajectory_bit_for_bit():
    config = with_overrides(ExperimentConfig(), {"duration": 1.0, "plant.noise_variance": 0.001})
    a = run_experiment(config, "GP-MPC", seed=5)
    b = run_experiment(config, "GP-MPC", seed=5)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.u, b.u)
    np.testing.assert_array_equal(a.disturbance_estimate, b.disturbance_estimate)


@pytest.mark.parametrize("features", ["state", "state+nominal", "state+torque"])
@pytest.mark.parametrize("feedforward", ["acceleration", "torque"])
def test_every_wiring_runs_and_learns(features, feedforward):
    arm = hydroarm.load_arm("paper")
    plant = hydroarm.UnderwaterPlant(arm)
    controller = GPMPC(arm, LinearMPC(arm), GPConfig(), GPMPCConfig(features=features, feedforward=feedforward))
    traj = run_closed_loop(plant, controller, hydroarm.paper_reference(), 1.5)
    assert controller.gp.n_samples == controller.gp.config.window
    late = traj.t > 1.0
    error = traj.disturbance_estimate[late, 0] - traj.disturbance[late, 0]
    assert np.sqrt(np.mean(error**2)) < 0.3 * np.sqrt(np.mean(traj.disturbance[late, 0] ** 2))


def test_variance_aware_mode_scales_the_feedforward_down():
    arm = hydroarm.load_arm("paper")
    plant = hydroarm.UnderwaterPlant(arm)
    controller = GPMPC(arm, LinearMPC(arm), GPConfig(), GPMPCConfig(variance_aware=True))
    traj = run_closed_loop(plant, controller, hydroarm.paper_reference(), 0.5)
    assert np.all(np.isfinite(traj.disturbance_var[5:]))
    assert np.all(traj.disturbance_var[5:] > 0.0)
