"""What every command shares: the Typer app, the console, exit paths, settings from --config/--set."""

from __future__ import annotations

import contextlib
import json
import signal
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape

from hydroarm.config import ConfigError, load_model

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="Simulate and control underwater robot arms (Liu et al. 2023 reproduced and beaten).",
)
console = Console(stderr=True, soft_wrap=True)  # never break an error or summary line mid-phrase


def _fail(message: str, code: int = 2) -> None:
    console.print(f"[bold red]error:[/] {escape(message)}")
    raise typer.Exit(code)


def _check_out(out: Path) -> None:
    """``--out`` must be a folder or not exist yet (it is created only once the settings are valid)."""
    if out.exists() and not out.is_dir():
        _fail(f"--out '{out}': exists and is not a folder")


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread like Ctrl-C so the same cleanup runs."""


@contextlib.contextmanager
def _sigterm_as_interrupt():
    """Turn SIGTERM into :class:`Terminated` while a long command runs."""

    def handler(signum, frame):
        raise Terminated()

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _interrupted(error: KeyboardInterrupt, out: Path) -> None:
    """Say where the finished runs are and exit 130 (SIGINT) or 143 (SIGTERM)."""
    console.print(f"[yellow]interrupted:[/] finished runs are kept in {out / 'runs'}; run the same command to resume")
    raise typer.Exit(143 if isinstance(error, Terminated) else 130)


def _parse_value(text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def _experiment_config(config_file: Path | None, overrides: list[str]):
    from hydroarm.studies.experiment import ExperimentConfig, with_overrides

    config = load_model(ExperimentConfig, config_file) if config_file else ExperimentConfig()
    pairs = {}
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"--set '{item}': expected key=value, e.g. mpc.r=0.001")
        key, value = item.split("=", 1)
        pairs[key.strip()] = _parse_value(value.strip())
    return with_overrides(config, pairs) if pairs else config


ConfigOption = Annotated[
    Path | None, typer.Option("--config", help="TOML/YAML experiment settings (see docs/tutorial.md).")
]
SetOption = Annotated[
    list[str] | None,
    typer.Option("--set", help="Override one setting, e.g. --set mpc.r=0.001 --set gp.window=20 (repeatable)."),
]
