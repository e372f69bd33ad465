"""Which value wins: a setting that three files can give (the settings, the arm file and a URDF
arm's hydrodynamics file) resolved for one run, with where each value came from
(``hydroarm settings --resolved``), and the precedence rules as data (:data:`PRECEDENCE`,
docs/settings.md's table).

The rules are the code's, not restated: the coefficients are the ones the strip water uses
(:class:`~hydroarm.model.water.strips.StripGeometry`: a cylinder's own ``cd``/``cm`` when its file
gives one, else ``water.cd``/``water.cm``), the torque limit the one the experiment builds
(:meth:`~hydroarm.model.arm.description.Arm.with_torque_limit`: ``torque_limit`` when set, else the arm
file's); tests/test_settings_resolved.py checks both against those functions.
"""

from __future__ import annotations

from dataclasses import dataclass

from hydroarm.model.arm.description import Arm
from hydroarm.sim.experiment import ExperimentConfig

PRECEDENCE: tuple[tuple[str, tuple[str, ...]], ...] = (
    (
        "C_d of a wetted cylinder (`water.cd`)",
        (
            "the cylinder's `cd` in a URDF arm's hydrodynamics file (`[[links.cylinders]]`) or in a DH arm file",
            "its link's `cd` in the hydrodynamics file (`[[links]]`)",
            "the settings' `water.cd`",
        ),
    ),
    (
        "C_m of a wetted cylinder (`water.cm`)",
        (
            "the cylinder's `cm` in the hydrodynamics file or the DH arm file",
            "its link's `cm` in the hydrodynamics file",
            "the settings' `water.cm`",
        ),
    ),
    (
        "torque limit of the arm (the controllers' torque box)",
        ("the settings' `torque_limit`", "the arm file's `torque_limit`"),
    ),
    (
        "the drives' torque clip (`actuator.torque_limit`)",
        ("the settings' `actuator.torque_limit`", "none: the drives apply the command as given"),
    ),
    (
        "the plant's RK4 step (`inner_step`)",
        (
            "on a fixed base: `plant.inner_step`",
            "on a vehicle: `vehicle.plant.inner_step`",
            "in a replay: the replay setting `inner_step`",
        ),
    ),
)
"""(what, its sources in order: the first one given wins); the inner step's rows are one per system."""


@dataclass(frozen=True)
class Resolved:
    """One resolved value: the ``setting``, ``where`` it applies (a cylinder, the arm, the run),
    the ``value`` used and its ``source`` (which rule of :data:`PRECEDENCE` gave it)."""

    setting: str
    where: str
    value: str
    source: str


def _number(value: float) -> str:
    return f"{value:g}"


def _limits(values) -> str:
    return ", ".join(_number(float(x)) for x in values)


def resolve_settings(config: ExperimentConfig, arm: Arm) -> list[Resolved]:
    """The values one run of ``config`` on ``arm`` (as loaded from its file, before the settings'
    torque limit) uses for the settings of :data:`PRECEDENCE`, each with its source."""
    file = "the arm's file" if arm.spec is not None else "the arm's hydrodynamics file"
    rows = []
    for cylinder in arm.cylinders:
        for key, own, default in (("cd", cylinder.cd, config.water.cd), ("cm", cylinder.cm, config.water.cm)):
            source = f"{file} (cylinder or link)" if own is not None else f"settings water.{key}"
            rows.append(Resolved(f"water.{key}", cylinder.name, _number(own if own is not None else default), source))
    limit = arm.with_torque_limit(config.torque_limit).torque_limit
    source = "settings torque_limit" if config.torque_limit is not None else "the arm file's torque_limit"
    rows.append(Resolved("torque_limit", f"{arm.n_joints} joints (N m)", _limits(limit), source))
    drives = config.actuator.torque_limit
    rows.append(
        Resolved(
            "actuator.torque_limit",
            "the drives (N m)",
            "none" if drives is None else (_limits(drives) if isinstance(drives, list) else _number(drives)),
            "settings actuator.torque_limit" if drives is not None else "not set: the drives apply the command",
        )
    )
    if config.vehicle.name is not None:
        rows.append(
            Resolved("vehicle.plant.inner_step", "the floating plant (s)", _number(config.vehicle.plant.inner_step),
                     "settings vehicle.plant.inner_step (on a vehicle)")
        )  # fmt: skip
    else:
        rows.append(
            Resolved("plant.inner_step", "the fixed-base plant (s)", _number(config.plant.inner_step),
                     "settings plant.inner_step (on a fixed base)")
        )  # fmt: skip
    return rows


def precedence_markdown() -> list[str]:
    """docs/settings.md's precedence table, from :data:`PRECEDENCE`."""
    lines = [
        "## Which value wins: settings, arm file, hydrodynamics file",
        "",
        "Some values can come from more than one file. The first source given wins;",
        "`hydroarm settings --resolved --arm ARM` prints, for one run, each value used and where it",
        "came from (`--config` and `--set` as for `hydroarm run`).",
        "",
        "| value | first | then | then |",
        "|---|---|---|---|",
    ]
    for what, sources in PRECEDENCE:
        cells = [*sources, *([""] * (3 - len(sources)))]
        lines.append(f"| {what} | " + " | ".join(cells) + " |")
    return [*lines, ""]
