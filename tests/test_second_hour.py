"""A newcomer's second hour (issue 24): no traceback on the inputs that gave one, messages that
say what is wrong."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hydroarm.cli import app
from hydroarm.config import ConfigError
from hydroarm.model.arm.loading import load_arm
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides
from hydroarm.sim.runner import Trajectory, run_closed_loop, tracking_metrics

RUNNER = CliRunner()
ROOT = Path(__file__).resolve().parents[1]


def _one_error_line(result) -> str:
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), result.output
    return lines[0]


class ScalarReference:
    """A reference whose ``sample`` takes one time only (math, not NumPy), as a user writes one."""

    def __init__(self, inner):
        self.inner = inner

    def sample(self, t: float):
        assert isinstance(t, float), type(t)
        return self.inner.sample(t)


@pytest.mark.parametrize("controller", ["SMC", "MPC", "GP-MPC", "IDMPC", "GP-IDMPC"])
def test_a_scalar_reference_runs_every_controller_as_the_vectorised_one(controller):
    """The same run from the task's vectorised reference and from one that takes a scalar time:
    the controllers must ask the scalar one one time at a time and get the same torques."""
    config = ExperimentConfig(duration=0.05)
    experiment = build_experiment(config, controller)
    expected = run_closed_loop(experiment.plant, experiment.controller, experiment.reference, 0.05, 0, x0=experiment.x0)
    experiment = build_experiment(config, controller)
    scalar = ScalarReference(experiment.reference)
    got = run_closed_loop(experiment.plant, experiment.controller, scalar, 0.05, 0, x0=experiment.x0)
    np.testing.assert_array_equal(got.u, expected.u)


@pytest.mark.parametrize(
    ("settings", "field"),
    [({"control_period": 0.5, "duration": 0.1}, "control_period"), ({"control_period": 0.01, "duration": 0.004}, "")],
)
def test_a_run_without_a_control_step_is_refused_at_validation(settings, field):
    with pytest.raises(ConfigError, match="control_period .*must be <= duration|at least one control step"):
        with_overrides(ExperimentConfig(), settings)


def test_the_shortest_valid_run_has_metrics():
    """What passes validation must not fail later (docs/reliability.md): one control step."""
    config = with_overrides(ExperimentConfig(), {"control_period": 0.1, "duration": 0.1})
    metrics = tracking_metrics(build_experiment(config, "SMC").run())
    assert len(metrics["Ep"]) == 6 and all(np.isfinite(metrics["Ep"]))


def test_run_with_a_control_period_beyond_the_duration_exits_2_and_writes_nothing(tmp_path):
    out = tmp_path / "cp"
    result = RUNNER.invoke(app, ["run", "--set", "control_period=0.5", "--set", "duration=0.1", "--out", str(out)])
    line = _one_error_line(result)
    assert "control_period" in line and "duration" in line
    assert not out.exists()


@pytest.mark.parametrize("command", [["run"], ["reproduce", "--quick"], ["run", "--vehicle", "bluerov2-heavy"]])
def test_an_out_folder_that_cannot_be_made_exits_2_in_one_line(command):
    result = RUNNER.invoke(app, [*command, "--out", "/proc/hydroarm-cannot-be-here"])
    line = _one_error_line(result)
    assert "--out '/proc/hydroarm-cannot-be-here'" in line and "cannot write" in line


def test_an_out_folder_under_a_file_exits_2(tmp_path):
    (tmp_path / "file").write_text("x")
    line = _one_error_line(RUNNER.invoke(app, ["run", "--out", str(tmp_path / "file" / "run")]))
    assert "is not a folder" in line


def test_an_unknown_arm_controller_on_a_vehicle_exits_2_naming_the_allowed():
    line = _one_error_line(RUNNER.invoke(app, ["run", "--vehicle", "bluerov2-heavy", "--controller", "foo"]))
    assert "controller = 'foo'" in line and "gp-idmpc" in line


def test_the_vehicle_run_settings_refuse_a_run_without_a_step():
    with pytest.raises(ConfigError, match="control_period"):
        with_overrides(ExperimentConfig(), {"vehicle.name": "bluerov2-heavy", "duration": 0.005})


@pytest.mark.parametrize("arm_controller", ["idmpc", "gp-idmpc"])
def test_the_inverse_dynamics_mpcs_run_on_the_vehicle(arm_controller, tmp_path):
    """They sample the reach-and-return reference (scalar times only) over their horizon."""
    result = RUNNER.invoke(
        app,
        ["run", "--vehicle", "bluerov2-heavy", "--controller", arm_controller,
         "--set", "duration=1.2", "--out", str(tmp_path / "v")],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert (tmp_path / "v" / "metrics.json").is_file()


# --- settings files that work from anywhere ---------------------------------------------


def test_tune_names_the_arm_relative_to_the_settings_file_and_run_reads_it_from_anywhere(tmp_path, monkeypatch):
    """What ``hydroarm tune --arm examples/myarm.toml --out DIR/x.toml`` writes must load from
    DIR and from anywhere else."""
    from hydroarm.sim.experiment import arm_for_settings_file, load_experiment_config
    from hydroarm.studies.tune import write_settings

    arms = tmp_path / "arms"
    arms.mkdir()
    (arms / "myarm.toml").write_text((ROOT / "src" / "hydroarm" / "arms" / "ur5.toml").read_text())
    out = tmp_path / "tuned" / "x.toml"
    out.parent.mkdir()
    monkeypatch.chdir(tmp_path)
    written = arm_for_settings_file("arms/myarm.toml", out)
    assert written == "../arms/myarm.toml"
    write_settings(out, {"arm": written, "smc.switching_gain": 5.0}, "test")
    for where in (out.parent, tmp_path / "arms", Path("/")):
        monkeypatch.chdir(where)
        config = load_experiment_config(out)
        assert Path(config.arm).resolve() == (arms / "myarm.toml").resolve()
        assert load_arm(config.arm).n_joints == 6
    assert arm_for_settings_file("paper", out) == "paper"


def test_run_config_from_the_settings_files_folder(tmp_path, monkeypatch):
    (tmp_path / "myarm.toml").write_text((ROOT / "src" / "hydroarm" / "arms" / "ur5.toml").read_text())
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "x.toml").write_text('arm = "../myarm.toml"\nduration = 0.05\n')
    monkeypatch.chdir(tmp_path / "sub")
    result = RUNNER.invoke(app, ["run", "--controller", "smc", "--config", "x.toml", "--out", str(tmp_path / "r")])
    assert result.exit_code == 0, result.output


# --- messages that say what is wrong ---------------------------------------------------


def test_a_folder_given_as_a_file_is_called_a_folder(tmp_path):
    (tmp_path / "d.urdf").mkdir()
    assert "a folder, not a file" in _one_error_line(RUNNER.invoke(app, ["run", "--config", str(tmp_path)]))
    line = _one_error_line(RUNNER.invoke(app, ["run", "--arm", str(tmp_path / "d.urdf")]))
    assert "a folder, not a file" in line and "no such file" not in line


def test_an_arm_file_of_an_unknown_type_names_every_arm_file_type(tmp_path):
    (tmp_path / "x.npz").write_bytes(b"PK")
    line = _one_error_line(RUNNER.invoke(app, ["run", "--arm", str(tmp_path / "x.npz")]))
    assert ".urdf" in line and ".toml" in line and ".hydro.toml" in line


def test_tuned_with_a_missing_arm_file_says_the_file_is_missing(tmp_path):
    line = _one_error_line(RUNNER.invoke(app, ["run", "--tuned", "--arm", "./missing.toml"]))
    assert "nor an existing file" in line and "no tuned settings ship" not in line


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["run", "--noise", "nan"], ["--noise", "nan", "0 <= x <= 10"]),
        (["run", "--seed", "-1"], ["--seed", "greater than or equal to 0"]),
        (["run", "--bogus"], ["No such option", "--bogus"]),
        (["animate"], ["Missing argument"]),
    ],
)
def test_option_parser_errors_are_one_line(args, words):
    line = _one_error_line(RUNNER.invoke(app, args))
    assert all(word in line for word in words), line
    assert "╭" not in line


def test_a_plant_mismatch_is_a_run_setting(tmp_path):
    """``--set mismatch.mass_scale`` as in sweep files: the plant only is lighter, so the torques
    differ from the nominal run's; the run records it."""
    runs = {}
    for label, extra in (("nominal", []), ("light", ["--set", "mismatch.mass_scale=0.8"])):
        out = tmp_path / label
        result = RUNNER.invoke(app, ["run", "--controller", "smc", "--set", "duration=0.1", *extra, "--out", str(out)])
        assert result.exit_code == 0, result.output
        runs[label] = Trajectory.load(out / "trajectory.npz")
    assert runs["light"].meta["mismatch"]["mass_scale"] == 0.8
    assert not np.allclose(runs["light"].u, runs["nominal"].u)
    line = _one_error_line(RUNNER.invoke(app, ["run", "--set", "mismatch.mass_scal=0.8"]))
    assert "did you mean 'mismatch.mass_scale'" in line


def test_a_controller_setting_on_a_vehicle_run_says_what_the_vehicle_run_takes():
    line = _one_error_line(RUNNER.invoke(app, ["run", "--vehicle", "bluerov2-heavy", "--set", "duraton=1"]))
    assert "did you mean 'duration'" in line
    line = _one_error_line(RUNNER.invoke(app, ["run", "--vehicle", "bluerov2-heavy", "--set", "vehicle.awar=true"]))
    assert "did you mean 'vehicle.aware'" in line  # the vehicle's settings are a section of the one settings


@pytest.mark.parametrize(
    "args",
    [["export-urdf", "paper"], ["tune", "--controller", "smc"], ["animate", "RUN"], ["view", "RUN", "--no-browser"]],
    ids=lambda args: args[0],
)
def test_a_file_out_that_cannot_be_written_exits_2_in_one_line(args, tmp_path):
    run = tmp_path / "run.npz"
    np.savez(run, x=np.zeros(1))
    args = [str(run) if a == "RUN" else a for a in args]
    line = _one_error_line(RUNNER.invoke(app, [*args, "--out", "/proc/hydroarm-cannot/x.out"]))
    assert "cannot write" in line


def test_run_prints_e_p_after_the_start_up_beside_the_whole_run(tmp_path):
    """The whole run's E_p is decided by the start-up from the task's start; both are printed."""
    result = RUNNER.invoke(app, ["run", "--controller", "smc", "--set", "duration=2.5", "--out", str(tmp_path / "r")])
    assert result.exit_code == 0, result.output
    assert "whole run" in result.output and "after the start-up (t > 2 s)" in result.output


# --- text that fits the terminal ---------------------------------------------------------


def test_help_paragraphs_are_wrapped_by_the_terminal_not_the_docstring():
    """The docstring's hard line breaks are gone: at 80 columns no help line ends a phrase early
    (e.g. "results of other" then "settings" alone), and each example keeps its own line."""
    result = RUNNER.invoke(app, ["reproduce", "--help"], env={"COLUMNS": "80"})
    assert result.exit_code == 0
    text = " ".join(result.output.split())
    assert "a folder holding results of other settings is refused" in text
    lines = [line.strip() for line in result.output.splitlines()]
    assert any(line.startswith("Examples: hydroarm reproduce --out results") for line in lines)
    from hydroarm.cli._common import _reflow

    assert (
        _reflow("One\nparagraph here.\n\nExample: hydroarm x\nmore")
        == "One paragraph here.\n\nExample: hydroarm x\n\nmore"
    )


def test_settings_honours_columns():
    wide = RUNNER.invoke(app, ["settings"], env={"COLUMNS": "200"}).output
    narrow = RUNNER.invoke(app, ["settings"], env={"COLUMNS": "80"}).output
    assert max(len(line) for line in narrow.splitlines()) <= 80
    assert max(len(line) for line in wide.splitlines()) > 80
    assert " ".join(narrow.split()).count("water density (kg/m^3)") == 1


def test_torque_figures_scale_each_joint_to_its_own_torques(tmp_path, monkeypatch):
    """Figure 11: a joint whose torques stay far below the limit is not drawn on +-limit axes."""
    import matplotlib.pyplot as plt

    from hydroarm.studies import figures

    traj = build_experiment(ExperimentConfig(duration=0.3), "SMC").run()
    limit = np.full(6, 500.0)
    captured = {}
    monkeypatch.setattr(figures, "_finish", lambda fig, axes, path: captured.update(axes=axes) or path)
    figures.plot_torque(traj, tmp_path / "t.png", "torques", limit)
    assert np.min(np.max(np.abs(traj.u), axis=0)) < 250.0  # the wrist's torques are small
    for j, ax in enumerate(captured["axes"]):
        peak = np.max(np.abs(traj.u[:, j]))
        low, high = ax.get_ylim()
        if peak < 250.0:
            assert high < 250.0 and "limit 500" in ax.get_ylabel(), (j, peak, high)
        else:
            assert high >= 500.0
    plt.close("all")


def test_the_disturbance_figure_of_a_run_without_an_estimate_warns_nothing(tmp_path):
    """numpy's 'Mean of empty slice' leaked from Figures 5/7 when a joint had no estimate after
    1 s (all NaN): the figure now leaves that joint's RMS out, with no RuntimeWarning."""
    import warnings

    import matplotlib.pyplot as plt

    from hydroarm.studies import figures

    traj = build_experiment(ExperimentConfig(duration=1.5), "SMC").run()
    assert np.isnan(traj.disturbance_estimate[traj.t > 1.0]).all()  # SMC estimates nothing
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        figures.plot_disturbance_error(traj, tmp_path / "d.png", "estimate error")
    assert (tmp_path / "d.png").exists()
    plt.close("all")


def test_view_out_writes_the_recording_without_a_server_banner(tmp_path, capfd):
    pytest.importorskip("viser")
    run = tmp_path / "run.npz"
    build_experiment(ExperimentConfig(duration=0.05), "SMC").run().save(run)
    result = RUNNER.invoke(app, ["view", str(run), "--out", str(tmp_path / "run.html")])
    captured = capfd.readouterr()
    assert result.exit_code == 0, result.output
    text = result.output + captured.out + captured.err
    assert "wrote" in text and "http://" not in text and "Websocket" not in text and "Server stopped" not in text
    assert (tmp_path / "run.html").stat().st_size > 1000


def test_a_quick_tables_title_says_its_task_is_shorter_than_the_papers(tmp_path):
    from hydroarm.studies.reproduce_numbers import write_tables

    block = {name: {"Ep": [0.1] * 6, "Ep_steady": [0.01] * 6} for name in ("SMC", "MPC", "GP-MPC")}
    for duration, said in ((3.0, True), (10.0, False)):
        metrics = {"settings": {"paper_arm": True, "experiment": {"duration": duration}}, "ablation": {}}
        for case in ("clean", "noisy"):
            metrics[case] = _table_block(block, case)
        write_tables(metrics, tmp_path)
        title = (tmp_path / "table1.md").read_text().splitlines()[0]
        assert ("over a 3 s task, the paper's over its 10 s one" in title) is said, title


def _table_block(block, case):
    from hydroarm.studies.reproduce_rows import EXTRA_ROWS

    rows = {name: {**row, "seeds": [0, 1], "Ep_std": [0.0] * 6} for name, row in block.items()}
    rows.update({name: {"Ep": [0.1] * 6, "Ep_steady": [0.01] * 6} for name in EXTRA_ROWS})
    rows["MPC_dry_arm_bound"] = {"Ep": [0.05] * 6, "gain_over_MPC_percent": [50.0] * 6}
    rows["gain_gp_mpc_over_mpc_percent"] = {
        "per_joint": [0.0] * 6,
        "mean_of_joints": 0.0,
        "steady_per_joint": [0.0] * 6,
    }
    return rows
