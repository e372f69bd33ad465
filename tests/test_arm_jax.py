"""The JAX control period (hydroarm.model.arm.fast_jax, the GPU path) against the numba BatchedArm.

XLA's compile of the unrolled period takes tens of seconds on a CPU and its CPU execution is slow
(every small operation of the loop body a separate step), so these tests keep one arm (the paper
arm, 6 joints), 2 Gauss points per drag piece and a few periods; the bench files
(bench/gpu/*.npz: the paper arm and the Alpha 5 at the paper's 8 points, 20 periods) are checked
by ``scripts/gpu_plant.py --run`` on the GPU machine.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("jax")

from hydroarm.model.arm.fast import BatchedArm  # noqa: E402
from hydroarm.model.arm.fast_export import export_constants  # noqa: E402
from hydroarm.model.arm.fast_jax import check_constants  # noqa: E402
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides  # noqa: E402

PERIOD = 0.01
SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "gpu_plant.py"


PAPER = Path(__file__).resolve().parents[1] / "src" / "hydroarm" / "arms" / "paper.toml"


@pytest.fixture(scope="module")
def axial_arm(tmp_path_factory):
    """The paper arm with an axial drag coefficient on every cylinder (the built-in arms give none,
    so the axial term would be zero and unchecked)."""
    path = tmp_path_factory.mktemp("arm") / "paper_axial.toml"
    lines = [line + ("\ncd_axial = 0.8" if line.startswith("buoyancy_kg") else "") for line in
             PAPER.read_text().splitlines()]  # fmt: skip
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def _plant(arm="paper", **overrides):
    settings = {"arm": arm, "plant.compiled": True, "plant.drag_points": 2, **overrides}
    return build_experiment(with_overrides(ExperimentConfig(), settings), None)


def _copies(experiment, count, seed=0):
    """The copies ``scripts/gpu_plant.py --export`` checks: the start moved by U(-0.1, 0.1), torques
    U(-0.1, 0.1) x the limits, start times 0.37 s apart."""
    rng = np.random.default_rng(seed)
    n = experiment.arm.n_joints
    x = experiment.x0 + rng.uniform(-0.1, 0.1, (count, 2 * n))
    tau = 0.1 * np.asarray(experiment.arm.torque_limit) * rng.uniform(-1, 1, (count, n))
    return x, tau, 0.37 * np.arange(count)


def _relative(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.max(np.abs(a - b), axis=1) / np.max(np.abs(b), axis=1)))


TERMS_OFF = {
    "drag": {"water.drag": False},
    "added mass": {"water.added_mass": False},
    "buoyancy": {"water.buoyancy": False},
    "axial drag": {"water.axial_drag": False},
    "the current": {"water.current.model": "none"},
    "joint friction": {"friction.scale": 0.0},
    "viscous friction": {"plant.friction": 0.0},
}
"""Each term the JAX period must carry, and the settings that switch it off."""


@pytest.mark.parametrize("term", list(TERMS_OFF))
def test_each_term_is_far_above_the_tolerance(term, axial_arm):
    """Each term switched off changes the numba kernel's state after one period of the test above
    by far more than its 1e-12 tolerance: a term the JAX port dropped would fail that test (numba
    both times: no second XLA compile). The same copies and times as the script's export."""
    settings = {"friction.scale": 1.0, "plant.friction": 0.3}
    full = _plant(axial_arm, **settings)
    off = _plant(axial_arm, **{**settings, **TERMS_OFF[term]})
    x, tau, times = _copies(full, 3)
    wet = BatchedArm(full.plant.fast).step(times, x, tau, PERIOD, full.plant.inner_step)[0]
    dry = BatchedArm(off.plant.fast).step(times, x, tau, PERIOD, off.plant.inner_step)[0]
    assert _relative(dry, wet) > 1e-9


def test_kirchhoffs_terms_are_far_above_the_tolerance(axial_arm):
    """Kirchhoff's added mass against Morison's changes the numba kernel's state after one period
    by far more than the 1e-12 tolerance, so the JAX test with it checks its terms."""
    settings = {"friction.scale": 1.0, "plant.friction": 0.3}
    morison = _plant(axial_arm, **settings)
    kirchhoff = _plant(axial_arm, **settings, **{"water.added_mass_model": "kirchhoff"})
    x, tau, times = _copies(morison, 3)
    one = BatchedArm(morison.plant.fast).step(times, x, tau, PERIOD, morison.plant.inner_step)[0]
    other = BatchedArm(kirchhoff.plant.fast).step(times, x, tau, PERIOD, kirchhoff.plant.inner_step)[0]
    assert _relative(other, one) > 1e-9


@pytest.mark.parametrize(
    "field, value, match",
    [("switches", [1, 1, 1, 1, 1, 0], "reynolds"), ("switches", [1, 1, 1, 1, 0, 2], "neither Morison"),
     ("floating", True, "floating")],
)  # fmt: skip
def test_what_it_does_not_model_is_refused(field, value, match):
    constants = export_constants(_plant().plant.fast)
    constants[field] = np.asarray(value)
    with pytest.raises(ValueError, match=match):
        check_constants(constants)


@pytest.mark.parametrize("added_mass", ["morison", "kirchhoff"])
def test_jax_period_equals_numba_with_every_term(tmp_path, axial_arm, added_mass):
    """``scripts/gpu_plant.py`` as on the GPU machine: ``--export`` here, every term on (water
    strips, buoyancy, axial drag, added mass (Morison's and Kirchhoff's: one XLA compile each), the
    paper's current at a different phase per copy, the
    joint friction model and the viscous friction), then ``--run`` with no hydroarm on the path (the
    JAX module loaded by file path), its timed row of 3 copies (the check's own count: the check and the
    row share one XLA compile; 8 copies compiled a second program, 34 s more on a 2-core CI machine),
    the 3 reference copies checked: state,
    disturbance and first-stage disturbance after one period and the state after five, each within
    1e-12 of the numba kernel's, per copy. One XLA compile (tens of seconds on a CPU; loaded from
    JAX's persistent cache where ``JAX_COMPILATION_CACHE_DIR`` names one that holds it: a user's
    setting, passed through to the bare environment)."""
    data, out = tmp_path / "tiny.npz", tmp_path / "result.json"
    subprocess.run([sys.executable, str(SCRIPT), "--export", str(data), "--arm", axial_arm, "--drag-points", "2",
                    "--periods", "5", "--reference-copies", "3", "--set", "friction.scale=1",
                    "--set", "plant.friction=0.3", "--set", f"water.added_mass_model={added_mass}"],
                   check=True, capture_output=True)  # fmt: skip
    assert data.stat().st_size < 2_000_000
    saved = np.load(data, allow_pickle=False)
    assert bool(saved["c_friction_on"]) and float(saved["c_uniform"]) == 0.3
    assert np.any(saved["c_current_joint"][0] != 0.0) and np.all(saved["c_switches"][:4] == 1)
    assert int(saved["c_switches"][5]) == (added_mass == "kirchhoff")
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}  # no PYTHONPATH: only the venv's jax and numpy
    # JAX's persistent compilation cache where one is set: the same program loads its compiled period
    # from there; a changed program misses it and compiles
    env.update({k: v for k, v in os.environ.items() if k == "JAX_COMPILATION_CACHE_DIR"})
    subprocess.run([sys.executable, str(SCRIPT), "--run", str(data), "--copies", "3", "--steps", "1", "--out",
                    str(out)], check=True, capture_output=True, cwd=tmp_path, env=env)  # fmt: skip
    result = json.loads(out.read_text())
    check = result["check"]
    assert check["copies"] == 3 and check["periods"] == 5
    assert max(check["after_1"].values()) <= 1e-12
    assert check["after_periods"]["state"] <= 1e-12
    assert [row["copies"] for row in result["rows"]] == [3]
    assert result["rows"][0]["finite"] and result["rows"][0]["copy_steps_per_s"] > 0


def test_the_bench_files_are_small_and_complete():
    """bench/gpu/*.npz (what the lead runs on the GPU machine): under 2 MB, every constant there."""
    for name in ("paper", "alpha5"):
        path = SCRIPT.parents[1] / "bench" / "gpu" / f"{name}.npz"
        assert path.stat().st_size < 2_000_000
        data = np.load(path, allow_pickle=False)
        check_constants({k[2:]: data[k] for k in data.files if k.startswith("c_")})
        assert json.loads(str(data["meta"]))["arm"] == name
