"""What a run's settings must hold beyond each field's range: one system per run, and the
settings sections that registered controllers declare.

A run simulates one system: the arm on a fixed base (``vehicle.name`` null) or the arm on a
vehicle. A fixed arm takes no ``vehicle.*`` setting, an arm on a vehicle no setting of the
fixed-base-only sections (:data:`~hydroarm.sim.vehicle.FIXED_BASE_ONLY_SECTIONS`):
:func:`check_one_system` refuses either with one message naming the field.

A controller registered from outside hydroarm declares its own section
(:attr:`~hydroarm.control.registry.ControllerSpec.settings`); :func:`split_declared` takes it
out of the settings' data and validates it against its model, so that
:class:`~hydroarm.sim.experiment.ExperimentConfig` holds it beside its built-in sections.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import pydantic

from hydroarm.config import ConfigError, field_error, shown
from hydroarm.control import registry
from hydroarm.sim.vehicle import FIXED_BASE_ONLY_SECTIONS, VEHICLE_HOMES, VehicleRun, check_vehicle_settings

__all__ = [
    "SYSTEM_ONLY",
    "check_one_system",
    "compact_declared",
    "declared_section_of",
    "first_change",
    "split_declared",
]

SYSTEM_ONLY: dict[str, tuple[str, ...]] = {
    "fixed arm": (*FIXED_BASE_ONLY_SECTIONS, "mismatch", *VEHICLE_HOMES),
    "arm on a vehicle": ("vehicle",),
}
"""The sections and keys only one system reads, by system (a replay is its own settings,
:class:`~hydroarm.studies.replay.ReplayConfig`, which refuses the real loop's sections): any of
them away from its default on the other system fails validation with one message naming it
(:func:`check_one_system`). Every other section is read by both."""


def first_change(value: pydantic.BaseModel, default: pydantic.BaseModel, prefix: str) -> tuple[str, Any, Any] | None:
    """``(dotted key, value, default)`` of the first setting of ``value`` away from ``default``
    (through its sub-sections), or None."""
    for key in type(value).model_fields:
        mine, theirs = getattr(value, key), getattr(default, key)
        if mine == theirs:
            continue
        if isinstance(mine, pydantic.BaseModel) and type(mine) is type(theirs):
            return first_change(mine, theirs, f"{prefix}{key}.")
        return f"{prefix}{key}", mine, theirs
    return None


def check_one_system(config: Any) -> None:
    """Raise :class:`ConfigError` naming the first setting ``config`` (an ``ExperimentConfig``)
    gives the other system: a vehicle setting on a fixed arm, a fixed-base-only setting on a
    vehicle run (:func:`~hydroarm.sim.vehicle.check_vehicle_settings`)."""
    if config.vehicle.name is not None:
        check_vehicle_settings(config)
        return
    changed = first_change(config.vehicle, VehicleRun(), "vehicle.")
    if changed is not None:
        key, value, default = changed
        raise field_error(
            key,
            value,
            "read only by a run on a vehicle: set vehicle.name (hydroarm run --vehicle NAME), "
            f"or leave it at its default ({shown(default)}) for the arm on a fixed base",
        )


def _validated(name: str, model: type[pydantic.BaseModel], value: Any) -> pydantic.BaseModel:
    """``value`` validated as the declared section ``name`` (``model``); a :class:`ConfigError`
    naming the first bad field (``toy.kp = -1.0: ...``)."""
    try:
        return model.model_validate(value)
    except pydantic.ValidationError as error:
        first = error.errors()[0]
        field = ".".join([name, *(str(part) for part in first["loc"])])
        reason = first["msg"].removeprefix("Value error, ")
        if first["type"] == "extra_forbidden":
            reason = f"unknown setting of the section {name!r} (allowed: {', '.join(model.model_fields)})"
        raise field_error(field, first.get("input"), reason) from None


def split_declared(data: Any, built_in: set[str]) -> tuple[Any, dict[str, pydantic.BaseModel]]:
    """``(the rest of data, {section: validated model})``: the sections registered controllers
    declare (each at its defaults where ``data`` has none) taken out of the settings ``data``;
    ``data`` as it is when it is not a mapping or nothing is declared. A declared section that
    shadows a built-in one (``built_in``) raises :class:`ConfigError`."""
    declared = registry.declared_settings()
    if not declared or not isinstance(data, Mapping):
        return data, {}
    clash = sorted(set(declared) & built_in)
    if clash:
        raise ConfigError(f"a registered controller declares the settings section {clash[0]!r}, a built-in one")
    rest = {key: value for key, value in data.items() if key not in declared}
    return rest, {name: _validated(name, model, data.get(name, {})) for name, model in declared.items()}


def declared_section_of(held: Mapping[str, pydantic.BaseModel], name: str) -> pydantic.BaseModel:
    """The declared section ``name`` from ``held`` (validated settings), or its defaults where the
    settings were validated before its controller was registered."""
    if name in held:
        return held[name]
    declared = registry.declared_settings()
    if name not in declared:
        raise ConfigError(
            f"a registered controller reads the settings section {name!r}, which ExperimentConfig has not: "
            f"declare it (ControllerSpec(settings={{{name!r}: Model}}))"
        )
    return declared[name]()


def compact_declared(data: dict[str, Any]) -> dict[str, Any]:
    """``data`` (settings as JSON data) without the declared sections at their defaults, so that
    registering a controller changes no other run's id (``data`` is changed and returned)."""
    for name, model in registry.declared_settings().items():
        if data.get(name) == model().model_dump(mode="json"):
            data.pop(name)
    return data
