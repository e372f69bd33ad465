"""The vehicle run's interfaces: ``hydroarm run --vehicle`` (an ordinary experiment), the
trajectory a vehicle-manipulator run saves, and ``animate`` drawing the vehicle's hull with the arm."""

from __future__ import annotations

import copy
import json
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from hydroarm.sim.experiment import ExperimentConfig, build_experiment
from hydroarm.sim.runner import Trajectory
from hydroarm.sim.vehicle import VehicleRun
from hydroarm.studies.animate import render_frame


def vehicle_config(**settings) -> ExperimentConfig:
    return ExperimentConfig(arm="mount", vehicle=VehicleRun(name="bluerov2_heavy"), **settings)


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    """0.3 s of station keeping, saved as ``run --vehicle --out`` saves it."""
    path = tmp_path_factory.mktemp("uvms") / "trajectory.npz"
    build_experiment(vehicle_config(duration=0.3), "smc").run().save(path)
    return path


def _hull_pixels(png) -> np.ndarray:
    """(row, column) of the pixels of the hull's translucent amber (no link, pane or ghost has it)."""
    image = np.asarray(Image.open(png).convert("RGB"), dtype=float) / 255.0
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    return np.argwhere((r > 0.85) & (g > 0.7 * r) & (g < 0.95 * r) & (b < 0.6))


def test_saved_uvms_run_is_a_trajectory_with_the_base_pose(saved):
    traj = Trajectory.load(saved)
    steps = len(traj.t)
    assert steps == 30 and traj.n_joints == 4 and traj.q.shape == (steps, 4)
    assert traj.meta["vehicle"] == "bluerov2-heavy" and traj.meta["arm"] == "alpha5"
    assert traj.extra["base_pose"].shape == (steps, 7)
    assert np.allclose(traj.extra["base_pose"][0], traj.meta["target_pose"])
    assert np.allclose(np.linalg.norm(traj.extra["base_pose"][:, 3:], axis=1), 1.0)
    assert np.allclose(traj.q[0], VehicleRun().home)
    assert len(traj.meta["final_state"]) == 7 + 4 + 6 + 4 + 8  # q, v, thrust of the floating plant
    assert "drift_rms_m" in traj.meta["metrics"]


def test_uvms_frame_draws_the_hull_at_the_base_pose(saved, tmp_path):
    """The hull's colour shows in a frame, not in an arm-only frame, and it moves with the base."""
    traj = Trajectory.load(saved)
    hull = _hull_pixels(render_frame(traj, tmp_path / "here.png", time=0.2))
    assert len(hull) > 2000

    arm_only = copy.deepcopy(traj)
    del arm_only.meta["vehicle"]
    arm_only.extra = {}
    assert len(_hull_pixels(render_frame(arm_only, tmp_path / "arm.png", time=0.2))) < 50

    moved = copy.deepcopy(traj)
    moved.extra["base_pose"][:, 1] += 0.4  # 0.4 m along world y; the camera stays on the target
    shifted = _hull_pixels(render_frame(moved, tmp_path / "moved.png", time=0.2))
    assert len(shifted) > 1000
    assert np.linalg.norm(shifted.mean(axis=0) - hull.mean(axis=0)) > 20.0  # pixels


def _cli(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "hydroarm.cli", *args], capture_output=True, text=True, timeout=180, cwd=cwd
    )


@pytest.mark.subprocess
def test_run_with_vehicle_is_the_python_experiment_and_animates(tmp_path):
    via_run = _cli("run", "--vehicle", "bluerov2-heavy", "--arm", "alpha5", "--set", "duration=0.2", "--json",
                   "--out", str(tmp_path / "a"))  # fmt: skip
    assert via_run.returncode == 0, via_run.stderr
    printed = json.loads(via_run.stdout.strip().splitlines()[-1])
    in_python = build_experiment(vehicle_config(duration=0.2), "smc").run().meta["metrics"]
    assert printed["station_keeping"] == in_python  # one code path: the same numbers
    for name in ("metrics.json", "trajectory.npz", "hydroarm-run.json"):
        assert (tmp_path / "a" / name).is_file()
    traj = Trajectory.load(tmp_path / "a" / "trajectory.npz")
    assert traj.meta["vehicle"] == "bluerov2-heavy" and traj.extra["base_pose"].shape == (20, 7)
    movie = _cli("animate", str(tmp_path / "a" / "trajectory.npz"), "--out", str(tmp_path / "uvms.gif"))
    assert movie.returncode == 0, movie.stderr
    with Image.open(tmp_path / "uvms.gif") as gif:
        assert gif.n_frames == 2  # 0.2 s at 10 fps


@pytest.mark.subprocess
def test_run_with_a_bad_vehicle_exits_2(tmp_path):
    from hydroarm.model.vehicle.description import builtin_vehicle_path

    bad = tmp_path / "bad.toml"
    bad.write_text(builtin_vehicle_path("bluerov2_heavy").read_text().replace("mass = 13.5 ", "mass = -1.0 "))
    cases = {
        "no-such-vehicle": (("--vehicle", "no-such-vehicle"), "neither a built-in vehicle"),
        "bad file": (("--vehicle", str(bad)), "mass"),
        "arm controller": (("--vehicle", "bluerov2-heavy", "--controller", "pid"), "must be one of"),
        "station keeper": (
            ("--vehicle", "bluerov2-heavy", "--set", "vehicle.control.kind=lqr"),
            "vehicle.control.kind",
        ),
        "arm-only option": (("--vehicle", "bluerov2-heavy", "--noise", "0.1"), "--noise"),
        "unknown setting": (("--vehicle", "bluerov2-heavy", "--set", "durations=1"), "durations"),
    }
    for case, (args, words) in cases.items():
        result = _cli("run", *args, "--out", str(tmp_path / "out"), cwd=tmp_path)
        assert result.returncode == 2, (case, result.stderr)
        assert words in result.stderr and "Traceback" not in result.stderr, (case, result.stderr)
        assert len(result.stderr.strip().splitlines()) == 1, (case, result.stderr)
    assert not (tmp_path / "out").exists()
