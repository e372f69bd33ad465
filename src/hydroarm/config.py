"""Validated configuration: loading TOML/YAML files into pydantic models.

Every config model of hydroarm is a frozen pydantic model with
``extra="forbid"``. A wrong value raises :class:`ConfigError`, a ``ValueError``
whose message names the field (as a dotted path such as ``links.2.mass``), the
value given and what is allowed; never a traceback from deep inside NumPy or
Pinocchio.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import pydantic

ModelT = TypeVar("ModelT", bound=pydantic.BaseModel)


class ConfigError(ValueError):
    """A configuration value is missing, unknown or out of its allowed range."""


class FrozenModel(pydantic.BaseModel):
    """Base of every config model: immutable, unknown keys rejected, NaN rejected."""

    model_config = pydantic.ConfigDict(
        extra="forbid", frozen=True, allow_inf_nan=False, validate_default=True
    )


def _location(loc: tuple[Any, ...]) -> str:
    return ".".join(str(part) for part in loc) or "<root>"


def format_validation_error(error: pydantic.ValidationError, source: str) -> str:
    """One readable line per problem: ``source: field = value: what is allowed``."""
    lines = []
    for item in error.errors():
        where = _location(item["loc"])
        value = item.get("input")
        message = item["msg"]
        if item["type"] == "extra_forbidden":
            lines.append(f"{source}: unknown key '{where}'")
            continue
        shown = repr(value)
        if len(shown) > 60:
            shown = shown[:57] + "..."
        lines.append(f"{source}: {where} = {shown}: {message}")
    return "\n".join(lines)


def validate(model: type[ModelT], data: Any, source: str) -> ModelT:
    """Validate ``data`` into ``model``; raise :class:`ConfigError` naming every bad field."""
    try:
        return model.model_validate(data)
    except pydantic.ValidationError as error:
        raise ConfigError(format_validation_error(error, source)) from None


def read_mapping(path: str | Path) -> dict[str, Any]:
    """Read a TOML (``.toml``) or YAML (``.yaml``/``.yml``) file into a dict."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: no such file")
    suffix = path.suffix.lower()
    try:
        if suffix == ".toml":
            with path.open("rb") as handle:
                return tomllib.load(handle)
        if suffix in (".yaml", ".yml"):
            import yaml  # optional: only needed for YAML files

            with path.open() as handle:
                data = yaml.safe_load(handle)
            if not isinstance(data, dict):
                raise ConfigError(f"{path}: the top level must be a mapping")
            return data
    except (tomllib.TOMLDecodeError, ValueError) as error:
        if isinstance(error, ConfigError):
            raise
        raise ConfigError(f"{path}: cannot parse: {error}") from None
    raise ConfigError(f"{path}: unknown config format '{suffix}' (use .toml, .yaml or .yml)")


def load_model(model: type[ModelT], path: str | Path) -> ModelT:
    """Read and validate a config file into ``model``."""
    return validate(model, read_mapping(path), str(path))


def per_joint(value: float | list[float], n: int, field: str) -> np.ndarray:
    """Broadcast a scalar, or check a per-joint list has n values; shape (n,).

    Raises :class:`ConfigError` naming ``field`` when the length is wrong.
    """
    values = np.asarray(value, dtype=float)
    if values.ndim == 0:
        return np.full(n, float(values))
    if values.shape != (n,):
        raise ConfigError(f"{field} has {values.shape[0]} values for {n} joints: give one or {n}")
    return values.copy()


def require_finite(name: str, value: float) -> float:
    """Return ``value`` or raise ConfigError if it is NaN or infinite."""
    if not math.isfinite(value):
        raise ConfigError(f"{name} = {value!r}: must be a finite number")
    return value
