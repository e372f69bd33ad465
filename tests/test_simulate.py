"""The closed-loop runner, the trajectory record, metrics and the SMC baseline."""

from __future__ import annotations

import math

import numpy as np
import pytest

import hydroarm
from hydroarm.control.smc import SlidingModeController, SMCConfig
from hydroarm.model.arm.plant import PlantConfig
from hydroarm.sim.runner import Trajectory, run_closed_loop, tracking_metrics


@pytest.fixture(scope="session")
def arm(paper_arm):
    return paper_arm


def test_smc_respects_limits_and_tracks(arm):
    plant = hydroarm.UnderwaterPlant(arm, hydroarm.Water(), PlantConfig(noise_variance=0.001))
    traj = run_closed_loop(plant, SlidingModeController(arm), hydroarm.paper_reference(), 3.0, seed=4)
    assert np.all(np.abs(traj.u) <= arm.torque_limit + 1e-12)
    metrics = tracking_metrics(traj)
    # After the start-up transient the well-tuned SMC holds the reference: steady-state
    # E_p over 2-3 s below 5e-3 rad^2 on every joint (measured: 2.0e-3 on joint 4, the
    # slowest to settle, and <= 5e-4 on the others), against ~1 rad^2 at start-up.
    assert max(metrics["Ep_steady"]) < 5e-3
    assert not metrics["diverged"]


def test_same_seed_same_trajectory_bit_for_bit(arm):
    def run(seed):
        plant = hydroarm.UnderwaterPlant(arm, hydroarm.Water(), PlantConfig(noise_variance=0.001))
        return run_closed_loop(plant, SlidingModeController(arm), hydroarm.paper_reference(), 0.5, seed=seed)

    a, b, c = run(11), run(11), run(12)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.u, b.u)
    assert not np.array_equal(a.y, c.y)


def test_trajectory_save_load_round_trip(arm, tmp_path):
    plant = hydroarm.UnderwaterPlant(arm)
    traj = run_closed_loop(plant, SlidingModeController(arm), hydroarm.paper_reference(), 0.2)
    path = traj.save(tmp_path / "run.npz")
    loaded = Trajectory.load(path)
    np.testing.assert_array_equal(loaded.x, traj.x)
    np.testing.assert_array_equal(loaded.status, traj.status)
    np.testing.assert_array_equal(loaded.timings["total"], traj.timings["total"])
    assert loaded.meta == traj.meta
    assert not (tmp_path / "run.npz.tmp").exists()


def test_metrics_on_a_known_error():
    t = np.arange(400) * 0.01
    n = 2
    q_ref = np.zeros((400, n))
    q = np.zeros((400, n))
    q[:, 0] = 0.1  # constant error 0.1 rad -> Ep 0.01
    q[:, 1] = np.where(t < 1.0, 1.0, 0.0)  # error 1 until 1 s
    traj = Trajectory(
        t=t, x=np.hstack([q, np.zeros_like(q)]), y=np.hstack([q, np.zeros_like(q)]), u=np.ones((400, n)),
        q_ref=q_ref, v_ref=q_ref, disturbance=q_ref, disturbance_estimate=q_ref, disturbance_var=q_ref,
        terminal_violation=np.zeros(400), status=np.array(["ok"] * 400), events=np.array([""] * 400),
    )  # fmt: skip
    metrics = tracking_metrics(traj)
    assert metrics["Ep"][0] == pytest.approx(0.01)
    assert metrics["Ep"][1] == pytest.approx(100 / 400)
    assert metrics["Ep_steady"][1] == 0.0
    assert metrics["time_to_band"][1] == pytest.approx(1.0)
    assert math.isnan(metrics["time_to_band"][0])


def test_divergence_stops_cleanly(arm):
    """A controller that pumps the full torque into the light wrist makes the plant
    exceed the divergence speed: the run stops and says so."""

    class Pump:
        name = "pump"
        control_period = 0.01

        def reset(self):
            pass

        def compute(self, t, y, reference):
            from hydroarm.control.interface import ControlOutput

            return ControlOutput(tau=np.array([0, 0, 0, 0, 0, 500.0]))

        def observe(self, *args):
            pass

    plant = hydroarm.UnderwaterPlant(arm)
    traj = run_closed_loop(plant, Pump(), hydroarm.paper_reference(), 5.0)
    assert traj.diverged
    assert len(traj.t) < 500
    assert np.all(np.isfinite(traj.x))


def test_smc_config_validation(arm):
    with pytest.raises(ValueError, match="switching_gain"):
        SMCConfig(switching_gain=-1.0)
    with pytest.raises(ValueError, match="surface_slope"):
        SlidingModeController(arm, SMCConfig(surface_slope=[1.0, 2.0]))
