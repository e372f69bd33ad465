"""``hydroarm settings``: every setting with its default, unit and allowed range."""

from __future__ import annotations

from typing import Annotated

import typer

from hydroarm.cli._common import _fail, app
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
) -> None:
    """List every setting (--set key=value, --config files, sweep files): default, allowed range, unit.

    Generated from the config models, so it is what validation accepts.
    Examples: hydroarm settings --controller gp-mpc;  hydroarm settings --markdown > docs/settings.md
    """
    from hydroarm.control.registry import canonical_name
    from hydroarm.studies.settings_table import (
        experiment_settings,
        other_settings_text,
        settings_json,
        settings_markdown,
        settings_text,
    )

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
