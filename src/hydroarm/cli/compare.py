"""``hydroarm compare``: saved runs side by side (a table and a figure)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from hydroarm.cli._common import _check_file_out, _fail, app, console
from hydroarm.config import ConfigError


def _cell(value: float | None) -> str:
    return "-" if value is None else f"{value:.3g}"


@app.command()
def compare(
    runs: Annotated[
        list[Path],
        typer.Argument(help="Trajectory .npz files (from run, reproduce, sweep) or ROS 2 bags of ros2 sim --record."),
    ],
    out: Annotated[Path, typer.Option("--out", help="The figure to write (PNG).")] = Path("compare.png"),
    steady_after: Annotated[
        float, typer.Option("--steady-after", min=0.0, max=3600.0, help="Where the start-up ends (s).")
    ] = 2.0,
    as_json: Annotated[bool, typer.Option("--json", help="Print the table as JSON.")] = False,
) -> None:
    """Compare saved runs: E_p over the whole run and after the start-up, per joint, side by side;
    a figure of their joint errors, torques and disturbance estimates, one axis per joint.

    Example: hydroarm compare results/runs/clean__mpc__seed0.npz results/runs/clean__gp-mpc__seed0.npz --out cmp.png
    """
    from hydroarm.studies.compare import compare_rows, load_runs, plot_comparison

    try:
        loaded = load_runs(runs)
    except ConfigError as error:
        _fail(str(error))
    _check_file_out(out)
    rows = compare_rows(loaded, steady_after)
    plot_comparison(loaded, out, steady_after)
    if as_json:
        print(json.dumps(rows, indent=1))
        return
    n = len(rows[0]["Ep"])
    table = Table(
        title="E_p (rad^2) over the whole run and after the start-up", box=None, pad_edge=False, padding=(0, 0, 0, 1)
    )
    for column in ("#", "span", "mean", *(f"joint {j + 1}" for j in range(n))):
        table.add_column(
            column,
            justify="left" if column in ("#", "span") else "right",
            no_wrap=True,
            min_width=8 if column != "#" else 2,
        )
    for k, row in enumerate(rows, 1):
        table.add_row(f"#{k}", "whole run", _cell(row["Ep_mean"]), *(_cell(x) for x in row["Ep"]))
        table.add_row(
            "", f"t > {steady_after:g} s", _cell(row["Ep_steady_mean"]), *(_cell(x) for x in row["Ep_steady"])
        )
    Console().print(table)
    for k, row in enumerate(rows, 1):
        console.print(f"#{k}: {row['label']}{' (diverged)' if row['diverged'] else ''}, {row['file']}")
    console.print(f"wrote {out}")
