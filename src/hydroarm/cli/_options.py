"""Typer option declarations of the commands, as ``Annotated`` aliases: a command's signature
names its options, their flags, ranges and help live here. The options every command shares
(``--config``, ``--set``, ``--tuned``, ``--overwrite``) are in :mod:`hydroarm.cli._common`."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def _noise_in_range(value: float | None) -> float | None:
    """``--noise``: a finite variance 0 <= x <= 10 (rad^2); NaN is named as such."""
    if value is not None and not 0.0 <= value <= 10.0:
        raise typer.BadParameter(f"{value!r}: must be a number 0 <= x <= 10 (rad^2)")
    return value


ControllerOption = Annotated[
    str | None,
    typer.Option(
        "--controller",
        help="A registered controller (hydroarm controllers; default gp-mpc; on a vehicle the arm's, default smc).",
    ),
]
RunArmOption = Annotated[
    str | None,
    typer.Option("--arm", help="Built-in arm name or arm file (default: the settings' arm; on a vehicle its file's)."),
]
NoiseOption = Annotated[
    float | None,
    typer.Option(
        "--noise",
        callback=_noise_in_range,
        help="Measurement noise variance, 0 <= x <= 10 rad^2 (default: plant.noise_variance, 0).",
    ),
]
ViewOption = Annotated[bool, typer.Option("--view", help="Then open the run in the browser viewer (the viewer extra).")]
ModelOption = Annotated[
    Path | None,
    typer.Option("--model", help="PI-IDMPC: start from the water model saved in this file (JSON)."),
]
SaveModelOption = Annotated[
    Path | None,
    typer.Option("--save-model", help="PI-IDMPC: save the water model learned by the run to this file (JSON)."),
]
VehicleOption = Annotated[
    str | None,
    typer.Option(
        "--vehicle",
        help="Mount the arm on this vehicle (bluerov2-heavy or a vehicle file): = --set vehicle.name=VEHICLE.",
    ),
]

# hydroarm reproduce
ReproduceOutOption = Annotated[Path, typer.Option("--out", help="Output folder (created).")]
QuickOption = Annotated[bool, typer.Option("--quick", help="3 s task, 2 noisy seeds, no ablation (CI).")]
SeedsOption = Annotated[int | None, typer.Option("--seeds", min=1, max=100, help="Noisy seeds (default 5; quick 2).")]
AblationOption = Annotated[
    bool | None, typer.Option("--ablation/--no-ablation", help="Run the ablation (default: on unless --quick).")
]
ReproduceWorkersOption = Annotated[int, typer.Option("--workers", min=1, max=64, help="Parallel processes.")]
ReproduceArmOption = Annotated[
    str | None,
    typer.Option("--arm", help="Another arm (built-in name or file); the task is scaled to its joint limits."),
]
ReplicasOption = Annotated[
    int | None,
    typer.Option(
        "--replicas",
        min=1,
        max=64,
        help="Runs of each clean GP row from starts 1e-12 rad apart, reported as mean and spread "
        "(default 8; quick 4; 1: none).",
    ),
]

# hydroarm sweep
SweepOutOption = Annotated[Path, typer.Option("--out", help="Output folder (created; the same command resumes).")]
SweepWorkersOption = Annotated[
    int, typer.Option("--workers", min=1, max=256, help="Parallel processes (or the CPUs of a local Ray instance).")
]
RayOption = Annotated[
    bool,
    typer.Option("--ray", help=r"Run on Ray: a local Ray instance with --workers CPUs (pip install 'hydroarm\[ray]')."),
]
RayAddressOption = Annotated[
    str | None,
    typer.Option(
        "--ray-address",
        metavar="ADDRESS",
        help="Run on this Ray cluster instead (implies --ray): auto, HOST:6379 or ray://HOST:10001.",
    ),
]
TrajectoriesOption = Annotated[bool, typer.Option("--trajectories", help="Also keep every trajectory (runs/<id>.npz).")]
