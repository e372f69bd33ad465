"""What every command shares: the Typer app, the console, exit paths, settings from --config/--set."""

from __future__ import annotations

import contextlib
import json
import signal
import typing
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape
from typer.core import TyperGroup

from hydroarm.config import ConfigError

if typing.TYPE_CHECKING:
    import click


def _flags_without_type(command: click.Command, ctx: click.Context) -> None:
    """No ``<bool>`` after plain flags (``--json``, ``--quick``, ``--help``) in ``command``'s help
    and its subcommands': a flag takes no value, so its metavar is empty."""
    if command.help and not getattr(command, "_hydroarm_reflowed", False):
        command.help = _reflow(command.help)
        command._hydroarm_reflowed = True  # type: ignore[attr-defined]
    help_option = command.get_help_option(ctx)
    for param in [*command.params, *([help_option] if help_option is not None else [])]:
        if getattr(param, "is_flag", False) and param.metavar is None:
            param.metavar = ""
    for sub in getattr(command, "commands", {}).values():
        _flags_without_type(sub, ctx)


def _reflow(text: str) -> str:
    """A docstring's help with its hard line breaks taken out, so the terminal's width wraps it:
    the lines of a paragraph joined, an ``Example:`` line kept as a line of its own."""
    paragraphs = []
    for paragraph in text.strip().split("\n\n"):
        lines, current = [], []
        for line in paragraph.splitlines():
            line = line.strip()
            if line.startswith(("Example:", "Examples:")):
                if current:
                    lines.append(" ".join(current))
                lines.append(line)
                current = []
            elif line:
                current.append(line)
        if current:
            lines.append(" ".join(current))
        paragraphs.append("\n\n".join(lines))
    return "\n\n".join(paragraphs)


class _Group(TyperGroup):
    """The app's group: every command it hands out (sub-apps' too) shows flags without a type."""

    def get_params(self, ctx: click.Context) -> list[click.Parameter]:
        _flags_without_type(self, ctx)
        return super().get_params(ctx)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        command = super().get_command(ctx, cmd_name)
        if command is not None:
            _flags_without_type(command, ctx)
        return command

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        """As Typer's, but a usage error (an option's range, an unknown option, a missing
        argument) is one line, like every other bad input, not a box: ``error: ...`` naming the
        option, then where its help is; exit code 2."""
        import sys

        from typer import Abort

        try:  # Typer 0.2x carries its own copy of click
            from typer._click.exceptions import ClickException, NoArgsIsHelpError, UsageError
        except ImportError:  # pragma: no cover - older Typer on click
            from click.exceptions import ClickException, NoArgsIsHelpError, UsageError

        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        try:
            code = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except NoArgsIsHelpError as error:  # `hydroarm` alone: its help
            error.show()
            sys.exit(error.exit_code)
        except UsageError as error:
            where = f" (see {error.ctx.command_path} --help)" if error.ctx is not None else ""
            console.print(f"[bold red]error:[/] {escape(error.format_message() + where)}")
            sys.exit(error.exit_code)
        except ClickException as error:
            console.print(f"[bold red]error:[/] {escape(error.format_message())}")
            sys.exit(error.exit_code)
        except Abort:
            console.print("[yellow]aborted[/]")
            sys.exit(1)
        sys.exit(code if isinstance(code, int) else 0)


app = typer.Typer(
    cls=_Group,
    add_completion=False,
    no_args_is_help=True,
    help="Simulate and control underwater robot arms (Liu et al. 2023 reproduced and beaten).",
)
console = Console(stderr=True, soft_wrap=True)  # never break an error or summary line mid-phrase


def _fail(message: str, code: int = 2) -> None:
    console.print(f"[bold red]error:[/] {escape(message)}")
    raise typer.Exit(code)


def _check_out(out: Path) -> None:
    """``--out`` must be a folder or not exist yet (it is created only once the settings are
    valid), and writable: a probe folder is made and removed in it or, if it does not exist
    yet, in its nearest existing parent (which must be a folder)."""
    if out.exists() and not out.is_dir():
        _fail(f"--out '{out}': exists and is not a folder")
    _require_writable("--out", out, out.absolute())


def _check_file_out(out: Path, option: str = "--out") -> None:
    """A file to write: not a folder, and its folder writable (made if missing, as the
    commands do): the same probe as :func:`_check_out`, on the file's folder."""
    if out.is_dir():
        _fail(f"{option} '{out}': a folder, not a file")
    _require_writable(option, out, out.absolute().parent)


def _require_writable(option: str, out: Path, folder: Path) -> None:
    """``folder`` (or, if it does not exist yet, its nearest existing parent, which must be a
    folder) takes a probe folder, made and removed; else one line naming ``option`` and exit 2."""
    import shutil
    import tempfile

    parent = folder
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        _fail(f"{option} '{out}': '{parent}' is not a folder")
    try:
        shutil.rmtree(tempfile.mkdtemp(prefix=".hydroarm-probe-", dir=parent))
    except OSError as error:
        _fail(f"{option} '{out}': cannot write in '{parent}' ({error.strerror or error}); choose a writable folder")


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


def _flat(mapping: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in mapping.items():
        if isinstance(value, dict):
            out.update(_flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def _experiment_config(
    config_file: Path | None,
    overrides: list[str],
    tuned: bool = False,
    arm: str | None = None,
    vehicle: str | None = None,
):
    """The settings of ``--config`` (or the defaults), then, with ``--tuned``, the gains tuned for
    the arm (``arm`` or the settings' arm; :func:`hydroarm.model.arm.loading.tuned_settings_path`),
    then ``--vehicle`` (``vehicle``) with the ``--set`` overrides (validated together: a vehicle's
    settings are refused on a fixed arm)."""
    from hydroarm.config import read_mapping
    from hydroarm.model.arm.loading import tuned_settings_path
    from hydroarm.sim.experiment import ExperimentConfig, load_experiment_config, with_overrides
    from hydroarm.sim.settings_schema import migrated

    config = load_experiment_config(config_file) if config_file else ExperimentConfig()
    if tuned:
        name = arm if arm is not None else config.arm
        path = tuned_settings_path(name)
        config = with_overrides(config, _flat(migrated(read_mapping(path), str(path))))
    pairs: dict[str, Any] = {} if vehicle is None else {"vehicle.name": vehicle}
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"--set '{item}': expected key=value, e.g. mpc.r=0.001")
        key, value = item.split("=", 1)
        pairs[key.strip()] = _parse_value(value.strip())
    return with_overrides(config, pairs) if pairs else config


def _version(value: bool) -> None:
    if value:
        import hydroarm

        print(f"hydroarm {hydroarm.__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[
        bool, typer.Option("--version", help="Print hydroarm's version and exit.", callback=_version, is_eager=True)
    ] = False,
) -> None:
    """Simulate and control underwater robot arms (Liu et al. 2023 reproduced and beaten)."""


OverwriteOption = Annotated[
    bool,
    typer.Option(
        "--overwrite", help="--out holds results of other settings: remove them first (else the command refuses)."
    ),
]

ConfigOption = Annotated[
    Path | None, typer.Option("--config", help="TOML/YAML experiment settings (see docs/tutorial.md).")
]
TunedOption = Annotated[
    bool,
    typer.Option(
        "--tuned", help="Use the SMC and MPC gains tuned on land for the (built-in) arm: arms/tuned/ARM.toml."
    ),
]
SetOption = Annotated[
    list[str] | None,
    typer.Option("--set", help="Override one setting, e.g. --set mpc.r=0.001 --set gp.window=20 (repeatable)."),
]
