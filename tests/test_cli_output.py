"""CLI messages stay whole lines whatever the terminal's width or the path's length."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest


@pytest.mark.subprocess
@pytest.mark.parametrize("columns", ["40", "80", "200"])
def test_error_line_is_never_wrapped(tmp_path, columns):
    missing = tmp_path / ("a-rather-long-folder-name-" * 4) / "no-such-run.npz"
    env = {**os.environ, "COLUMNS": columns, "TERM": "xterm"}
    result = subprocess.run(
        [sys.executable, "-m", "hydroarm.cli", "animate", str(missing)],
        capture_output=True, text=True, env=env, timeout=120,
    )  # fmt: skip
    assert result.returncode == 2
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, result.stderr  # one message, one line
    assert lines[0].startswith("error:") and str(missing) in lines[0] and "no such file" in lines[0]
