"""Torque limits are never exceeded (issue 7, item 3): every controller, any seed,
disturbance, noise level, limit and start, hypothesis drawing the cases."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import hydroarm
from hydroarm.control.gp import GPConfig
from hydroarm.control.mpc import MPCConfig
from hydroarm.model.arm.plant import PlantConfig, UnderwaterPlant
from hydroarm.model.water.morison import CurrentConfig, Water
from hydroarm.sim.experiment import ExperimentConfig, build_controller
from hydroarm.sim.runner import run_closed_loop

UR5_LIMITS = [150.0, 150.0, 150.0, 28.0, 28.0, 28.0]


@pytest.fixture(scope="module")
def arm():
    return hydroarm.load_arm("paper")


limits = st.one_of(
    st.floats(5.0, 500.0),  # one limit for every joint; 5 N m saturates nearly always
    st.just(UR5_LIMITS),
    st.lists(st.floats(5.0, 500.0), min_size=6, max_size=6),
)

cases = st.fixed_dictionaries(
    {
        "controller": st.sampled_from(["SMC", "MPC", "GP-MPC"]),
        "seed": st.integers(0, 2**31 - 1),
        "current_scale": st.floats(0.0, 3.0),
        "noise_variance": st.sampled_from([0.0, 1e-4, 1e-3, 1e-2]),
        "cd": st.floats(0.5, 1.5),
        "cm": st.floats(1.0, 3.0),
        "limit": limits,
        "start_offset": st.lists(st.floats(-1.0, 1.0), min_size=12, max_size=12),
        "r": st.sampled_from([0.1, 1e-3]),
    }
)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=cases)
@pytest.mark.slow
def test_no_controller_ever_exceeds_its_torque_limit(arm, case):
    """100 random closed loops of 0.3 s (the start-up, where the torques saturate most)."""
    config = ExperimentConfig(
        water=Water(cd=case["cd"], cm=case["cm"], current=CurrentConfig(scale=case["current_scale"])),
        plant=PlantConfig(noise_variance=case["noise_variance"]),
        torque_limit=case["limit"],
        mpc=MPCConfig(r=case["r"]),
        gp=GPConfig(),
    )
    controller = build_controller(case["controller"], arm, config)
    plant = UnderwaterPlant(arm, config.water, config.plant)
    x0 = np.asarray(case["start_offset"])
    traj = run_closed_loop(plant, controller, hydroarm.paper_reference(), 0.3, seed=case["seed"], x0=x0)
    limit = np.broadcast_to(np.asarray(case["limit"], dtype=float), (6,))
    assert traj.meta["faults"]["controller_error"] == 0
    assert np.all(np.isfinite(traj.u))
    assert np.all(np.abs(traj.u) <= limit), np.max(np.abs(traj.u) / limit)
