"""Same seed and settings, bit-identical results across two processes (issue 7, item 6).

Two fresh interpreters (different hash seeds, so nothing may depend on set or dict
order of strings) run every controller on the noisy plant in a doubled current
and save their trajectories; every array must be equal bit for bit.
"""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from hydroarm.sim.runner import Trajectory

pytestmark = [pytest.mark.subprocess]

SCRIPT = r"""
import sys
from hydroarm.sim.experiment import ExperimentConfig, run_experiment, with_overrides

config = with_overrides(ExperimentConfig(), {
    "duration": 1.5, "plant.noise_variance": 1e-3, "water.current.scale": 2.0,
})
for name in ("SMC", "MPC", "GP-MPC"):
    run_experiment(config, name, seed=11).save(f"{sys.argv[1]}/{name}.npz")
"""

ARRAYS = ("x", "y", "u", "disturbance", "disturbance_estimate", "disturbance_var", "terminal_violation")


def run_in_fresh_process(folder, hash_seed: str) -> None:
    env = dict(os.environ, PYTHONHASHSEED=hash_seed, MPLBACKEND="Agg")
    subprocess.run([sys.executable, "-c", SCRIPT, str(folder)], check=True, env=env, timeout=600)


@pytest.mark.slow
def test_two_processes_give_bit_identical_runs(tmp_path):
    first, second = tmp_path / "first", tmp_path / "second"
    first.mkdir()
    second.mkdir()
    run_in_fresh_process(first, "1")
    run_in_fresh_process(second, "2")
    for name in ("SMC", "MPC", "GP-MPC"):
        a, b = Trajectory.load(first / f"{name}.npz"), Trajectory.load(second / f"{name}.npz")
        assert len(a.t) == 150
        for field in ARRAYS:
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=f"{name}.{field}")
        np.testing.assert_array_equal(a.status, b.status)
        np.testing.assert_array_equal(a.events, b.events)
        assert a.meta["faults"] == b.meta["faults"]
    # the noise did act: the measurement differs from the true state
    assert np.std(a.y - a.x) > 0.01
