"""Which value wins: a setting that three files can give (the settings, the arm file and a URDF
arm's hydrodynamics file) resolved for one run, with where each value came from
(``hydroarm settings --resolved``), and the precedence rules as data (:data:`PRECEDENCE`,
docs/settings.md's table).

The rules are the code's, not restated: the coefficients are the ones the strip water uses
(:func:`~hydroarm.model.arm.description.coefficient`, the one rule: a cylinder's own ``cd``/``cm`` when its
hydrodynamics file gives one, else ``water.cd``/``water.cm``; a DH arm file gives none), the
torque limit the one the experiment builds (:meth:`~hydroarm.model.arm.description.Arm.with_torque_limit`:
``torque_limit`` when set, else the arm file's); tests/test_settings_resolved.py checks both against those functions.
"""

from __future__ import annotations

from dataclasses import dataclass

from hydroarm.model.arm.description import Arm
from hydroarm.sim.experiment import ExperimentConfig

PRECEDENCE: tuple[tuple[str, tuple[str, ...]], ...] = (
    (
        "C_d of a wetted cylinder (`water.cd`)",
        (
            "the cylinder's `cd` in a URDF arm's hydrodynamics file (`[[links.cylinders]]`)",
            "its link's `cd` in the hydrodynamics file (`[[links]]`)",
            "the settings' `water.cd`",
        ),
    ),
    (
        "C_m of a wetted cylinder (`water.cm`)",
        (
            "the cylinder's `cm` in the hydrodynamics file",
            "its link's `cm` in the hydrodynamics file",
            "the settings' `water.cm`",
        ),
    ),
    (
        "torque limit of the arm (the controllers' torque box)",
        (
            "the settings' `torque_limit`",
            "the arm file's `torque_limit` (a DH arm file, or a URDF arm's hydrodynamics file)",
            "a URDF's `<limit effort>`",
        ),
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
    (
        "the water current",
        (
            "on a fixed base: `water.current`",
            "on a vehicle: `vehicle.current` (uniform along world x; `water.current` refused)",
            "in a replay: none (the tank's still water)",
        ),
    ),
    (
        "Gauss points per cylinder of the drag integral",
        (
            "on a fixed base: `plant.drag_points` (compiled plant), else `water.quadrature_points`",
            "on a vehicle: `vehicle.plant.drag_points` (`water.quadrature_points` refused)",
        ),
    ),
    (
        "the arm's drag, added mass, buoyancy on a vehicle",
        (
            "on only where both switches are: `water.drag` / `water.added_mass` / `water.buoyancy` "
            "(the hull's too) and `vehicle.plant.arm_drag` / `arm_added_mass` / `arm_buoyancy` (the arm's alone)",
        ),
    ),
    (
        "the GP's settings (two learners, one model: `GPConfig`)",
        (
            "the arm controller's GP (GP-MPC, GP-IDMPC), on either system: `gp`",
            "the vehicle's feed-forward GP (`vehicle.aware`): `vehicle.gp` (`gp` does not reach it)",
        ),
    ),
    (
        "the water density",
        ("on a fixed base or a vehicle: `water.rho`", "in a replay: the replay setting `water_density`"),
    ),
)
"""(what, its sources in order: the first one given wins); the rows that name a system (the inner
step, the current, the Gauss points, the density) give each system's one home instead."""


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
        for key, own, used in zip(("cd", "cm"), (cylinder.cd, cylinder.cm), cylinder.coefficients(config.water)):
            source = f"{file} (cylinder or link)" if own is not None else f"settings water.{key}"
            rows.append(Resolved(f"water.{key}", cylinder.name, _number(used), source))
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
    return rows + _system_rows(config)


def _system_rows(config: ExperimentConfig) -> list[Resolved]:
    """The rows of :data:`PRECEDENCE` with one home per system: the inner step, the current and
    the Gauss points of the drag integral, as the plant of ``config``'s system reads them."""
    vehicle = config.vehicle
    if vehicle.name is not None:
        return [
            Resolved("vehicle.plant.inner_step", "the floating plant (s)", _number(vehicle.plant.inner_step),
                     "settings vehicle.plant.inner_step (on a vehicle)"),
            Resolved("vehicle.current", "the water (m/s, uniform along world x)", _number(vehicle.current),
                     "settings vehicle.current (on a vehicle)"),
            Resolved("vehicle.plant.drag_points", "the arm's cylinders (Gauss points)",
                     str(vehicle.plant.drag_points), "settings vehicle.plant.drag_points (on a vehicle)"),
        ]  # fmt: skip
    plant = config.plant
    compiled = plant.compiled and plant.drag_points is not None
    return [
        Resolved("plant.inner_step", "the fixed-base plant (s)", _number(plant.inner_step),
                 "settings plant.inner_step (on a fixed base)"),
        Resolved("water.current", "the water", config.water.current.model, "settings water.current (on a fixed base)"),
        Resolved("plant.drag_points" if compiled else "water.quadrature_points", "the arm's cylinders (Gauss points)",
                 str(plant.drag_points if compiled else config.water.quadrature_points),
                 "settings plant.drag_points (the compiled plant)" if compiled
                 else "settings water.quadrature_points (on a fixed base)"),
    ]  # fmt: skip


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
