"""The JAX control period (hydroarm.model.arm.fast_jax, the GPU path) against the numba BatchedArm.

XLA's compile of the unrolled period takes tens of seconds on a CPU and its CPU execution is slow
(every small operation of the loop body a separate step), so these tests keep one arm (the paper
arm, 6 joints), 2 Gauss points per drag piece and a few periods; the bench files
(bench/gpu/*.npz: the paper arm and the Alpha 5 at the paper's 8 points, 20 periods) are checked
by ``scripts/gpu_plant.py --run`` on the GPU machine.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("jax")

from hydroarm.model.arm.fast import BatchedArm  # noqa: E402
from hydroarm.model.arm.fast_export import export_constants  # noqa: E402
from hydroarm.model.arm.fast_jax import check_constants, make_period  # noqa: E402
from hydroarm.model.dynamics.integrator import inner_steps  # noqa: E402
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides  # noqa: E402

PERIOD = 0.01
SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "gpu_plant.py"


def _plant(**overrides):
    settings = {"arm": "paper", "plant.compiled": True, "plant.drag_points": 2, **overrides}
    return build_experiment(with_overrides(ExperimentConfig(), settings), None)


def _copies(experiment, count, seed=3):
    rng = np.random.default_rng(seed)
    n = experiment.arm.n_joints
    x = experiment.x0 + rng.uniform(-0.2, 0.2, (count, 2 * n))
    tau = 0.2 * np.asarray(experiment.arm.torque_limit) * rng.uniform(-1, 1, (count, n))
    return x, tau


def _relative(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.max(np.abs(a - b), axis=1) / np.max(np.abs(b), axis=1)))


def test_jax_period_equals_numba_with_friction_and_current():
    """Every term on (water strips, buoyancy, axial drag, added mass, the paper's current, the
    joint friction model and the viscous friction): state, disturbance and first-stage disturbance
    after one period, the state after five, each within 1e-12 of the numba kernel's, per copy."""
    experiment = _plant(**{"friction.scale": 1.0, "plant.friction": 0.3})
    fast = experiment.plant.fast
    constants = export_constants(fast)
    assert bool(constants["friction_on"]) and float(constants["uniform"]) == 0.3
    assert np.any(constants["current_joint"][0] != 0.0) and np.all(constants["switches"][:4] == 1)
    x, tau = _copies(experiment, 3)
    steps, h = inner_steps(PERIOD, experiment.plant.inner_step)
    period = make_period(constants, steps, h)
    batch = BatchedArm(fast)
    times = np.array([0.0, 0.37, 1.2])  # different times per copy: the current's phase differs
    jax_out = period(times, x, tau)
    numba_out = batch.step(times, x, tau, PERIOD, experiment.plant.inner_step)
    for ours, theirs in zip(jax_out, numba_out, strict=True):
        assert _relative(ours, theirs) <= 1e-12
    state_jax, state_numba = jax_out[0], numba_out[0]
    for k in range(1, 5):
        state_jax = period(times + k * PERIOD, state_jax, tau)[0]
        state_numba = batch.step(times + k * PERIOD, state_numba, tau, PERIOD, experiment.plant.inner_step)[0]
    assert np.all(np.isfinite(state_numba))
    assert _relative(state_jax, state_numba) <= 1e-12


def test_a_dropped_term_shows():
    """The water switched off in the JAX constants only: the period differs from numba's with water
    (so the test above would fail if a term were dropped)."""
    experiment = _plant()
    fast = experiment.plant.fast
    constants = export_constants(fast)
    constants["switches"] = np.zeros(6, dtype=np.int64)
    x, tau = _copies(experiment, 2)
    steps, h = inner_steps(PERIOD, experiment.plant.inner_step)
    dry = make_period(constants, steps, h)(np.zeros(2), x, tau)[0]
    wet = BatchedArm(fast).step(0.0, x, tau, PERIOD, experiment.plant.inner_step)[0]
    assert _relative(dry, wet) > 1e-6


@pytest.mark.parametrize(
    "field, value, match",
    [("switches", [1, 1, 1, 1, 1, 0], "reynolds"), ("switches", [1, 1, 1, 1, 0, 1], "kirchhoff"),
     ("floating", True, "floating")],
)  # fmt: skip
def test_what_it_does_not_model_is_refused(field, value, match):
    constants = export_constants(_plant().plant.fast)
    constants[field] = np.asarray(value)
    with pytest.raises(ValueError, match=match):
        check_constants(constants)


def test_the_gpu_script_runs_small(tmp_path):
    """``scripts/gpu_plant.py``: ``--export`` a tiny file here, ``--run`` it (8 copies, 2 steps)
    with no hydroarm on the path (arm_jax loaded by file path): the check passes, the row is there."""
    data, out = tmp_path / "tiny.npz", tmp_path / "result.json"
    subprocess.run([sys.executable, str(SCRIPT), "--export", str(data), "--arm", "paper", "--drag-points", "2",
                    "--periods", "2", "--reference-copies", "2"], check=True, capture_output=True)  # fmt: skip
    assert data.stat().st_size < 2_000_000
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}  # no PYTHONPATH: only the venv's jax and numpy
    subprocess.run([sys.executable, str(SCRIPT), "--run", str(data), "--copies", "8", "--steps", "2", "--out",
                    str(out)], check=True, capture_output=True, cwd=tmp_path, env=env)  # fmt: skip
    result = json.loads(out.read_text())
    assert result["check"]["after_1"]["state"] <= 1e-12
    assert result["check"]["after_periods"]["state"] <= 1e-12
    assert [row["copies"] for row in result["rows"]] == [8]
    assert result["rows"][0]["finite"] and result["rows"][0]["copy_steps_per_s"] > 0


def test_the_bench_files_are_small_and_complete():
    """bench/gpu/*.npz (what the lead runs on the GPU machine): under 2 MB, every constant there."""
    for name in ("paper", "alpha5"):
        path = SCRIPT.parents[1] / "bench" / "gpu" / f"{name}.npz"
        assert path.stat().st_size < 2_000_000
        data = np.load(path, allow_pickle=False)
        check_constants({k[2:]: data[k] for k in data.files if k.startswith("c_")})
        assert json.loads(str(data["meta"]))["arm"] == name
