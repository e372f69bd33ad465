"""A newcomer's first hour (issue 16): the small frictions of the command line and the tutorial."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest
import typer.main
from typer.testing import CliRunner

import hydroarm
from hydroarm.cli import _experiment_config, app
from hydroarm.control.registry import canonical_name
from hydroarm.model.arm.loading import builtin_arm_path
from hydroarm.model.arm.urdf_import import load_hydro_spec
from hydroarm.sim import experiment

ROOT = Path(__file__).resolve().parents[1]
TUTORIAL = ROOT / "docs" / "tutorial.md"
RUNNER = CliRunner()


def _command_paths() -> list[list[str]]:
    """Every command of the app, sub-apps' included: ``[]`` (the app), ``["run"]``, ..."""
    paths: list[list[str]] = [[]]

    def walk(command, prefix: list[str]) -> None:
        for name, sub in sorted(getattr(command, "commands", {}).items()):
            paths.append([*prefix, name])
            walk(sub, [*prefix, name])

    walk(typer.main.get_command(app), [])
    return paths


@pytest.mark.parametrize("command", ["animate", "view"])
def test_animate_on_a_file_that_is_no_trajectory_says_so_in_one_line(command):
    """(``view`` checks the file before it starts its server.)"""
    result = RUNNER.invoke(app, [command, str(ROOT / "README.md"), *(["--no-browser"] if command == "view" else [])])
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and "README.md" in lines[0], result.output
    assert "not a hydroarm trajectory" in lines[0] and "pickle" not in result.output


@pytest.mark.parametrize("command", _command_paths(), ids=lambda path: " ".join(path) or "hydroarm")
def test_help_shows_no_type_after_plain_flags(command):
    assert {"run", "reproduce", "sweep", "settings"} <= {path[0] for path in _command_paths() if path}
    result = RUNNER.invoke(app, [*command, "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    assert "<bool>" not in result.output
    assert re.search(r"--help\s+Show this message and exit", result.output)


def test_version():
    result = RUNNER.invoke(app, ["--version"])
    assert result.exit_code == 0 and result.output.strip() == f"hydroarm {hydroarm.__version__}"


def test_arms_describes_the_urdf_arm_from_its_hydrodynamics_file():
    arms = {row["name"]: row for row in json.loads(RUNNER.invoke(app, ["arms", "--json"]).output)}
    expected = load_hydro_spec(builtin_arm_path("alpha5")).description
    assert expected and arms["alpha5"]["description"] == expected
    assert all(row["description"] and row["description"] != "URDF arm" for row in arms.values())


def _tutorial_same_run() -> tuple[str, list[str], str, str]:
    """From the tutorial's "Changing settings": the settings file, the `--set` items and the
    controller of its `hydroarm run` command, and the "same run in Python" snippet."""
    text = TUTORIAL.read_text()
    section = text[text.index("### Changing settings") : text.index("## 3. The paper's study")]
    toml = re.search(r"cat > fast\.toml <<'EOF'\n(.*?)\nEOF\n", section, re.S).group(1)
    command = re.search(r"^hydroarm run .*--config fast\.toml.*$", section, re.M).group(0)
    sets = re.findall(r"--set (\S+)", command)
    controller = re.search(r"--controller (\S+)", command).group(1)
    snippet = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    return toml, sets, controller, snippet


def test_the_tutorials_same_run_in_python_is_the_same_run(tmp_path, monkeypatch):
    toml, sets, controller, snippet = _tutorial_same_run()
    (tmp_path / "fast.toml").write_text(toml)
    cli_config = _experiment_config(tmp_path / "fast.toml", sets)
    calls = []

    def fake_run(config, name, seed=0, progress=None):
        calls.append((config, canonical_name(name), seed))
        return None

    monkeypatch.setattr(experiment, "run_experiment", fake_run)
    monkeypatch.setattr("hydroarm.sim.runner.tracking_metrics", lambda traj: {"Ep": []})
    exec(compile(snippet, str(TUTORIAL), "exec"), {})  # noqa: S102 - our own tutorial
    (config, name, seed), *_ = calls
    assert config == cli_config, "the tutorial's Python snippet builds other settings than its command"
    assert name == canonical_name(controller) and seed == 0


@pytest.mark.subprocess  # git check-ignore
def test_the_readme_and_tutorial_outputs_are_git_ignored():
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    paths = [
        "run/", "run1/", "run2/", "fast-run/", "results/", "results-quick/", "alpha5/", "sweep1/", "sweep2/",
        "myrun/", "myrun_urdf/", "myrun_urdf_smc/", "bench-results/", "fast.toml", "paper.urdf",
        "myarm_export.urdf", "arm.gif", "run.npz", "tuned.toml", "run3/", "run4/", "myarm-tuned.toml",
    ]  # fmt: skip
    result = subprocess.run(["git", "check-ignore", "--no-index", *paths], cwd=ROOT, capture_output=True, text=True)
    ignored = {line.strip() for line in result.stdout.splitlines()}
    assert [p for p in paths if p not in ignored] == []
