"""The arm moving: GIF rendering of a saved trajectory, headless."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

import hydroarm
from hydroarm.config import ConfigError
from hydroarm.control.smc import SlidingModeController
from hydroarm.model.arm.plant import UnderwaterPlant
from hydroarm.model.task.references import paper_reference
from hydroarm.model.water.morison import Water
from hydroarm.sim.runner import Trajectory, run_closed_loop
from hydroarm.studies.animate import animate, reach, render_frame


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """1.5 s of SMC on the paper arm in water, saved as the CLI would save it."""
    arm = hydroarm.load_arm("paper")
    traj = run_closed_loop(UnderwaterPlant(arm, Water()), SlidingModeController(arm), paper_reference(), 1.5)
    traj.meta["arm"] = "paper"
    path = tmp_path_factory.mktemp("anim") / "run.npz"
    traj.save(path)
    return path


@pytest.mark.slow
def test_gif_of_a_saved_run(run, tmp_path):
    out = animate(run, tmp_path / "arm.gif", fps=10)
    assert out == tmp_path / "arm.gif" and out.stat().st_size < 1_000_000
    assert not list(tmp_path.glob("*.tmp*"))
    with Image.open(out) as gif:
        assert gif.format == "GIF"
        assert gif.n_frames == 15  # 1.5 s in real time at 10 fps (stride 10 control steps)
        assert gif.size == (400, 352)
        gif.seek(0)
        first = np.asarray(gif.convert("RGB"), dtype=float)
        gif.seek(gif.n_frames - 1)
        last = np.asarray(gif.convert("RGB"), dtype=float)
    assert np.abs(first - last).mean() > 0.5  # the arm moved


@pytest.mark.slow
def test_window_stride_and_explicit_arm(run, tmp_path):
    traj = Trajectory.load(run)
    out = animate(traj, tmp_path / "part.gif", arm="paper", fps=5, stride=5, start=0.5, duration=0.5)
    with Image.open(out) as gif:
        assert gif.n_frames == 10  # samples 50, 55, ..., 95


@pytest.mark.slow
def test_frame_png_shows_arm_and_ghost(run, tmp_path):
    """At t = 0.1 s the arm is far from the reference: both the coloured arm and the grey ghost show."""
    png = render_frame(run, tmp_path / "frame.png", time=0.1)
    image = np.asarray(Image.open(png).convert("RGB"), dtype=float) / 255.0
    saturation = image.max(axis=2) - image.min(axis=2)
    grey = (saturation < 0.04) & (image.mean(axis=2) > 0.45) & (image.mean(axis=2) < 0.8)
    assert (saturation > 0.35).sum() > 300  # coloured link tubes
    assert grey.sum() > 300  # ghosted reference


def test_reach_bounds_the_arm():
    arm = hydroarm.load_arm("paper")
    extent = reach(arm)
    assert 0.9 < extent < 1.2  # |a2| + |a3| + wrist + radius
    q = np.random.default_rng(0).uniform(-3, 3, size=(20, 6))
    assert all(np.abs(arm.cylinder_endpoints(x)).max() <= extent for x in q)


@pytest.mark.slow
def test_errors(run, tmp_path):
    with pytest.raises(ConfigError, match="unknown movie format"):
        animate(run, tmp_path / "arm.avi")
    with pytest.raises(ConfigError, match="joints"):
        animate(run, tmp_path / "arm.gif", arm="alpha5")
    with pytest.raises(ConfigError, match="no trajectory samples"):
        animate(run, tmp_path / "arm.gif", start=100.0, duration=1.0)
