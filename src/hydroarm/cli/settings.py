"""``hydroarm settings``: every setting with its default, unit and allowed range."""

from __future__ import annotations

from typing import Annotated

import typer

from hydroarm.cli._common import ConfigOption, SetOption, _experiment_config, _fail, app
from hydroarm.config import ConfigError


@app.command()
def settings(
    controller: Annotated[
        str | None,
        typer.Option("--controller", help="Only the sections this controller reads (hydroarm controllers lists them)."),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the table as JSON (one object per key).")] = False,
    markdown: Annotated[
        bool, typer.Option("--markdown", help="Print docs/settings.md (every section, as Markdown).")
    ] = False,
    resolved: Annotated[
        bool,
        typer.Option(
            "--resolved",
            help="Print, for one run (--arm, --config, --set), the values that the settings, the arm file and "
            "its hydrodynamics file can each give, and which one won.",
        ),
    ] = False,
    arm: Annotated[str | None, typer.Option("--arm", help="--resolved: the arm (default: the settings').")] = None,
    config_file: ConfigOption = None,
    overrides: SetOption = None,
) -> None:
    """List every setting (--set key=value, --config files, sweep files): default, allowed range, unit.

    Generated from the config models, so it is what validation accepts. --resolved prints, for one
    run, which value won where the settings, the arm file and its hydrodynamics file can each give one.
    Examples: hydroarm settings --controller gp-mpc;  hydroarm settings --markdown > docs/settings.md
    Example: hydroarm settings --resolved --arm alpha5 --set water.cd=1.2
    """
    from hydroarm.control.registry import canonical_name
    from hydroarm.studies.settings_table import (
        experiment_settings,
        other_settings_text,
        settings_json,
        settings_markdown,
        settings_text,
    )

    if resolved:
        _print_resolved(config_file, overrides or [], arm, as_json)
        return
    if arm is not None or config_file is not None or overrides:
        _fail("--arm, --config and --set go with --resolved")
    if markdown:
        if controller is not None or as_json:
            _fail("--markdown prints every section: leave out --controller and --json")
        print(settings_markdown(), end="")
        return
    try:
        rows = experiment_settings(controller)
    except ConfigError as error:
        _fail(f"--{error}")
    if as_json:
        print(settings_json(rows))
        return
    if controller is not None:
        print(f"The settings a run of {canonical_name(controller)} reads (hydroarm settings: all of them).\n")
    import os
    import shutil
    import sys

    columns = shutil.get_terminal_size().columns if "COLUMNS" in os.environ or sys.stdout.isatty() else None
    columns = max(columns, 40) if columns else None
    print(settings_text(rows, columns=columns), end="")
    if controller is None:  # every section, as --markdown lists them
        print("\n" + other_settings_text(columns), end="")


def _print_resolved(config_file, overrides: list[str], arm: str | None, as_json: bool) -> None:
    """``hydroarm settings --resolved``: one row per resolved value (a table, or JSON)."""
    import dataclasses
    import json

    from rich.console import Console
    from rich.table import Table

    from hydroarm.model.arm.loading import load_arm
    from hydroarm.sim.experiment import with_overrides
    from hydroarm.studies.settings_resolved import resolve_settings

    try:
        config = _experiment_config(config_file, overrides, False, arm)
        if arm is not None:
            config = with_overrides(config, {"arm": arm})
        rows = resolve_settings(config, load_arm(config.arm))
    except ConfigError as error:
        _fail(str(error))
    if as_json:
        print(json.dumps([dataclasses.asdict(row) for row in rows]))
        return
    table = Table(title=f"resolved for arm {config.arm} (docs/settings.md: which value wins)")
    for column in ("setting", "where", "value", "source"):
        table.add_column(column)
    for row in rows:
        table.add_row(row.setting, row.where, row.value, row.source)
    Console().print(table)
