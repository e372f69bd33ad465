"""``hydroarm compare``: saved runs side by side (issue 24)."""

from __future__ import annotations

import json

import matplotlib.image
import numpy as np
import pytest
from typer.testing import CliRunner

from hydroarm.cli import app
from hydroarm.sim.experiment import ExperimentConfig, run_experiment
from hydroarm.sim.runner import tracking_metrics

RUNNER = CliRunner()


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two controllers on the paper arm over 0.3 s, one on alpha5."""
    folder = tmp_path_factory.mktemp("runs")
    paths = {}
    for name, arm in (("SMC", "paper"), ("GP-MPC", "paper"), ("SMC-alpha5", "alpha5")):
        traj = run_experiment(ExperimentConfig(duration=0.3, arm=arm), name.split("-alpha5")[0], seed=0)
        paths[name] = folder / f"{name}.npz"
        traj.save(paths[name])
    return paths


def test_the_table_is_each_runs_e_p_whole_and_after_the_start_up(runs, tmp_path):
    out = tmp_path / "cmp.png"
    args = ["compare", str(runs["SMC"]), str(runs["GP-MPC"]), "--steady-after", "0.1", "--out", str(out), "--json"]
    result = RUNNER.invoke(app, args)
    assert result.exit_code == 0, result.output
    rows = json.loads(result.stdout)
    assert [row["label"] for row in rows] == ["SMC", "GP-MPC"]
    from hydroarm.sim.runner import Trajectory

    for row, name in zip(rows, ("SMC", "GP-MPC"), strict=True):
        expected = tracking_metrics(Trajectory.load(runs[name]), steady_after=0.1)
        np.testing.assert_allclose(row["Ep"], expected["Ep"], rtol=1e-12)
        np.testing.assert_allclose(row["Ep_steady"], expected["Ep_steady"], rtol=1e-12)
        assert row["Ep_mean"] == pytest.approx(np.mean(expected["Ep"]))
        assert row["Ep_steady_mean"] < row["Ep_mean"]  # the start-up from 3 rad away dominates
    image = matplotlib.image.imread(out)
    assert image.shape[0] > image.shape[1] * 0.8  # six rows of per-joint axes, three columns


def test_the_printed_table_shows_both_spans_at_80_columns(runs, tmp_path):
    result = RUNNER.invoke(
        app, ["compare", str(runs["SMC"]), str(runs["SMC"]), "--out", str(tmp_path / "c.png")], env={"COLUMNS": "80"}
    )
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert any("whole run" in line for line in lines) and any("t > 2 s" in line for line in lines)
    assert all(len(line) <= 80 for line in lines) and "…" not in result.stdout
    # a run shorter than the start-up has no E_p after it: shown as "-", not NaN
    assert "nan" not in result.stdout.lower() and " - " in result.stdout + " "
    # the same controller twice is told apart by its file
    assert "SMC (SMC)" in result.output


def test_runs_of_different_arms_or_unreadable_files_exit_2(runs, tmp_path):
    result = RUNNER.invoke(
        app, ["compare", str(runs["SMC"]), str(runs["SMC-alpha5"]), "--out", str(tmp_path / "c.png")]
    )
    assert result.exit_code == 2 and "different numbers of joints" in result.output
    (tmp_path / "bad.npz").write_text("no")
    result = RUNNER.invoke(app, ["compare", str(tmp_path / "bad.npz")])
    assert result.exit_code == 2 and "not a hydroarm trajectory" in result.output
    result = RUNNER.invoke(app, ["compare", str(tmp_path / "missing.npz")])
    assert result.exit_code == 2 and "no such file" in result.output
