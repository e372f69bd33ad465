"""The ``hydroarm`` command line: reproduce the paper, run one experiment, list arms and settings, export URDF.

Exit codes: 0 success, 1 a run failed, 2 bad input (a clear message naming the
field, no traceback), 130 interrupted by Ctrl-C / SIGINT, 143 terminated by
SIGTERM (in both cases finished runs are kept on disk and the same command
resumes from them).
"""

from __future__ import annotations

from hydroarm.cli import compare, replay, ros2, runs, settings, studies, vehicles, view  # noqa: F401  (they register)
from hydroarm.cli._common import _experiment_config, app

__all__ = ["_experiment_config", "app", "main"]


def main() -> None:  # pragma: no cover - entry point
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
