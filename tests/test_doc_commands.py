"""Every shell command of the README, the tutorial and every ``--help`` example runs without a
traceback (issue 24), on quick settings.

The commands run in order in one folder holding a copy of ``examples/`` (the README's
``animate`` reads what its ``reproduce`` wrote). Each command is the documented one with only
what makes it quick added at its end (:func:`quick`): a short task (``--set duration=...``), one
noisy seed, two replicas and ``--quick`` for ``reproduce``, the example sweep files shortened likewise. What is
not run, and why, is :func:`not_run`'s list: installs, the test suite, Ray clusters, the
benchmark suite (``tests/test_bench.py`` runs ``hydroarm bench --quick``), the viewer's server.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import typer.main

from hydroarm.cli import app

ROOT = Path(__file__).resolve().parents[1]
DURATION = "0.3"
"""s: the task of every quick run (30 control steps)."""


def _shell_lines(path: Path) -> list[str]:
    """The commands of a Markdown file's ```bash blocks (here-documents kept whole)."""
    commands = []
    for block in re.findall(r"```(?:bash|sh)\n(.*?)```", path.read_text(), re.S):
        lines = block.splitlines()
        k = 0
        while k < len(lines):
            line = lines[k]
            match = re.search(r"<<'?(\w+)'?", line)
            if match:  # a here-document: the command and its body up to the terminator
                end = lines.index(match.group(1), k + 1)
                commands.append("\n".join(lines[k : end + 1]))
                k = end + 1
                continue
            if line.strip():
                commands.append(line)
            k += 1
    return commands


def _help_examples() -> list[str]:
    """The ``Example(s): hydroarm ...`` commands of every command's help (to the end of the
    line; ``;`` separates two)."""
    found: list[str] = []

    def walk(command) -> None:
        for line in (command.help or "").splitlines():
            match = re.search(r"Examples?: (hydroarm .*)$", line)
            if match:
                found.extend(part.strip() for part in match.group(1).split(";") if part.strip())
        for sub in getattr(command, "commands", {}).values():
            walk(sub)

    walk(typer.main.get_command(app))
    return found


def not_run(command: str) -> str | None:
    """Why ``command`` is not run here, or None."""
    words = shlex.split(command.split("\n")[0], comments=True)
    if not words:
        return "empty"
    if words[0] in ("python3", "pip", "ray"):
        return "an install, the test suite or a Ray cluster: not a hydroarm command"
    if words[0] != "hydroarm":
        return None if words[0] == "cat" else f"not a hydroarm command: {words[0]}"
    if "--ray" in words or "--ray-address" in words:
        return "needs the ray extra and a Ray instance (tests/test_sweep.py runs sweeps on Ray)"
    if words[1] == "bench":
        return "the benchmark suite: tests/test_bench.py runs hydroarm bench --quick"
    if words[1] == "view" and "--out" not in words:
        return "starts the viewer's server (tests/test_viewer.py serves a run)"
    if words[1] == "ros2":
        return "a node waiting for its peer on the ROS 2 graph: tests/test_ros2.py runs ros2 sim and control together"
    return None


def quick(command: str) -> str:
    """``command`` with quick settings appended (the documented words unchanged)."""
    if not command.startswith("hydroarm "):
        return command
    words = shlex.split(command, comments=True)
    extra: list[str] = []
    if words[1] == "reproduce":  # --quick sets a 3 s task itself: a short task and one seed instead
        words = [w for w in words if w != "--quick"]
        command = shlex.join(words)
        # two replicas of each GP row (the fewest that still report a spread), not the default 8
        extra = ["--seeds", "1", "--no-ablation", "--replicas", "2", "--set", f"duration={DURATION}"]
    elif words[1] in ("run", "tune") and "--vehicle" not in words:
        extra = ["--set", f"duration={DURATION}"]
    elif words[1] == "run":
        extra = ["--set", "duration=1.2"]
    documented = command.split(" #", 1)[0].rstrip()  # without its trailing comment
    return documented + (" " + shlex.join(extra) if extra else "")


def _documented() -> list[tuple[str, str]]:
    """(where, command) of every documented command, each quick form once (the first place it
    appears: the tutorial repeats the README's)."""
    commands = [("README", c) for c in _shell_lines(ROOT / "README.md")]
    commands += [("tutorial", c) for c in _shell_lines(ROOT / "docs" / "tutorial.md")]
    commands += [("--help", c) for c in _help_examples()]
    seen: set[str] = set()
    unique = []
    for source, command in commands:
        if quick(command) not in seen:
            seen.add(quick(command))
            unique.append((source, command))
    return unique


DOCUMENTED = _documented()


def test_the_documented_commands_are_found():
    """The extraction itself: the README's reproduce, the tutorial's here-document and sweep, the
    help's examples (a silent extraction would make the test below pass on nothing)."""
    texts = [command for _, command in DOCUMENTED]
    assert "hydroarm reproduce --out results-quick --quick" in " ".join(texts)
    assert any(text.startswith("cat > fast.toml <<'EOF'\n") and text.endswith("\nEOF") for text in texts)
    assert "hydroarm animate results/runs/clean__gp-mpc__seed0.npz --out arm.gif" in texts
    assert "hydroarm settings --markdown > docs/settings.md" in texts
    assert sum(source == "--help" for source, _ in DOCUMENTED) >= 5
    assert sum(not_run(command) is None for _, command in DOCUMENTED) >= 20


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A user's folder: a copy of examples/ with the example sweeps shortened, and docs/."""
    where = tmp_path_factory.mktemp("newcomer")
    shutil.copytree(ROOT / "examples", where / "examples", ignore=shutil.ignore_patterns("notebooks"))
    for sweep in (where / "examples").glob("sweep*.toml"):
        text = re.sub(r"(?m)^duration = [0-9.]+", f"duration = {DURATION}", sweep.read_text())
        text = re.sub(r"(?m)^seeds = [0-9]+", "seeds = 1", text)
        text = re.sub(r"(?m)^samples = [0-9]+", "samples = 2", text)
        sweep.write_text(text)
    (where / "docs").mkdir()
    return where


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.parametrize(("source", "command"), DOCUMENTED, ids=[f"{s}: {c[:70]}" for s, c in DOCUMENTED])
def test_a_documented_command_runs_without_a_traceback(source, command, folder):
    reason = not_run(command)
    if reason is not None:
        pytest.skip(reason)
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    env["COLUMNS"] = "120"
    result = subprocess.run(
        ["bash", "-c", quick(command)], cwd=folder, env=env, capture_output=True, text=True, timeout=600
    )
    output = result.stdout + result.stderr
    assert "Traceback" not in output, f"{source}: {command}\n{output[-3000:]}"
    assert result.returncode == 0, f"{source}: {command} -> exit {result.returncode}\n{output[-3000:]}"
